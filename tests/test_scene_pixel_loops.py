"""The faster rendering pieces equal what they replace, bit for bit: the alpha-over loop against
the NumPy float32 expression, the sensor noise's random bytes against ``Generator.bytes``, and
whole frames against digests of the frames rendered before these changes."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from common.scene import SceneConfig, SyntheticScene
import cv2

from common.scene.noise import SensorNoise, random_bytes
from common.scene.pixel_loops import add_noise, alpha_over

# sha256 (first 16 hex digits) of frames of the default scene, rendered by the code before the
# alpha-over loop and the copy-free random bytes (commit 047fe72).
GOLDEN = {
    0: {0: "f71eac831051111e", 77: "9ccaeb4b74f2c13d", 150: "02ace237b12e5f22", 233: "c6a33ff35e0992dd"},
    5: {1: "c507d92011ec1171", 77: "882c969421d26acd", 233: "2a8de092d3fc704f", 299: "80e6b4f064a2af96"},
}


def _reference_alpha_over(roi: np.ndarray, rgba: np.ndarray) -> None:
    a = rgba[..., 3:4].astype(np.float32) * (1.0 / 255.0)
    out = roi.astype(np.float32) * (1.0 - a) + rgba[..., :3].astype(np.float32)
    roi[...] = np.clip(out + 0.5, 0, 255).astype(np.uint8)


def test_alpha_over_equals_the_float32_expression():
    rng = np.random.default_rng(7)
    img = rng.integers(0, 256, (97, 131, 3), dtype=np.uint8)
    alpha = rng.integers(0, 256, (60, 70, 1), dtype=np.uint8)
    alpha[:5] = 0
    alpha[5:10] = 255
    colour = (rng.integers(0, 256, (60, 70, 3)) * (alpha / 255.0)).astype(np.uint8)  # premultiplied
    rgba = np.concatenate([colour, alpha], axis=2)
    rgba[10:12, :, :3] = 255  # saturating sums
    want, got = img.copy(), img.copy()
    _reference_alpha_over(want[20:80, 30:100], rgba)
    alpha_over(got[20:80, 30:100], rgba)  # a non-contiguous view, written in place
    assert np.array_equal(want, got)


@pytest.mark.parametrize("n", [1, 3, 4, 5, 1280 * 720 * 3])
def test_random_bytes_equal_generator_bytes(n):
    a, b = np.random.default_rng([4, 2, n]), np.random.default_rng([4, 2, n])
    assert random_bytes(a, n).tobytes() == b.bytes(n)
    assert a.integers(0, 1 << 30) == b.integers(0, 1 << 30)  # the generators are left in the same state


def test_random_bytes_after_a_buffered_uint32_equal_generator_bytes():
    """A generator holding half a 64-bit output (after an odd number of uint32 draws) must not take
    the raw path: its next bytes start with the buffered half."""
    a, b = np.random.default_rng(11), np.random.default_rng(11)
    a.integers(0, 1 << 32, size=3, dtype=np.uint32)
    b.integers(0, 1 << 32, size=3, dtype=np.uint32)
    assert random_bytes(a, 4096).tobytes() == b.bytes(4096)
    assert a.integers(0, 1 << 30) == b.integers(0, 1 << 30)


def test_add_noise_equals_the_opencv_expression():
    rng = np.random.default_rng(3)
    img = rng.integers(0, 256, (50, 70, 3), dtype=np.uint8)
    img[:5], img[5:10] = 255, 0  # both saturations
    noise = SensorNoise(9.0)
    u = rng.integers(0, 256, img.shape, dtype=np.uint8)
    want = cv2.subtract(cv2.add(img, cv2.LUT(u, noise._pos)), cv2.LUT(u, noise._neg))
    got = np.empty_like(img)
    add_noise(img.reshape(-1), u.reshape(-1), noise._pos, noise._neg, got.reshape(-1))
    assert np.array_equal(want, got)
    assert not np.array_equal(got, img)  # the noise did something


@pytest.mark.parametrize("seed", sorted(GOLDEN))
def test_frames_equal_the_frames_rendered_before(seed):
    scene = SyntheticScene(SceneConfig(), seed=seed)
    for i, digest in GOLDEN[seed].items():
        assert hashlib.sha256(scene.frame(i).image.tobytes()).hexdigest()[:16] == digest, i
