"""Drawing: the static background with clutter, people in depth order, the light level.

Parts are drawn without anti-aliasing so that every pixel of a part has exactly its clothing
colour (times the light level, before sensor noise), and a label image records which part of
which person each pixel shows (0: background).
"""

from __future__ import annotations

import cv2
import numpy as np

from ..noise import fractal_noise
from .body import Pose

SHIRTS = ((200, 30, 30), (30, 90, 200), (40, 160, 60), (230, 200, 40), (150, 50, 170), (240, 130, 30), (30, 170, 170))
"""Shirt colours (RGB), one per person, drawn without replacement."""
TROUSERS = ((40, 40, 90), (120, 80, 40), (70, 70, 70), (20, 70, 130), (150, 150, 120), (90, 30, 30))
SKIN = ((224, 172, 105), (198, 134, 66), (141, 85, 36), (255, 205, 148), (170, 110, 70))
FLOOR = (150, 148, 140)
WALL = (176, 170, 156)

FAR_SEGMENTS = (6, 7, 2, 3)  # left leg, left arm (part indices) behind the torso
NEAR_SEGMENTS = (8, 9, 4, 5)  # right leg, right arm in front


def label_of(person: int, part: int) -> int:
    """Label-image value of ``part`` of ``person`` (0 is the background)."""
    return 1 + 16 * person + part


def part_colours(shirt, trousers, skin) -> np.ndarray:
    """(10, 3) uint8 RGB colour of each part: skin head, shirt torso and upper arms, darker sleeves
    on the forearms, trousers on the thighs and darker trousers on the shins."""
    shirt, trousers, skin = (np.asarray(c, float) for c in (shirt, trousers, skin))
    cols = [skin, shirt, shirt, 0.75 * shirt, shirt, 0.75 * shirt, trousers, 0.8 * trousers, trousers, 0.8 * trousers]
    return np.clip(np.round(cols), 0, 255).astype(np.uint8)


def part_areas(p: Pose) -> np.ndarray:
    """(10,) drawn area of each part in pixels (analytic, ignoring occlusion)."""
    d1, d2 = p.torso_corners[2] - p.torso_corners[0], p.torso_corners[3] - p.torso_corners[1]
    torso = 0.5 * abs(d1[0] * d2[1] - d1[1] * d2[0])  # quadrilateral area from its diagonals
    lengths = np.linalg.norm(p.segments[:, 1] - p.segments[:, 0], axis=1)
    limbs = lengths * p.widths + np.pi * (p.widths / 2) ** 2
    return np.concatenate([[np.pi * p.head_radius**2, torso], limbs])


def hue_shifted(rgb, shift_deg: float) -> tuple[int, int, int]:
    """``rgb`` with its hue turned by ``shift_deg`` degrees (OpenCV HSV)."""
    hsv = cv2.cvtColor(np.uint8([[rgb]]), cv2.COLOR_RGB2HSV).astype(int)
    hsv[0, 0, 0] = (hsv[0, 0, 0] + int(round(shift_deg / 2))) % 180
    return tuple(int(v) for v in cv2.cvtColor(hsv.astype(np.uint8), cv2.COLOR_HSV2RGB)[0, 0])


def background(width: int, height: int, clutter_colours: list, rng: np.random.Generator,
               person_height: float, lanes: tuple[float, float]) -> np.ndarray:
    """Floor and wall with a mild texture, and static clutter boxes in clothing-like colours,
    half of them placed in the band the people walk through."""
    img = np.empty((height, width, 3), np.float32)
    wall_h = int(0.3 * height)
    img[:wall_h] = WALL
    img[wall_h:] = FLOOR
    img += 8.0 * fractal_noise(rng, (height, width), (24, 6), (1.0, 0.5))[..., None]
    img[wall_h - 2: wall_h + 1] = (90, 85, 80)
    out = np.clip(np.round(img), 0, 255).astype(np.uint8)
    for k, colour in enumerate(clutter_colours):
        w = int(rng.uniform(0.10, 0.22) * person_height)
        h = int(rng.uniform(0.15, 0.35) * person_height)
        x = int(rng.uniform(0, width - w))
        if k % 2 == 0:  # in the walking band: a look-alike right where the people are
            y = int(rng.uniform(lanes[0] - 0.9 * person_height, lanes[1] - h))
        else:
            y = int(rng.uniform(0, height - h))
        cv2.rectangle(out, (x, y), (x + w, y + h), tuple(int(c) for c in colour), -1, cv2.LINE_8)
    return out


def draw_person(img: np.ndarray, labels: np.ndarray, p: Pose, colours: np.ndarray, person: int) -> None:
    """Draw one person (far limbs, torso, head, near limbs) into ``img`` and ``labels`` in place."""

    def seg(part: int) -> None:
        a, b = np.round(p.segments[part - 2]).astype(int)
        t = max(1, int(round(p.widths[part - 2])))
        for canvas, value in ((img, tuple(int(c) for c in colours[part])), (labels, label_of(person, part))):
            cv2.line(canvas, tuple(a.tolist()), tuple(b.tolist()), value, t, cv2.LINE_8)

    for part in FAR_SEGMENTS:
        seg(part)
    poly = np.round(p.torso_corners).astype(np.int32)
    cv2.fillConvexPoly(img, poly, tuple(int(c) for c in colours[1]), cv2.LINE_8)
    cv2.fillConvexPoly(labels, poly, label_of(person, 1), cv2.LINE_8)
    c = tuple(np.round(p.head_centre).astype(int).tolist())
    r = int(round(p.head_radius))
    cv2.circle(img, c, r, tuple(int(v) for v in colours[0]), -1, cv2.LINE_8)
    cv2.circle(labels, c, r, label_of(person, 0), -1, cv2.LINE_8)
    for part in NEAR_SEGMENTS:
        seg(part)


def apply_light(img: np.ndarray, gain: float) -> np.ndarray:
    """Every channel times ``gain``, rounded and saturated (the illumination change)."""
    if gain == 1.0:
        return img
    return np.clip(np.floor(img.astype(np.float32) * np.float32(gain) + 0.5), 0, 255).astype(np.uint8)


