"""The built-in synthetic aerial scene: determinism, ground truth, events and config validation."""

from __future__ import annotations

import hashlib
import subprocess
import sys
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
from pydantic import ValidationError

from common.scene import SceneConfig, SceneFrame, SyntheticScene, Truth

ROOT = Path(__file__).resolve().parents[1]
AERO = ROOT.parent / "shared" / "data" / "opencv-aerial" / "aero1.jpg"

# A small, fast scene (320x180, 3 px/m) for tests that do not need full resolution.
SMALL = dict(width=320, height=180, pixels_per_metre=3.0)


@pytest.fixture(scope="module")
def scene() -> SyntheticScene:
    return SyntheticScene(SceneConfig(), seed=0)


@pytest.fixture(scope="module")
def small() -> SyntheticScene:
    return SyntheticScene(SceneConfig(**SMALL), seed=3)


def _digest(img: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(img).tobytes()).hexdigest()


def _car_mask(scene: SyntheticScene, i: int, occluders: bool) -> np.ndarray:
    """Pixels that change when the target car is drawn (noise-free, decoy left out)."""
    with_car = scene.render(i, draw_decoy=False, draw_occluders=occluders, add_noise=False)
    without = scene.render(i, draw_target=False, draw_decoy=False, draw_occluders=occluders, add_noise=False)
    return np.any(with_car != without, axis=2)


def _axis_diff(a: float, b: float) -> float:
    """Difference of two undirected axis angles, degrees, in [0, 90]."""
    return abs((a - b + 90.0) % 180.0 - 90.0)


# ---- API and defaults ------------------------------------------------------------------------

def test_defaults_and_frame_api(scene):
    cfg = scene.config
    assert (cfg.width, cfg.height, cfg.fps, cfg.n_frames) == (1280, 720, 30.0, 300)
    assert cfg.noise_sigma == pytest.approx(4.0) and cfg.smoke_duration_s == pytest.approx(1.5)
    assert cfg.decoy_distance_car_lengths == pytest.approx(1.5)
    assert len(scene) == 300 and scene.fps == 30.0
    f = scene.frame(45)
    assert isinstance(f, SceneFrame) and isinstance(f.truth, Truth)
    assert f.index == 45 and f.time == pytest.approx(1.5)
    assert f.image.shape == (720, 1280, 3) and f.image.dtype == np.uint8
    assert f.homography.shape == (3, 3) and f.homography.dtype == np.float64
    t = f.truth
    assert len(t.image_xy) == 2 and len(t.world_xy) == 2 and len(t.box) == 4
    assert -180.0 < t.angle_image_deg <= 180.0 and -180.0 < t.heading_world_deg <= 180.0
    assert 0.0 <= t.visible_fraction <= 1.0
    assert set(scene.events) >= {"smoke", "wall", "decoy_pass"}
    for a, b in scene.events.values():
        assert 0 <= a < b <= len(scene)
    with pytest.raises(IndexError):
        scene.frame(300)
    with pytest.raises(IndexError):
        scene.frame(-1)


def test_car_size_and_target_stays_in_view(scene):
    cfg = scene.config
    h0 = scene.homographies[0]
    t0 = scene.truth(0)
    # the car's long axis spans ~50 px at default zoom (4.5 m at 50/4.5 px/m)
    heading = np.deg2rad(t0.heading_world_deg)
    fwd = np.array([np.cos(heading), np.sin(heading)]) * cfg.car_length_m / 2
    ends = [h0 @ np.array([*(np.array(t0.world_xy) + s * fwd), 1.0]) for s in (1, -1)]
    length_px = np.hypot(*(ends[0][:2] / ends[0][2] - ends[1][:2] / ends[1][2]))
    assert 45 <= length_px <= 55
    for i in range(len(scene)):
        x, y, w, h = scene.truth(i).box
        assert x >= 0 and y >= 0 and x + w <= cfg.width and y + h <= cfg.height, i


# ---- determinism -------------------------------------------------------------------------------

def test_same_seed_bit_identical_in_order_and_random_access(small):
    in_order = [_digest(small.frame(i).image) for i in range(12)]
    other = SyntheticScene(SceneConfig(**SMALL), seed=3)
    order = [7, 0, 11, 3, 3, 5, 1, 10, 2, 9, 4, 6, 8]
    for i in order:
        assert _digest(other.frame(i).image) == in_order[i], i
    assert np.array_equal(other.frame(5).homography, small.frame(5).homography)
    assert other.truth(5) == small.truth(5)
    assert other.events == small.events
    # consecutive frames differ (noise, motion), so the check above is not vacuous
    assert len(set(in_order)) == len(in_order)


