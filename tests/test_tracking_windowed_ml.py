"""Windowed maximum-likelihood baseline (Nelson 2008 §III-A, Pang 2010 §8)."""

import numpy as np
import pytest

from common.tracking import InitialState, WindowedML, WindowedMLConfig
from common.tracking.testing import GaussianBumpObservation, RecordingObservation, constant_velocity_scene

OCCLUDED = range(30, 35)


def _run(cfg=None, occluded=OCCLUDED, n=60):
    # 30 px/s at 30 frames/s: a slowly moving bump, turning 15 deg/s
    scene = constant_velocity_scene(
        n, 1.0 / 30.0, (60.0, 100.0), (30.0, 7.5), occluded_frames=occluded, turn_rate_deg_s=15.0
    )
    f = WindowedML(cfg or WindowedMLConfig(), InitialState(x=60.0, y=100.0))
    states, calls, sizes = [], [], []
    for fr in scene:
        rec = RecordingObservation(fr.observation)
        states.append(f.step(fr.time, rec))
        calls.append(rec.calls)
        sizes.append(f.window_size)
    return scene, states, calls, sizes


def test_follows_a_slow_bump_and_widens_the_window_when_lost():
    scene, states, calls, sizes = _run()
    err = np.array([np.hypot(*(s.map_estimate.image_xy - fr.image_xy)) for s, fr in zip(states, scene)])
    visible = [i for i in range(len(scene)) if i not in OCCLUDED]
    assert err[visible].max() <= 2.0  # integer-pixel search, plus the clutter
    # orientation: the best of the 48 angles (7.5 deg apart), within one step of the truth
    for i in visible:
        assert abs((states[i].orientation - scene[i].theta + 180) % 360 - 180) <= 7.5
        assert states[i].p_visible == 1.0 and states[i].score >= 0.6
    # one batched score_grid call per frame; a locked 25x25 window is 625 points at 48 angles
    assert all(len(c) == 1 and c[0][0] == "score_grid" for c in calls)
    assert calls[0][0][1] == (625, 2)
    # below threshold in the occlusion: the next window doubles each frame, capped at max_window_px
    assert [states[i].p_visible for i in OCCLUDED] == [0.0] * len(OCCLUDED)
    assert all(states[i].score < 0.6 for i in OCCLUDED)
    assert sizes[OCCLUDED.start - 1] == 25
    assert sizes[OCCLUDED.start : OCCLUDED.stop] == [50, 100, 200, 200, 200]
    assert [states[i].search_window[2] for i in OCCLUDED] == [25, 50, 100, 200, 200]
    # a doubled window keeps 25 x 25 points at twice the spacing
    assert calls[OCCLUDED.start + 1][0][1] == (625, 2)
    pts = calls[OCCLUDED.start + 1][0][2]
    assert np.ptp(pts[:, 0]) >= 46 and np.all(np.diff(np.unique(pts[:, 0])) == 2)  # side 50: stride 2
    # while lost the position is extrapolated from the last two positions (about 1 px/frame here)
    for i in OCCLUDED:
        assert err[i] < 3.0
        assert states[i].search_window[:2] != states[OCCLUDED.start - 1].search_window[:2]
    # re-acquired on the first visible frame after the occlusion, and the window narrows again
    assert states[OCCLUDED.stop].p_visible == 1.0 and err[OCCLUDED.stop] <= 2.0
    assert sizes[OCCLUDED.stop] == 25
    assert states[-1].map_estimate == states[-1].mmse_estimate
    # velocity from integer-pixel differences: noisy per frame, right on average
    assert np.mean([s.map_estimate.vx for s in states[-20:]]) == pytest.approx(30.0, abs=4.0)
    assert np.mean([s.map_estimate.vy for s in states[-20:]]) == pytest.approx(7.5, abs=4.0)


def test_threshold_decides_lock():
    # with an impossible threshold every frame is "lost": windows keep doubling and the track coasts
    scene, states, _, sizes = _run(WindowedMLConfig(threshold=1.5, max_window_px=120), occluded=(), n=6)
    assert sizes == [50, 100, 120, 120, 120, 120]
    assert all(s.p_visible == 0.0 for s in states)
    assert all(np.allclose(s.map_estimate.image_xy, [60.0, 100.0]) for s in states)  # no velocity yet: stays


def test_angle_window_restricts_theta_when_locked():
    obs = GaussianBumpObservation(time=0.0, target_xy=(100.0, 100.0), target_theta=90.0, clutter=0.0)
    f = WindowedML(WindowedMLConfig(angle_window_deg=15.0, threshold=0.0), InitialState(x=100.0, y=100.0))
    s = f.step(0.0, obs)
    assert abs(s.orientation) <= 15.0  # only angles near the previous theta (0) are searched
    g = WindowedML(WindowedMLConfig(), InitialState(x=100.0, y=100.0))
    assert g.step(0.0, obs).orientation == 90.0


def test_no_observation_coasts_and_window_is_cut_to_the_image():
    f = WindowedML(WindowedMLConfig(), InitialState(x=3.0, y=4.0, time=0.0))
    obs = GaussianBumpObservation(time=0.1, target_xy=(3.0, 4.0), image_size=(320, 240))
    rec = RecordingObservation(obs)
    s = f.step(0.1, rec)
    n_points = rec.calls[0][1][0]
    assert n_points == (3 + 13) * (4 + 13)  # the 25x25 window about (3, 4) cut at x >= 0, y >= 0
    s2 = f.step(0.2, None)
    assert not s2.observed and s2.score is None and s2.search_window is None
    assert np.array_equal(s2.map_estimate.image_xy, s.map_estimate.image_xy)  # v = 0: stays put
    assert np.isnan(s2.n_eff) and s2.particles is None
