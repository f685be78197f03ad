"""``PeopleScene``: a deterministic, seeded surveillance video of several walking people.

Everything random comes from ``numpy.random.default_rng([seed, 2, k])`` (one stream per component
k: people, clutter, background, lookalikes) and the sensor noise of frame ``i`` from
``default_rng([seed, 1, i])``, so ``scene.frame(i)`` is bit-identical in any order and process.

People walk along nearby horizontal lanes, alternately left-to-right and right-to-left, each
passing the middle of the image at a random time in the middle of the run: people walking
opposite ways cross, and the nearer one (lower in the image) hides the other. Look-alikes (people
standing still in clothes like a walker's) stand on the walkers' paths, drawn into the static
background behind everyone: clutter, label 0, no ground truth.
``scene.crossings`` lists ``(i, j, frame)`` for every pair whose body axes pass each other.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..noise import SensorNoise
from . import body
from .config import PeopleSceneConfig
from .render import SHIRTS, SKIN, TROUSERS, apply_light, background, draw_person, hue_shifted, label_of, part_areas, part_colours

_NOISE_TAG = 1
_CONTENT_TAG = 2
_STREAMS = ("people", "clutter", "background", "lookalikes")


@dataclass(frozen=True)
class PeopleTruth:
    """Ground truth of every person in one frame (person order = target order)."""

    parts: np.ndarray
    """(n_people, 10, 2) part centres in pixels, :data:`body.PART_NAMES` order."""
    visible: np.ndarray
    """(n_people, 10) bool: the pixel at the part's centre shows that part (not hidden, inside the image)."""
    visible_fraction: np.ndarray
    """(n_people, 10) share of the part's drawn area that is not hidden by another person (or the border)."""
    boxes: np.ndarray
    """(n_people, 4) x, y, w, h box around each person's drawn parts."""


@dataclass(frozen=True)
class PeopleFrame:
    index: int
    time: float
    """index / fps, seconds."""
    image: np.ndarray
    """(H, W, 3) uint8 RGB."""
    labels: np.ndarray
    """(H, W) uint8: :func:`render.label_of` (person, part) of each pixel, 0 for the background."""
    truth: PeopleTruth
    light: float
    """Light level (gain) of this frame."""


@dataclass(frozen=True)
class Walker:
    """One person's fixed parameters."""

    height: float
    speed: float
    direction: float  # +1 walks right, -1 left
    feet_y: float
    x_mid: float  # x at t_mid
    t_mid: float
    phase0: float
    colours: np.ndarray  # (10, 3) uint8

    def x(self, t: float) -> float:
        return self.x_mid + self.direction * self.speed * (t - self.t_mid)

    def phase(self, t: float) -> float:
        stride = 0.8 * self.height  # one gait cycle (two steps) per 0.8 H walked
        return self.phase0 + 2.0 * np.pi * self.speed * t / stride


@dataclass(frozen=True)
class Lookalike:
    """A static person-shaped clutter figure, drawn into the background."""

    pose: body.Pose
    colours: np.ndarray  # (10, 3) uint8
    feet_y: float


