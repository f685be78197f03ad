"""The real-footage pipeline end to end on a small generated folder sequence: a panning camera
without a homography (stabilisation), a small car (upsampling), determinism of the CSV."""

import csv
from dataclasses import replace

import cv2
import numpy as np
import pytest

from services.cli import main
from common.single_target.runner import Tracker
from common.settings import profile_for
from common.sources import open_source
from test_scale import texture

N_FRAMES = 24
W, H = 400, 300


def car_sprite() -> np.ndarray:
    """A 16x8 px red car with a dark windscreen, RGBA-like (alpha from the body)."""
    car = np.zeros((8, 16, 3), np.float32)
    car[:] = (200, 30, 35)
    car[1:7, 9:12] = (40, 40, 50)
    car[0, :] = car[-1, :] = (120, 20, 25)
    return car


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    d = tmp_path_factory.mktemp("seq") / "panning-car"
    (d / "img").mkdir(parents=True)
    ground = texture(size=(700, 900), seed=5)
    car = car_sprite()
    boxes = []
    for i in range(N_FRAMES):
        g = ground.copy()
        # the car drives right and slightly down over the ground, turning gently
        cx, cy, ang = 430 + 1.5 * i, 330 + 0.4 * i, 5.0 * np.sin(i / 8)
        m = cv2.getRotationMatrix2D((7.5, 3.5), ang, 1.0)
        m[:, 2] += (cx - 7.5, cy - 3.5)
        sprite = cv2.warpAffine(car, m, (900, 700), flags=cv2.INTER_LINEAR)
        mask = cv2.warpAffine(np.ones((8, 16), np.float32), m, (900, 700), flags=cv2.INTER_LINEAR)[:, :, None]
        g = g * (1 - mask) + sprite * mask
        # the camera pans (3 px/frame right, 1 down) and rolls slowly: frame = world warped
        cam = cv2.getRotationMatrix2D((450, 350), 0.3 * i, 1.0)
        cam[:, 2] -= (250 + 3.0 * i, 200 + 1.0 * i)  # the window's origin moves with the pan
        frame = cv2.warpAffine(g, cam, (W, H), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
        cv2.imwrite(str(d / "img" / f"{i + 1:06d}.png"), np.clip(frame, 0, 255).astype(np.uint8)[:, :, ::-1])
        px, py = cam[:, :2] @ np.array([cx, cy]) + cam[:, 2]
        boxes.append((px - 8, py - 4, 16, 8))
    (d / "groundtruth_rect.txt").write_text("".join(f"{x:.2f},{y:.2f},{w},{h}\n" for x, y, w, h in boxes))
    return d


def run_track(seq, out):
    assert main(["track", str(seq), "--out", str(out), "--no-progress"]) == 0
    with open(out) as fh:
        return list(csv.DictReader(fh))


def test_real_profile_tracks_a_small_car_from_a_panning_camera(sequence):
    src = open_source(str(sequence))
    frames = list(src)
    st = profile_for(src)
    tracker = Tracker.start(frames[0], frames[0].truth.box, st)
    errs = []
    for f in frames:
        s = tracker.step(f)
        errs.append(np.hypot(s.map_estimate.image_x - f.truth.centre[0], s.map_estimate.image_y - f.truth.centre[1]))
    assert tracker.stabiliser is not None and tracker.stabiliser.fallbacks == 0
    assert tracker.scale.u > 2.5  # a 16 px car is matched enlarged about 3x
    assert max(errs) < 5.0, np.round(errs, 1)


def test_same_seed_same_csv(sequence, tmp_path):
    a = run_track(sequence, tmp_path / "a.csv")
    b = run_track(sequence, tmp_path / "b.csv")
    assert len(a) == N_FRAMES and a == b


def test_the_targets_own_flow_is_measured_only_while_the_box_holds_the_target(sequence):
    """The target's own change of size is read from the pixels in the previous estimate's box only
    while p(V=1|Z) there says the box holds the target (``scale.flow.min_p_visible``); below it the
    box's points measure whatever it holds. Same tracker, same frames: only the posterior differs."""
    src = open_source(sequence)
    frames = list(src)
    settings = profile_for(src)
    tracker = Tracker.start(frames[0], src.truth[0], settings)
    for f in frames[:6]:
        tracker.step(f)
    held = replace(tracker.last_state, p_visible=1.0)
    tracker.last_state = held
    measured = tracker._own_scale_change(frames[6])
    assert measured is not None and abs(measured.dlog) < 0.05  # the car keeps its size
    gate = settings.scale.flow.min_p_visible
    tracker.last_state = replace(held, p_visible=gate - 0.01)
    assert tracker._own_scale_change(frames[6]) is None
    tracker.last_state = replace(held, p_visible=gate)
    assert tracker._own_scale_change(frames[6]) is not None
