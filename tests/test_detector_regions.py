"""Region-of-interest preparation, support flags, bad input, template files, the frame cache."""

import numpy as np
import pytest

from common.detector import FrameCache, PolarMatcher, Template, prepare_frame
from common.detector.frame import KERNEL_MARGIN_PX
from common.detector.layout import SUBBAND_FREQ, SUPPORT_RADIUS_PX
from imagegen import blob_image


@pytest.fixture(scope="module")
def frame():
    rng = np.random.default_rng(0)
    base = blob_image(0, size=512, n=400, channels=3, seed=11)
    return base + rng.normal(0, 0.02, base.shape)


def _region_coefficients(full, roi, level):
    """The region's coefficients and the full frame's over the same samples, with the
    region's local demodulation phase converted to the full frame's."""
    s = 2**level
    x0, y0, x1, y1 = roi.region
    a = full.levels[level].coef[y0 // s:y1 // s, x0 // s:x1 // s]
    b_lv = roi.levels[level]
    ox, oy = b_lv.origin_px
    b = b_lv.coef[(y0 - oy) // s:(y1 - oy) // s, (x0 - ox) // s:(x1 - ox) // s]
    nch = full.channels
    # local index = global index - origin / s, so the local demodulation carries an extra phase
    ph = np.exp(-1j * (SUBBAND_FREQ[:, 0] * (ox // s) + SUBBAND_FREQ[:, 1] * (oy // s)))
    b = (b.reshape(*b.shape[:2], 6, nch) * ph[None, None, :, None]).reshape(b.shape)
    rms = np.sqrt(np.mean(np.abs(full.levels[level].coef) ** 2))
    return a, b, rms


def test_region_margin_rule(frame):
    """Margin rule: with KERNEL_MARGIN_PX = 64 transformed beyond the region, level 2-3
    coefficients inside the region match the full frame's to 1e-3 of the subband RMS, level 4
    to 5 percent and level 5 (whose kernels reach ~200 px) to 50 percent at the region's very
    edge; scores of in-support hypotheses agree to 0.005."""
    assert KERNEL_MARGIN_PX == 64
    full = prepare_frame(frame)
    roi = prepare_frame(frame, (200, 190, 330, 300))
    assert roi.region == (192, 160, 352, 320)  # rounded out to 32-px blocks
    limits = {2: 1e-3, 3: 1e-3, 4: 0.05, 5: 0.5}
    for level, limit in limits.items():
        a, b, rms = _region_coefficients(full, roi, level)
        assert a.shape == b.shape
        assert np.max(np.abs(a - b)) <= limit * rms, level
    matcher = PolarMatcher(Template.from_image(frame, (256.0, 256.0)))
    rng = np.random.default_rng(1)
    bx0, by0, bx1, by1 = roi.valid_box
    xyt = np.c_[rng.uniform(bx0, bx1, 200), rng.uniform(by0, by1, 200), rng.uniform(-180, 180, 200)]
    s_full, v_full = matcher.score_at(full, xyt)
    s_roi, v_roi = matcher.score_at(roi, xyt)
    assert v_full.all() and v_roi.all()
    assert np.max(np.abs(s_full - s_roi)) < 0.005


def test_region_without_margin_is_wrong(frame, monkeypatch):
    """Negative control: without the margin the region's coefficients are far off."""
    import common.detector.frame as fm

    monkeypatch.setattr(fm, "KERNEL_MARGIN_PX", 0)
    full = prepare_frame(frame)
    roi = prepare_frame(frame, (200, 190, 330, 300))
    a, b, rms = _region_coefficients(full, roi, 3)
    assert np.max(np.abs(a - b)) > 0.1 * rms


def test_region_at_frame_edge_is_exact(frame):
    """Where the region touches the frame edge, the crop is padded exactly as the full frame."""
    full = prepare_frame(frame[:500, :470])
    roi = prepare_frame(frame[:500, :470], (300, 300, 470, 500))
    for level in (2, 3):
        a, b, rms = _region_coefficients(full, roi, level)
        edge_a, edge_b = a[-3:, -3:], b[-3:, -3:]  # bottom-right corner, at the padded frame edge
        assert np.max(np.abs(edge_a - edge_b)) <= 1e-3 * rms


def test_out_of_support_hypotheses_are_flagged(frame):
    matcher = PolarMatcher(Template.from_image(frame, (256.0, 256.0)))
    prep = prepare_frame(frame)
    r = SUPPORT_RADIUS_PX
    xyt = np.array([
        [256.0, 256.0, 0.0],      # inside
        [r - 0.5, 256.0, 0.0],    # just too close to the left edge
        [r, 256.0, 0.0],          # exactly at the limit: in support
        [256.0, 511 - r + 0.5, 0.0],
        [-1000.0, 5.0, 10.0],     # far outside
        [1e9, 1e9, 0.0],
    ])
    s, valid = matcher.score_at(prep, xyt)
    assert valid.tolist() == [True, False, True, False, False, False]
    assert np.all(s[~valid] == 0.0)
    g, gv = matcher.score_grid(prep, xyt[:, :2])
    assert gv.tolist() == valid.tolist()
    assert np.all(g[~gv] == 0.0)
    # a region's support ends inside the region
    roi = prepare_frame(frame, (200, 200, 330, 330))
    s, valid = matcher.score_at(roi, np.array([[256.0, 256.0, 0.0], [150.0, 256.0, 0.0]]))
    assert valid.tolist() == [True, False]


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_coordinates_raise(frame, bad):
    matcher = PolarMatcher(Template.from_image(frame, (256.0, 256.0)))
    prep = prepare_frame(frame)
    with pytest.raises(ValueError, match="NaN or infinite"):
        matcher.score_at(prep, np.array([[256.0, 256.0, 0.0], [bad, 3.0, 0.0]]))
    with pytest.raises(ValueError, match="NaN or infinite"):
        matcher.score_grid(prep, np.array([[256.0, bad]]))
    with pytest.raises(ValueError, match="shape"):
        matcher.score_at(prep, np.zeros((4, 2)))


def test_template_save_load_roundtrip(frame, tmp_path):
    t = Template.from_image(frame, (250.5, 260.25), box=(230, 250, 41, 21))
    path = tmp_path / "car.npz"
    t.save(path)
    assert path.stat().st_size < 20_000
    u = Template.load(path)
    np.testing.assert_array_equal(u.pmatrix, t.pmatrix)
    assert u.centre == (250.5, 260.25) and u.box == (230, 250, 41, 21) and u.channels == 3
    prep = prepare_frame(frame)
    xyt = np.array([[250.5, 260.25, 0.0], [300.0, 200.0, 45.0]])
    np.testing.assert_array_equal(PolarMatcher(t).score_at(prep, xyt)[0], PolarMatcher(u).score_at(prep, xyt)[0])


def test_template_errors(frame, tmp_path):
    with pytest.raises(ValueError, match="too close to the edge"):
        Template.from_image(frame, (10.0, 256.0))
    with pytest.raises(ValueError, match="finite"):
        Template.from_image(frame, (np.nan, 256.0))
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a template")
    with pytest.raises(ValueError, match="not a PolarTrack template"):
        Template.load(bad)


def test_frame_cache_follows_the_cloud(frame):
    cache = FrameCache(max_frames=2)
    p1 = cache.get(1, frame, (250, 250, 260, 260))
    assert cache.preparations == 1
    assert cache.get(1, frame, (252, 252, 258, 258)) is p1  # inside: reused
    assert cache.preparations == 1
    p2 = cache.get(1, frame, (300, 250, 330, 262))  # moved: union prepared
    assert cache.preparations == 2 and p2.contains_box((250, 250, 330, 262))
    w = p2.region[2] - p2.region[0]
    assert w < 512  # still a region, not the whole frame
    cache.get(2, frame, (250, 250, 260, 260))
    cache.get(3, frame, (250, 250, 260, 260))
    assert 1 not in cache._items and len(cache._items) == 2  # bounded
