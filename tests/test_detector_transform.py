"""The OpenCV DTCWT (levels 2-5) equals dtcwt's own forward transform."""

import numpy as np
import pytest

from common.detector.transform import highpasses
from common.dtcwt_compat import BIORT, QSHIFT, dtcwt


@pytest.mark.parametrize("shape", [(96, 160, 3), (64, 64, 1), (128, 96, 2)])
def test_matches_dtcwt(shape):
    rng = np.random.default_rng(3)
    img = rng.random(shape).astype(np.float32) * 255
    mine = highpasses(img, nlevels=5, first=2)
    t = dtcwt.Transform2d(biort=BIORT, qshift=QSHIFT)
    for c in range(shape[2]):
        ref = t.forward(img[:, :, c], nlevels=5).highpasses
        for level in range(2, 6):
            r = ref[level - 1]
            m = mine[level][:, :, c, :]
            assert m.shape == r.shape
            assert np.max(np.abs(m - r)) <= 2e-5 * np.max(np.abs(r))


def test_grey_input_and_bad_size():
    img = np.random.default_rng(0).random((64, 64)).astype(np.float32)
    out = highpasses(img)
    assert out[2].shape == (16, 16, 1, 6)
    with pytest.raises(ValueError, match="multiple of 32"):
        highpasses(np.zeros((70, 64), np.float32))


def test_negative_control_wrong_filters_differ():
    # The standard filters give a different transform: the equality test above can fail.
    img = np.random.default_rng(1).random((64, 64)).astype(np.float32)
    mine = highpasses(img)[3][:, :, 0, :]
    ref = dtcwt.Transform2d().forward(img, nlevels=5).highpasses[2]
    assert np.max(np.abs(mine - ref)) > 0.05 * np.max(np.abs(ref))


def test_q2c_equals_the_complex64_expression():
    """The real-arithmetic q2c gives exactly dtcwt's complex expression in float32."""
    from common.detector.transform import _SQRT_HALF, _q2c

    y = (np.random.default_rng(5).standard_normal((64, 48, 3)) * 100).astype(np.float32)
    p = (y[0::2, 0::2] + 1j * y[0::2, 1::2]) * _SQRT_HALF
    q = (y[1::2, 1::2] - 1j * y[1::2, 0::2]) * _SQRT_HALF
    lo, hi = _q2c(y)
    assert lo.dtype == hi.dtype == np.complex64
    assert np.array_equal(lo, (p - q).astype(np.complex64))
    assert np.array_equal(hi, (p + q).astype(np.complex64))