def test_different_seeds_differ(small):
    other = SyntheticScene(SceneConfig(**SMALL), seed=4)
    a, b = small.frame(0), other.frame(0)
    assert not np.array_equal(a.image, b.image)
    assert a.truth.heading_world_deg != b.truth.heading_world_deg
    # the noise alone differs between frames of one scene but is fixed per (seed, frame)
    n1 = small.frame(3).image.astype(int) - small.render(3, add_noise=False)
    n2 = small.frame(3).image.astype(int) - small.render(3, add_noise=False)
    assert np.array_equal(n1, n2) and np.any(n1 != 0)


def test_bit_identical_across_processes(small):
    code = (
        "import hashlib; from common.scene import SceneConfig, SyntheticScene;"
        f"s = SyntheticScene(SceneConfig(**{SMALL!r}), seed=3);"
        "print(hashlib.sha256(s.frame(9).image.tobytes()).hexdigest())"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == _digest(small.frame(9).image)


# ---- ground truth --------------------------------------------------------------------------------

def test_homography_maps_world_to_image(scene):
    for i in range(0, len(scene), 7):
        f_h = scene.homographies[i]
        t = scene.truth(i)
        q = f_h @ np.array([*t.world_xy, 1.0])
        assert np.allclose(q[:2] / q[2], t.image_xy, atol=1e-6)
    f = scene.frame(100)
    assert np.array_equal(f.homography, scene.homographies[100])


@pytest.mark.parametrize("i", [0, 30, 165, 205, 299])
def test_rendered_car_is_where_truth_says(scene, i):
    t = scene.truth(i)
    assert t.visible_fraction == 1.0
    mask = _car_mask(scene, i, occluders=True)
    m = cv2.moments(mask.astype(np.uint8), binaryImage=True)
    cx, cy = m["m10"] / m["m00"], m["m01"] / m["m00"]
    assert np.hypot(cx - t.image_xy[0], cy - t.image_xy[1]) < 1.0
    # principal axis (image y is down, so the displayed anticlockwise angle is minus it)
    axis = -0.5 * np.degrees(np.arctan2(2 * m["mu11"], m["mu20"] - m["mu02"]))
    assert _axis_diff(axis, t.angle_image_deg) < 3.0
    # the car's area is that of its body rectangle in the image (plus an anti-aliased rim)
    cfg = scene.config
    hd = np.radians(t.heading_world_deg)
    fwd, left = np.array([np.cos(hd), np.sin(hd)]), np.array([-np.sin(hd), np.cos(hd)])
    corners = [np.array(t.world_xy) + a * cfg.car_length_m / 2 * fwd + b * cfg.car_width_m / 2 * left
               for a, b in ((1, 1), (-1, 1), (-1, -1), (1, -1))]
    q = np.array([(lambda p: p[:2] / p[2])(scene.homographies[i] @ np.array([*c, 1.0])) for c in corners])
    body_area = 0.5 * abs(np.dot(q[:, 0], np.roll(q[:, 1], 1)) - np.dot(q[:, 1], np.roll(q[:, 0], 1)))
    assert 1000 < body_area < 1400
    assert 0.95 * body_area < m["m00"] < 1.3 * body_area
    ys, xs = np.nonzero(mask)
    x, y, w, h = t.box
    assert xs.min() >= x - 1.5 and xs.max() <= x + w + 1.5 and ys.min() >= y - 1.5 and ys.max() <= y + h + 1.5
    # front vs back: the pale headlights sit on the forward side of the centre
    img = scene.render(i, draw_decoy=False, add_noise=False).astype(int)
    pale = mask & (img[..., 1] > 170) & (img[..., 2] > 150)
    hy, hx = np.nonzero(pale)
    a = np.radians(t.angle_image_deg)
    assert len(hx) > 0 and (np.mean(hx) - cx) * np.cos(a) - (np.mean(hy) - cy) * np.sin(a) > 10


def test_car_rotates_at_least_90_degrees_with_turns_of_varying_sharpness(scene):
    angles = np.array([scene.truth(i).angle_image_deg for i in range(len(scene))])
    steps = (np.diff(angles) + 180.0) % 360.0 - 180.0
    assert np.abs(steps).sum() >= 90.0
    assert scene.total_rotation_deg() == pytest.approx(np.abs(steps).sum())
    assert np.ptp(np.cumsum(steps)) >= 90.0  # not just back-and-forth jitter
    # separate turns (angular speed above 10 deg/s) with clearly different peak rates
    rate = np.abs(steps) * scene.fps
    turning = np.concatenate([[0], (rate > 10.0).astype(int), [0]])
    edges = np.flatnonzero(np.diff(turning))
    peaks = [rate[a:b].max() for a, b in zip(edges[::2], edges[1::2]) if b - a >= 5]
    assert len(peaks) >= 3
    assert max(peaks) / min(peaks) > 1.5


# ---- events ----------------------------------------------------------------------------------------

def test_smoke_hides_target_completely_for_configured_time(scene):
    a, b = scene.events["smoke"]
    assert b - a == round(1.5 * scene.fps)
    assert 1.0 <= (b - a) / scene.fps <= 2.0
    vis = np.array([scene.truth(i).visible_fraction for i in range(len(scene))])
    assert np.all(vis[a:b] == 0.0)
    assert vis[a - 1] > 0.0 and vis[b] > 0.0
    assert np.count_nonzero(vis == 0.0) == b - a  # one blackout, no other
    sa, sb = scene.events["smoke_any"]
    assert sa < a and sb > b
    # in the rendered frame the car leaves no trace at all under the smoke
    i = (a + b) // 2
    assert not _car_mask(scene, i, occluders=True).any()
    assert _car_mask(scene, i, occluders=False).sum() > 900
    # and it drives in: partly hidden just before
    assert 0.0 < vis[a - 3] < 1.0


def test_smoke_duration_is_a_parameter():
    s = SyntheticScene(SceneConfig(**SMALL, smoke_duration_s=1.0), seed=2)
    a, b = s.events["smoke"]
    assert b - a == 30
    assert all(s.truth(i).visible_fraction == 0.0 for i in range(a, b))
    assert "smoke" not in SyntheticScene(SceneConfig(**SMALL, smoke_duration_s=0), seed=2).events


def test_wall_hides_part_of_the_car(scene):
    a, b = scene.events["wall"]
    vis = np.array([scene.truth(i).visible_fraction for i in range(a, b)])
    assert np.all((vis > 0.0) & (vis < 1.0))
    partial = (vis >= 0.3) & (vis <= 0.7)
    assert partial.sum() / scene.fps >= 0.5  # at least half a second of half-hidden car
    # the rendered car really is partly covered, by about the truth's fraction
    i = a + int(np.argmin(np.abs(vis - 0.5)))
    seen = _car_mask(scene, i, occluders=True).sum()
    whole = _car_mask(scene, i, occluders=False).sum()
    assert seen / whole == pytest.approx(scene.truth(i).visible_fraction, abs=0.1)


def test_decoy_passes_within_configured_distance(scene):
    cfg = scene.config
    d = scene.decoy_distances()
    assert d.min() == pytest.approx(cfg.decoy_distance_car_lengths * cfg.car_length_m, abs=0.05)
    k = int(np.argmin(d))
    assert scene.decoy_closest_frame == k
    a, b = scene.events["decoy_pass"]
    assert a <= k < b
    f = scene.frame(k)
    assert f.decoy is not None and f.decoy.visible_fraction == 1.0 and f.truth.visible_fraction == 1.0
    px = np.hypot(*np.subtract(f.decoy.image_xy, f.truth.image_xy))
    assert 40 < px < 1.6 * 50 * cfg.decoy_distance_car_lengths
    # same shape, different (darker) red
    assert cfg.decoy_color != cfg.target_color and sum(cfg.decoy_color) < sum(cfg.target_color)
    # the events do not overlap each other
    spans = sorted(scene.events[k] for k in ("smoke", "decoy_pass", "wall"))
    assert all(spans[j][1] <= spans[j + 1][0] for j in range(len(spans) - 1))


def test_decoy_distance_is_a_parameter():
    s = SyntheticScene(SceneConfig(**SMALL, decoy_distance_car_lengths=3.0), seed=5)
    assert s.decoy_distances().min() == pytest.approx(3.0 * 4.5, abs=0.05)
    off = SyntheticScene(SceneConfig(**SMALL, decoy=False), seed=5)
    assert "decoy_pass" not in off.events and off.frame(0).decoy is None


def test_sensor_noise_level(scene):
    noisy = scene.frame(10).image.astype(float)
    clean = scene.render(10, add_noise=False).astype(float)
    diff = noisy - clean
    assert abs(diff.mean()) < 0.1
    assert diff.std() == pytest.approx(4.0, rel=0.1)


# ---- config and spec -------------------------------------------------------------------------------

@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(noise_sigma=-1.0), "noise_sigma"),
        (dict(smoke_duration_s=20.0), "smoke_duration_s"),
        (dict(n_frames=30, smoke_duration_s=1.5), "smoke_duration_s"),
        (dict(decoy_distance_car_lengths=0.2), "decoy_distance_car_lengths"),
        (dict(width=10), "width"),
        (dict(fps=0), "fps"),
        (dict(wall_cover_fraction=1.5), "wall_cover_fraction"),
        (dict(target_color=(300, 0, 0)), "target_color"),
        (dict(no_such_field=1), "no_such_field"),
    ],
)
def test_config_validation_errors_are_clear(kwargs, field):
    with pytest.raises(ValidationError) as err:
        SceneConfig(**kwargs)
    assert field in str(err.value)
    assert isinstance(err.value, ValueError)


