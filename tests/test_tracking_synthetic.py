"""The synthetic GaussianBumpObservation used by the tracker tests honours the FrameObservation protocol."""

import numpy as np

from common.tracking import GRID_ANGLES_DEG, FrameObservation
from common.tracking.testing import GaussianBumpObservation, constant_velocity_scene


def test_bump_observation_protocol_and_shape():
    obs = GaussianBumpObservation(time=1.0, target_xy=(100.0, 80.0), target_theta=30.0, clutter=0.05)
    assert isinstance(obs, FrameObservation)
    hyps = np.array([[100.0, 80.0, 30.0], [100.0, 80.0, 210.0], [130.0, 80.0, 30.0], [2.0, 80.0, 30.0]])
    s, v = obs.score_at(hyps)
    assert s.shape == (4,) and v.dtype == bool
    assert s[0] > 0.75 and s[0] > s[1] + 0.5 and s[0] > s[2] + 0.5  # peaked in position and angle
    assert not v[3] and s[3] == 0.0  # support leaves the frame
    assert np.all((s >= -1) & (s <= 1))
    occ = GaussianBumpObservation(time=1.0, target_xy=(100.0, 80.0), target_theta=30.0, occluded=True)
    assert abs(occ.score_at(hyps[:1])[0][0]) < 0.25


def test_score_grid_matches_score_at():
    obs = GaussianBumpObservation(time=0.0, target_xy=(60.0, 70.0), target_theta=-45.0, clutter=0.1)
    xy = np.array([[60.0, 70.0], [65.5, 72.0], [5.0, 5.0]])
    grid, valid = obs.score_grid(xy)
    assert grid.shape == (3, 48) and valid.tolist() == [True, True, False]
    for i in range(3):
        s, _ = obs.score_at(np.column_stack([np.repeat(xy[i : i + 1], 48, 0), GRID_ANGLES_DEG]))
        assert np.allclose(grid[i], s, atol=1e-12)
    assert GRID_ANGLES_DEG[int(np.argmax(grid[0]))] == 315.0  # -45 deg


def test_clutter_is_a_fixed_field_with_the_requested_spread():
    a = GaussianBumpObservation(time=0.0, target_xy=(0.0, 0.0), occluded=True, clutter=0.05)
    rng = np.random.default_rng(0)
    hyps = np.column_stack([rng.uniform(20, 300, 20000), rng.uniform(20, 220, 20000), rng.uniform(0, 360, 20000)])
    s1, _ = a.score_at(hyps)
    s2, _ = a.score_at(hyps)
    assert np.array_equal(s1, s2)
    assert 0.035 < s1.std() < 0.065 and abs(s1.mean()) < 0.01


def test_scene_helper():
    h = np.diag([2.0, 2.0, 1.0])
    scene = constant_velocity_scene(4, 0.5, (1.0, 2.0), (2.0, 0.0), occluded_frames={2}, homography=h)
    assert [fr.time for fr in scene] == [0.0, 0.5, 1.0, 1.5]
    assert np.allclose(scene[3].world, [4.0, 2.0, 2.0, 0.0]) and np.allclose(scene[3].image_xy, [8.0, 4.0])
    assert [fr.observation.occluded for fr in scene] == [False, False, True, False]
