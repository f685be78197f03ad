"""dtcwt runs on NumPy 2 through common.dtcwt_compat, with its known numerical behaviour."""

import numpy as np
import pytest

from common import dtcwt_compat
from common.dtcwt_compat import dtcwt


def test_numpy_is_2():
    assert int(np.__version__.split(".")[0]) >= 2


def test_shims_have_numpy1_semantics():
    a = dtcwt_compat.asfarray([1, 2, 3])
    assert a.dtype == np.float64 and a.tolist() == [1.0, 2.0, 3.0]
    f32 = np.zeros(3, np.float32)
    assert dtcwt_compat.asfarray(f32, dtype=f32.dtype).dtype == np.float32
    # an integer dtype request falls back to float64, as NumPy 1 did
    assert dtcwt_compat.asfarray([1], dtype=np.int32).dtype == np.float64
    assert dtcwt_compat.issubsctype(np.float32, np.float32)
    assert dtcwt_compat.issubsctype(np.complex64, np.complexfloating)
    assert not dtcwt_compat.issubsctype(np.float64, np.complex128)


def test_standard_filters_reconstruct_perfectly():
    rng = np.random.default_rng(1)
    img = rng.random((64, 96))
    t = dtcwt.Transform2d()  # standard near_sym_a / qshift_a: perfect reconstruction
    pyr = t.forward(img, nlevels=4)
    assert [h.shape for h in pyr.highpasses] == [(32, 48, 6), (16, 24, 6), (8, 12, 6), (4, 6, 6)]
    rec = t.inverse(pyr)
    assert np.max(np.abs(rec - img)) < 1e-10


def test_forward_matches_known_values():
    # A constant image: every highpass vanishes (the bandpass filters have zero mean) and the
    # lowpass is the constant times the product of the lowpass filter gains, computed here
    # from the filter taps themselves.
    from dtcwt.coeffs import biort, qshift

    h0o = biort("near_sym_a")[0]
    h0a = qshift("qshift_a")[0]
    img = np.full((64, 64), 3.0)
    pyr = dtcwt.Transform2d().forward(img, nlevels=2)
    assert pyr.highpasses[0].dtype == np.complex128
    for h in pyr.highpasses:
        assert np.max(np.abs(h)) < 1e-6  # taps are stored to ~1e-8
    expected = 3.0 * (np.sum(h0o) ** 2) * (np.sum(h0a) ** 2)
    assert np.allclose(pyr.lowpass, expected, rtol=1e-12)
    assert expected == pytest.approx(6.0)  # gains: 1 per level-1 axis, sqrt(2) per qshift axis


def test_bp_filters_load():
    t = dtcwt.Transform2d(biort=dtcwt_compat.BIORT, qshift=dtcwt_compat.QSHIFT)
    pyr = t.forward(np.random.default_rng(2).random((64, 64)).astype(np.float32), nlevels=3)
    assert pyr.highpasses[2].shape == (8, 8, 6)
    assert pyr.highpasses[0].dtype == np.complex64