def test_smoke_longer_than_run_message_explains_the_limit():
    with pytest.raises(ValueError, match=r"smoke_duration_s=20 s is too long.*at most 2.5 s"):
        SceneConfig(smoke_duration_s=20.0)


def test_config_is_frozen():
    cfg = SceneConfig()
    with pytest.raises(ValidationError):
        cfg.noise_sigma = 1.0


def test_bad_seed_rejected():
    with pytest.raises(ValueError, match="seed"):
        SyntheticScene(SceneConfig(**SMALL), seed=-1)


def test_from_spec(monkeypatch):
    seen = []

    def fake_init(self, config=None, seed=0):
        seen.append(seed)

    monkeypatch.setattr(SyntheticScene, "__init__", fake_init)
    SyntheticScene.from_spec("synthetic")
    SyntheticScene.from_spec("synthetic:7")
    SyntheticScene.from_spec(" synthetic:12 ")
    assert seen == [0, 7, 12]
    for bad in ["", "synthetic:", "synthetic:x", "synthetic:-1", "video:3", "synthetic:1:2", "synth"]:
        with pytest.raises(ValueError, match="synthetic:SEED"):
            SyntheticScene.from_spec(bad)


def test_from_spec_builds_the_seeded_scene(small):
    s = SyntheticScene.from_spec("synthetic:3", SceneConfig(**SMALL))
    assert s.seed == 3 and np.array_equal(s.frame(2).image, small.frame(2).image)


