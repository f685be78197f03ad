"""Nelson 2008 SIR filter with sampled visibility."""

import numpy as np
import pytest

from common.tracking import SIR, ExponentialScoreLikelihood, InitialState, SIRConfig, VisibilityMarkovChain
from common.tracking.testing import GaussianBumpObservation, RecordingObservation, constant_velocity_scene

OCCLUDED = range(40, 55)


def _scene():
    # Nelson's T = 1/30 s; the target moves 40, 10 px/s and turns 10 deg/s, hidden for half a second
    return constant_velocity_scene(
        90, 1.0 / 30.0, (60.0, 100.0), (40.0, 10.0), occluded_frames=OCCLUDED, turn_rate_deg_s=10.0, sigma_px=5.0
    )


def _errors(states, scene):
    return np.array([np.hypot(*(s.mmse_estimate.image_xy - fr.image_xy)) for s, fr in zip(states, scene)])


@pytest.mark.parametrize("score_scale", [False, True])
def test_sir_tracks_through_occlusion(score_scale):
    scene = _scene()
    cfg = SIRConfig(likelihood=ExponentialScoreLikelihood(nv_c_on_score_scale=score_scale))  # Table I otherwise
    f = SIR(cfg, InitialState(x=60.0, y=100.0), seed=11)
    states = [f.step(fr.time, fr.observation) for fr in scene]
    err = _errors(states, scene)
    map_err = np.array([np.hypot(*(s.map_estimate.image_xy - fr.image_xy)) for s, fr in zip(states, scene)])
    assert err[: OCCLUDED.start].max() < 6.0 and np.median(err[: OCCLUDED.start]) < 3.0
    assert err[OCCLUDED.stop + 5 :].max() < 3.0
    assert map_err[OCCLUDED.stop + 5 :].max() < 4.0
    pv = np.array([s.p_visible for s in states])
    assert pv[: OCCLUDED.start].min() > 0.9 and pv[OCCLUDED.stop + 5 :].min() > 0.9
    # visibility is sampled: each particle carries V in {0, 1} and p_visible is their weighted mean
    for s in states:
        assert set(np.unique(s.particle_visibility)) <= {0.0, 1.0}
        assert s.p_visible == pytest.approx(float(s.weights @ s.particle_visibility), abs=1e-12)
    # with eq. 15 as printed (exp(NV_c) = e^0.2 against exp(5 * ~0) on clutter) the visibility posterior
    # falls only to about the chain's stationary P_V / (P_V + P_NV) = 0.71; with NV_c on the score scale
    # (exp(5 * 0.2)) it collapses
    occluded_pv = pv[OCCLUDED.start + 5 : OCCLUDED.stop].max()
    assert occluded_pv < (0.85 if not score_scale else 0.35)
    assert abs((states[-1].mmse_estimate.theta - scene[-1].theta + 180) % 360 - 180) < 8.0


def test_sir_deterministic_and_one_call_per_frame():
    scene = _scene()[:20]
    init = InitialState(x=60.0, y=100.0, p_visible=0.7, pos_std=1.0)
    runs = []
    for seed in (4, 4, 5):
        f = SIR(SIRConfig(n_particles=77), init, seed=seed)
        out = []
        for fr in scene:
            rec = RecordingObservation(fr.observation)
            out.append(f.step(fr.time, rec))
            assert rec.calls == [("score_at", (77, 3))]
        runs.append(out)
    assert all(a.identical(b) for a, b in zip(runs[0], runs[1]))
    assert not any(a.identical(c) for a, c in zip(runs[0], runs[2]))


def test_sir_weight_update_is_eq_15():
    """One step from equal weights, no motion: w_p ∝ exp(k s_p) if V_p = 1 else exp(NV_c) (as printed)."""
    cfg = SIRConfig(n_particles=64, visibility=VisibilityMarkovChain(p_nv=0.5, p_v=0.5),
                    likelihood=ExponentialScoreLikelihood(nv_c_on_score_scale=False))
    f = SIR(cfg, InitialState(x=100.0, y=100.0, pos_std=6.0, p_visible=0.5, time=0.0), seed=2)
    obs = GaussianBumpObservation(time=0.0, target_xy=(100.0, 100.0))
    s = f.step(0.0, obs)  # zero elapsed time: no prediction
    scores, _ = obs.score_at(np.column_stack([s.particles_image, s.particles[:, 4]]))
    v = s.particle_visibility
    ref = np.where(v == 1.0, 5.0 * scores, 0.2)
    ref = np.exp(ref - ref.max())
    assert 0 < v.sum() < 64  # some of each
    assert np.allclose(s.weights, ref / ref.sum(), rtol=1e-12)


def test_sir_step_without_observation():
    f = SIR(SIRConfig(), InitialState(x=50.0, y=50.0, vx=10.0, time=0.0), seed=0)
    s = f.step(1.0, None)
    assert not s.observed and s.score is None
    assert np.allclose(s.weights, 1.0 / 300)
    assert s.mmse_estimate.x == pytest.approx(60.0, abs=3.0)
    # visibility was propagated through the chain: about 1 - P_NV of the particles stay visible
    assert s.p_visible == pytest.approx(0.9, abs=0.06)