class PeopleScene:
    """Seeded scene; ``frame(i)`` renders frame i with its ground truth."""

    def __init__(self, config: PeopleSceneConfig | None = None, seed: int = 0):
        self.config = cfg = config if config is not None else PeopleSceneConfig()
        self.seed = int(seed)
        rngs = {name: np.random.default_rng([self.seed, _CONTENT_TAG, k]) for k, name in enumerate(_STREAMS)}
        r = rngs["people"]
        duration = cfg.n_frames / cfg.fps
        base_feet = 0.85 * cfg.height
        shirts, trousers, skins = (r.permutation(len(c)) for c in (SHIRTS, TROUSERS, SKIN))  # distinct per person
        first_dir = 1.0 if r.random() < 0.5 else -1.0
        self.walkers: list[Walker] = []
        for k in range(cfg.n_people):
            h = cfg.person_height_px * r.uniform(0.92, 1.08)
            colours = part_colours(SHIRTS[shirts[k]], TROUSERS[trousers[k]], SKIN[skins[k]])
            self.walkers.append(Walker(
                height=h, speed=cfg.speed_px_s * r.uniform(0.8, 1.2), direction=first_dir * (1 if k % 2 == 0 else -1),
                feet_y=base_feet + r.uniform(-0.5, 0.5) * cfg.lane_spread_px,
                x_mid=0.5 * cfg.width + r.uniform(-0.07, 0.07) * cfg.width,
                t_mid=duration * r.uniform(0.35, 0.65), phase0=r.uniform(0, 2 * np.pi), colours=colours,
            ))  # fmt: skip
        self.depth_order = sorted(range(cfg.n_people), key=lambda k: self.walkers[k].feet_y)
        rc = rngs["clutter"]
        clutter = []
        for _ in range(cfg.n_clutter):
            w = self.walkers[rc.integers(cfg.n_people)]
            clutter.append(hue_shifted(w.colours[rc.choice([1, 6])], rc.uniform(-8, 8)))
        lanes = (min(w.feet_y for w in self.walkers), max(w.feet_y for w in self.walkers))
        self.background = background(cfg.width, cfg.height, clutter, rngs["clutter"], cfg.person_height_px, lanes)
        self.lookalikes = self._lookalikes(rngs["lookalikes"])
        blank = np.zeros(self.background.shape[:2], np.uint8)
        for la in sorted(self.lookalikes, key=lambda a: a.feet_y):
            draw_person(self.background, blank, la.pose, la.colours, 0)
        self.noise = SensorNoise(cfg.noise_sigma)
        self.crossings = self._crossings()

    def _lookalikes(self, rng: np.random.Generator) -> list[Lookalike]:
        """Static person-shaped clutter: per walking person, ``lookalikes_per_person`` people standing
        still just behind its lane where it passes at stratified random times, in its shirt with the hue
        turned, other trousers and a random skin (see :class:`~.config.PeopleSceneConfig`)."""
        cfg = self.config
        duration = cfg.n_frames / cfg.fps
        n = cfg.lookalikes_per_person
        lo, hi = cfg.lookalike_hue_deg
        out = []
        for w in self.walkers:
            for j in range(n):
                t = duration * (j + rng.uniform(0.15, 0.85)) / n
                turn = rng.choice([-1.0, 1.0]) * rng.uniform(lo, hi)
                others = [c for c in TROUSERS if tuple(c) != tuple(w.colours[6])]  # not the person's trousers
                trousers = others[rng.integers(len(others))]
                colours = part_colours(hue_shifted(w.colours[1], turn), trousers, SKIN[rng.integers(len(SKIN))])
                feet_y = w.feet_y - rng.uniform(2.0, 8.0)
                h = w.height * rng.uniform(0.95, 1.05)
                p = body.pose(w.x(t), feet_y, h, rng.choice([-1.0, 1.0]), rng.uniform(0, 2 * np.pi),
                              np.deg2rad(4.0), np.deg2rad(4.0))
                out.append(Lookalike(p, colours, feet_y))
        return out

    def __len__(self) -> int:
        return self.config.n_frames

    @property
    def n_people(self) -> int:
        return self.config.n_people

    def light(self, i: int) -> float:
        """Light level of frame i: 1 before the change, ramping linearly to ``illumination_low``."""
        cfg = self.config
        a, b = (f * cfg.n_frames for f in cfg.illumination_change)
        s = float(np.clip((i - a) / max(b - a, 1e-9), 0.0, 1.0))
        return 1.0 + s * (cfg.illumination_low - 1.0)

    def poses(self, i: int) -> list[body.Pose]:
        cfg = self.config
        t = i / cfg.fps
        sw, aw = np.deg2rad(cfg.leg_swing_deg), np.deg2rad(cfg.arm_swing_deg)
        return [body.pose(w.x(t), w.feet_y, w.height, w.direction, w.phase(t), sw, aw) for w in self.walkers]

    def _crossings(self) -> list[tuple[int, int, int]]:
        t = np.arange(self.config.n_frames) / self.config.fps
        xs = np.array([[w.x(ti) for ti in t] for w in self.walkers])
        out = []
        for i in range(len(xs)):
            for j in range(i + 1, len(xs)):
                s = np.sign(xs[i] - xs[j])
                flips = np.flatnonzero(s[1:] != s[:-1])
                out += [(i, j, int(f) + 1) for f in flips]
        return sorted(out, key=lambda c: c[2])

    def frame(self, i: int) -> PeopleFrame:
        cfg = self.config
        if not 0 <= i < cfg.n_frames:
            raise IndexError(f"frame {i} outside 0..{cfg.n_frames - 1}")
        img = self.background.copy()
        labels = np.zeros(img.shape[:2], np.uint8)
        poses = self.poses(i)
        for k in self.depth_order:
            draw_person(img, labels, poses[k], self.walkers[k].colours, k)
        light = self.light(i)
        img = apply_light(img, light)
        img = self.noise.apply(img, np.random.default_rng([self.seed, _NOISE_TAG, i]))
        return PeopleFrame(i, i / cfg.fps, img, labels, self._truth(poses, labels), light)

    def _truth(self, poses: list[body.Pose], labels: np.ndarray) -> PeopleTruth:
        h, w = labels.shape
        n = len(poses)
        parts = np.array([p.centres for p in poses])
        counts = np.bincount(labels.ravel(), minlength=1 + 16 * n)
        visible = np.zeros((n, 10), bool)
        frac = np.zeros((n, 10))
        boxes = np.zeros((n, 4))
        for k, p in enumerate(poses):
            ij = np.round(parts[k]).astype(int)
            inside = (ij[:, 0] >= 0) & (ij[:, 0] < w) & (ij[:, 1] >= 0) & (ij[:, 1] < h)
            lab = np.array([label_of(k, q) for q in range(10)])
            at = np.where(inside, labels[np.clip(ij[:, 1], 0, h - 1), np.clip(ij[:, 0], 0, w - 1)], 0)
            visible[k] = inside & (at == lab)
            frac[k] = np.clip(counts[lab] / part_areas(p), 0.0, 1.0)
            pts = np.concatenate([p.segments.reshape(-1, 2), p.torso_corners, p.head_centre[None] - p.head_radius,
                                  p.head_centre[None] + p.head_radius])
            pad = 0.5 * p.widths.max()
            x0, y0 = pts.min(axis=0) - pad
            x1, y1 = pts.max(axis=0) + pad
            boxes[k] = (x0, y0, x1 - x0, y1 - y0)
        return PeopleTruth(parts, visible, frac, boxes)