# ---- ground texture ---------------------------------------------------------------------------------

def test_missing_texture_image_falls_back_with_warning():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        s = SyntheticScene(SceneConfig(**SMALL, texture_image="/nonexistent/aero.jpg"), seed=1)
    assert any("texture_image" in str(w.message) for w in caught)
    plain = SyntheticScene(SceneConfig(**SMALL), seed=1)
    assert np.array_equal(s.frame(0).image, plain.frame(0).image)


@pytest.mark.skipif(not AERO.is_file(), reason="shared aerial photo not present")
def test_texture_image_is_used_when_present():
    s = SyntheticScene(SceneConfig(**SMALL, texture_image=str(AERO)), seed=1)
    plain = SyntheticScene(SceneConfig(**SMALL), seed=1)
    assert not np.array_equal(s.frame(0).image, plain.frame(0).image)
    assert s.truth(0) == plain.truth(0)  # the ground does not change the truth


def test_a_long_scene_keeps_the_target_in_view():
    """A 5-minute scene: the camera follows the car however far it drives (the car's path spans
    kilometres; half-following its mean had left the car ~40 km off the image in the soak's
    scene). The 300-frame scenes are unchanged: their paths never reach the camera's limit."""
    from common.sources import open_source

    scene = open_source("synthetic:0:9000").scene
    w, h = scene.size
    centres = np.array([scene.truth(i).image_xy for i in range(0, len(scene), 50)])
    span = np.ptp(np.array([scene.truth(i).world_xy for i in range(0, len(scene), 50)]), axis=0)
    assert span.max() > 1000  # the car drives more than a kilometre
    inside = (centres[:, 0] > 0) & (centres[:, 0] < w) & (centres[:, 1] > 0) & (centres[:, 1] < h)
    assert inside.all(), centres[~inside][:5]
