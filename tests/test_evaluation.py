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


def test_live_errors_score_an_estimate_that_arrives_before_its_truth():
    """``LiveErrors``: the same errors whichever of a frame's estimate and truth comes first; an
    estimate whose frame's truth never comes is let go, unscored, by a later frame's; a hidden target,
    or a frame without a truth (its info only), is NaN. Scored on arrival only, frame 2 would be NaN."""
    import math

    from common.evaluation import LiveErrors

    live = LiveErrors()
    live.truth(0, 10.0, 10.0, True)
    live.estimate(0, 13.0, 14.0)  # the usual order
    live.estimate(1, 0.0, 0.0)  # before frame 1's truth
    live.estimate(2, 20.0, 0.0)  # before frame 2's truth
    assert math.isnan(live.errors[1]) and math.isnan(live.errors[2])  # waiting
    live.truth(1, 0.0, 0.0, False)  # hidden: NaN, not 0
    live.truth(2, 20.0, 5.0, True)
    live.estimate(3, 1.0, 1.0)
    live.estimate(4, 1.0, 1.0)
    live.frame(3)  # a frame without a truth (a real video's)
    live.truth(5, 1.0, 1.0, True)  # frame 4's info never came: 5's lets it go, unscored
    live.estimate(5, 4.0, 5.0)
    e = live.errors
    assert e[0] == 5.0 and e[2] == 5.0 and e[5] == 5.0
    assert all(math.isnan(e[k]) for k in (1, 3, 4)) and sorted(e) == [0, 1, 2, 3, 4, 5]


def test_live_multi_errors_score_the_parts_whatever_the_order_and_keep_no_stale_truths():
    """``LiveMultiErrors`` (the launcher's multi-target summary): the mean distance over targets and
    parts, the same whichever of a frame's estimate and truth comes first (scored on arrival, as the
    launcher did before, frame 1 would be NaN); NaN where the estimate's targets are not the truth's
    people; a frame the tracker skipped leaves no truth behind once a later frame is scored."""
    import math

    import numpy as np

    from common.evaluation import LiveMultiErrors

    gt = np.zeros((2, 3, 2))  # two people, three parts
    est = gt.copy()
    est[0, :, 0] = 3.0  # person 0's parts 3 px right
    est[1, :, 1] = 4.0  # person 1's 4 px down: mean (3 + 4) / 2
    live = LiveMultiErrors()
    live.truth(0, gt)
    live.estimate(0, est)
    live.estimate(1, est)  # before frame 1's truth
    assert math.isnan(live.errors[1])
    live.truth(1, gt + [0.0, 4.0])  # person 0 now 5 px off, person 1 on the truth: mean 2.5
    live.truth(2, gt)  # frame 2: the tracker skips it
    live.truth(3, gt)
    live.estimate(3, est[:1])  # one target for two people: not comparable
    live.truth(4, gt)
    live.estimate(4, est)
    e = live.errors
    assert e[0] == 3.5 and e[1] == 2.5 and e[4] == 3.5
    assert math.isnan(e[3]) and sorted(e) == [0, 1, 3, 4]
    assert live._truths == {}  # frame 2's truth went with frame 3's estimate
