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
