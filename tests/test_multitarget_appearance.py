"""Colour-histogram evidence: the integral-histogram answers equal direct per-box histograms."""

import numpy as np
import pytest

from common.multitarget.appearance import HistogramConfig, HistogramEvidence, bhattacharyya, bin_image, part_boxes
from common.scene.people import PeopleScene, PeopleSceneConfig


def test_batched_similarity_equals_direct_histograms():
    img = PeopleScene(PeopleSceneConfig(n_people=3, n_frames=10), seed=0).frame(5).image
    cfg = HistogramConfig()
    ev = HistogramEvidence(img, cfg)
    bins = bin_image(img, cfg)
    rng = np.random.default_rng(1)
    c = rng.uniform([-10, -10], [394, 298], size=(300, 2))
    boxes = part_boxes(c, rng.uniform(2, 60, size=(300, 2)))
    refs = ev.histograms(part_boxes(np.array([[150.0, 200.0], [220.0, 180.0]]), np.array([[20.0, 30.0]] * 2)))
    ref_idx = rng.integers(0, 2, 300)
    got = ev.similarity(boxes, refs, ref_idx)  # one batched call
    h, w = bins.shape
    for q in range(300):
        x0, y0, x1, y1 = np.clip(np.rint(boxes[q]).astype(int), 0, [w, h, w, h])
        counts = np.bincount(bins[y0:max(y1, y0), x0:max(x1, x0)].ravel(), minlength=cfg.n_bins).astype(float)
        if counts.sum() == 0:
            assert got[q] == 0.0
            continue
        assert got[q] == pytest.approx(bhattacharyya(counts / counts.sum(), refs[ref_idx[q]]), abs=1e-5)


def test_bad_image_is_refused():
    with pytest.raises(ValueError, match="uint8 RGB"):
        HistogramEvidence(np.zeros((10, 10), np.uint8))


@pytest.mark.parametrize("n_bins", [1, 40, 600])  # 600: past OpenCV's 512 channels, the NumPy path
def test_integral_histogram_counts_every_box(n_bins):
    from common.multitarget.appearance import integral_histogram

    rng = np.random.default_rng(n_bins)
    bins = rng.integers(0, n_bins, (23, 31)).astype(np.int32)
    ii = integral_histogram(bins, n_bins)
    assert ii.shape == (24, 32, n_bins) and ii.dtype == np.int32
    for y0, x0, y1, x1 in [(0, 0, 23, 31), (3, 5, 9, 30), (10, 10, 11, 11), (7, 2, 7, 9)]:
        want = np.bincount(bins[y0:y1, x0:x1].ravel(), minlength=n_bins)
        got = ii[y1, x1] - ii[y0, x1] - ii[y1, x0] + ii[y0, x0]
        assert np.array_equal(got, want)
