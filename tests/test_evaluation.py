"""Evaluation metrics and the occlusion-recovery rule, against hand-computed answers."""

import numpy as np
import pytest

from common.evaluation import centre_errors, recovered, reemergence_frame, score_run


def test_precision_auc_mean():
    errors = np.array([0.0, 5.0, 19.9, 20.0, 35.0, 100.0, np.nan])
    visible = np.array([True, True, True, True, True, True, False])
    sc = score_run(errors, visible)
    assert sc.precision20 == pytest.approx(4 / 6)
    assert sc.visible_frames == 6 and sc.frames == 7
    assert sc.mean_err == pytest.approx(np.mean([0, 5, 19.9, 20, 35, 100]))
    # AUC by hand: for t in 0..50, count errors <= t
    expected = np.mean([np.sum(np.array([0, 5, 19.9, 20, 35, 100]) <= t) / 6 for t in range(51)])
    assert sc.auc50 == pytest.approx(expected)
    # a lost track (NaN estimate) on a visible frame counts as a miss
    sc2 = score_run(np.array([1.0, np.nan]), np.array([True, True]))
    assert sc2.precision20 == 0.5


def test_centre_errors():
    e = centre_errors(np.array([[0.0, 0.0], [3.0, 4.0]]), np.array([[0.0, 0.0], [0.0, 0.0]]))
    assert e.tolist() == [0.0, 5.0]


def test_recovery_rule():
    vf = np.r_[np.ones(10), np.zeros(10), np.linspace(0.1, 1.0, 10), np.ones(20)]
    re = reemergence_frame(vf, (10, 20))
    assert re == 24  # first frame at or after the smoke with at least half the car visible
    e = np.full(50, 50.0)
    e[30:] = 3.0  # back under 10 px six frames after re-emergence, and stays
    assert recovered(e, re)
    e2 = e.copy()
    e2[33] = 40.0  # a sweep past the target: not a recovery
    assert not recovered(e2, re)
    e3 = np.full(50, 50.0)
    e3[36:] = 3.0  # too late (12 frames)
    assert not recovered(e3, re)
    assert not recovered(e, None)
