"""Camera-motion estimation (common.single_target.stabilise): accuracy on a known warp, determinism, fallbacks."""

import cv2
import numpy as np
import pytest

from common.single_target.stabilise import CameraMotionEstimator, StabiliserConfig
from common.tracking.camera import apply_homography
from imagegen import DATA


def _texture(h=360, w=480, seed=0) -> np.ndarray:
    """A real aerial photograph when the shared data is there, else smooth random texture."""
    path = DATA / "opencv-aerial" / "aero1.jpg"
    if path.exists():
        img = cv2.imread(str(path))[:, :, ::-1]
        return np.ascontiguousarray(cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA))
    rng = np.random.default_rng(seed)
    noise = rng.uniform(0, 255, (h // 8, w // 8, 3)).astype(np.float32)
    return np.clip(cv2.resize(noise, (w, h), interpolation=cv2.INTER_CUBIC), 0, 255).astype(np.uint8)


def _known_warp(w, h) -> np.ndarray:
    """A shift of (6.3, -4.2) px, a 2.5 degree rotation about the centre and a mild perspective."""
    g = np.vstack([cv2.getRotationMatrix2D((w / 2, h / 2), 2.5, 1.01), [0, 0, 1]])
    g[0, 2] += 6.3
    g[1, 2] -= 4.2
    g[2, 0] = 2e-5
    return g / g[2, 2]


def _warp(img, g):
    h, w = img.shape[:2]
    return cv2.warpPerspective(img, g, (w, h), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)


def _grid(w, h, margin=40, step=20):
    return np.array([(x, y) for x in range(margin, w - margin, step) for y in range(margin, h - margin, step)], float)


def test_recovers_a_known_homography():
    img = _texture()
    h, w = img.shape[:2]
    g = _known_warp(w, h)
    est = CameraMotionEstimator()
    assert np.array_equal(est.start(img), np.eye(3))
    hom = est.update(_warp(img, g))
    pts = _grid(w, h)
    err = np.linalg.norm(apply_homography(hom, pts) - apply_homography(g, pts), axis=1)
    assert err.max() < 0.5, err.max()
    assert est.fallbacks == 0 and est.last.inliers >= 50
    # accumulated over two frames: world -> image is the composition
    hom2 = est.update(_warp(_warp(img, g), g))
    err2 = np.linalg.norm(apply_homography(hom2, pts) - apply_homography(g @ g, pts), axis=1)
    assert err2.max() < 1.0, err2.max()


@pytest.mark.parametrize("model", ["affine", "similarity"])
def test_simpler_models_recover_a_rigid_shift(model):
    img = _texture()
    h, w = img.shape[:2]
    g = np.vstack([cv2.getRotationMatrix2D((w / 2, h / 2), -1.5, 1.0), [0, 0, 1]])
    g[0, 2] += 3.7
    est = CameraMotionEstimator(StabiliserConfig(model=model))
    est.start(img)
    hom = est.update(_warp(img, g))
    pts = _grid(w, h)
    assert np.abs(apply_homography(hom, pts) - apply_homography(g, pts)).max() < 0.5


def test_excluded_disc_gets_no_features():
    img = _texture()
    h, w = img.shape[:2]
    shift = np.array([[1, 0, 2.0], [0, 1, 1.0], [0, 0, 1]])
    centre, radius = np.array([w / 2, h / 2]), 80.0
    est = CameraMotionEstimator()
    est.start(img)
    est.update(_warp(img, shift))
    assert np.sum(np.linalg.norm(est.last_points - centre, axis=1) < radius) > 5  # corners there ...
    est.start(img)
    est.update(_warp(img, shift), exclude_xy=centre, exclude_radius=radius)
    d = np.linalg.norm(est.last_points - centre, axis=1)
    assert len(d) > 50 and d.min() >= radius - 1.0  # ... not used when excluded


def test_bit_identical_on_the_same_frames():
    img = _texture()
    h, w = img.shape[:2]
    g = _known_warp(w, h)
    frames = [img, _warp(img, g), _warp(_warp(img, g), g)]

    def run():
        est = CameraMotionEstimator()
        out = [est.start(frames[0])]
        for f in frames[1:]:
            out.append(est.update(f, exclude_xy=(w / 2, h / 2), exclude_radius=30.0))
        return out

    a, b = run(), run()
    for x, y in zip(a, b):
        assert x.tobytes() == y.tobytes()


def test_too_few_features_keeps_the_previous_motion():
    img = _texture()
    h, w = img.shape[:2]
    shift = np.array([[1, 0, 5.0], [0, 1, -3.0], [0, 0, 1]])
    est = CameraMotionEstimator()
    est.start(img)
    h1 = est.update(_warp(img, shift))
    assert est.fallbacks == 0
    flat = np.full_like(img, 128)  # no corner at all
    h2 = est.update(flat)
    assert est.fallbacks == 1 and est.last.fallback
    assert est.last.features == 0
    # the previous frame-to-frame motion is applied again: the camera keeps moving as it did
    expect = est.last.interframe @ h1
    np.testing.assert_allclose(h2, expect / expect[2, 2], atol=1e-9)
    np.testing.assert_allclose(est.last.interframe, h1, atol=0.05)
    # an implausible estimate (a 2x zoom in one frame) is rejected the same way
    est2 = CameraMotionEstimator()
    est2.start(img)
    zoom = np.array([[2.0, 0, -w / 2], [0, 2.0, -h / 2], [0, 0, 1]])
    est2.update(_warp(img, zoom))
    assert est2.fallbacks == 1
    np.testing.assert_allclose(est2.homography, np.eye(3))


def test_same_homographies_whatever_opencv_thread_count(tmp_path):
    """cv2.setNumThreads is process-wide, so each count runs in its own process."""
    import subprocess
    import sys

    script = tmp_path / "run.py"
    script.write_text(
        "import sys, hashlib, cv2, numpy as np\n"
        "cv2.setNumThreads(int(sys.argv[1]))\n"
        "sys.path.insert(0, sys.argv[2])\n"
        "from test_stabilise import _texture, _known_warp, _warp\n"
        "from common.single_target.stabilise import CameraMotionEstimator\n"
        "img = _texture(); g = _known_warp(img.shape[1], img.shape[0])\n"
        "est = CameraMotionEstimator(); est.start(img)\n"
        "h = est.update(_warp(img, g), exclude_xy=(240, 180), exclude_radius=30)\n"
        "print(hashlib.sha1(h.tobytes()).hexdigest())\n")
    tests_dir = str(__import__("pathlib").Path(__file__).parent)
    out = {subprocess.run([sys.executable, str(script), str(n), tests_dir], capture_output=True, text=True,
                          check=True).stdout.strip() for n in (1, 4)}
    assert len(out) == 1


def test_a_portrait_frame_is_analysed_as_the_same_frame_turned_landscape():
    """The working resolution follows the frame's long side, so a camera held portrait is stabilised
    as the same footage turned landscape: the frame pair and its 90-degree turn give the same
    features (turned) and the same camera motion (turned). Analysed by width, as before, the
    720 x 1280 frame was worked at 1.8 times the resolution of the 1280 x 720 one: other corners,
    other windows and thresholds."""
    img = _texture(720, 1280)
    h, w = img.shape[:2]
    g = _known_warp(w, h)
    nxt = _warp(img, g)
    land = CameraMotionEstimator()
    land.start(img)
    hom = land.update(nxt)
    turn = lambda a: np.ascontiguousarray(np.rot90(a, -1))  # noqa: E731  clockwise: (x, y) -> (h - 1 - y, x)
    port = CameraMotionEstimator()
    port.start(turn(img))
    hom_p = port.update(turn(nxt))
    to_port = np.array([[0.0, -1.0, h - 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    pts = _grid(w, h, margin=80, step=40)
    # the same camera motion, turned
    moved = apply_homography(np.linalg.inv(to_port) @ hom_p @ to_port, pts)
    assert np.abs(moved - apply_homography(hom, pts)).max() < 0.3
    # the same corners, turned: most of the landscape frame's features have one within 1.5 px (a working
    # pixel maps to full resolution at its corner, so turned it lands a full-resolution pixel away)
    a = land.last_points
    b = apply_homography(np.linalg.inv(to_port), port.last_points)
    near = np.min(np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2), axis=1) < 1.5
    assert len(a) >= 50 and abs(len(a) - len(b)) <= 0.1 * len(a) and near.mean() > 0.8, (len(a), len(b), near.mean())
