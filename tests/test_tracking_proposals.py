"""The RBPF's two proposals beyond Pang: the orientation's locally optimal proposal from the 48-angle
scores, and K candidates per particle."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from common.detector import FrameCache, PolarMatcher, Template
from common.detector.observation import DetectorObservation
from common.tracking import RBPF, BetaRatioLikelihood, InitialState, RBPFConfig
from common.tracking.motion import NearConstantVelocity, OrientationRandomWalk, VisibilityMarkovChain
from common.tracking.orientation_proposal import curve_at, curve_coefficients, prior_nodes, sample_orientation
from common.tracking.testing import GaussianBumpObservation
from tests.imagegen import blob_image, rotate_about


@pytest.fixture(scope="module")
def real_observation():
    img = blob_image(0.0, size=256, seed=3)
    template = Template.from_image(img, (128.0, 128.0))
    rotated = rotate_about(img, (128.0, 128.0), 37.0)
    return DetectorObservation(0, 0.0, rotated, PolarMatcher(template), FrameCache(), None)


def test_score_curve_from_48_angles_is_exact_at_any_angle(real_observation):
    """The polar-matching score is band-limited (|h| <= 14): the 48 grid scores give it exactly."""
    rng = np.random.default_rng(0)
    xy = 128.0 + rng.uniform(-6, 6, size=(20, 2))
    grid, _ = real_observation.score_grid(xy)
    theta = rng.uniform(-180, 180, size=(20, 7))
    direct = np.stack([real_observation.score_at(np.column_stack([xy, theta[:, j]]))[0] for j in range(7)], axis=1)
    assert np.max(np.abs(curve_at(curve_coefficients(grid), theta) - direct)) < 1e-5
    # negative control: linear interpolation between grid angles is not exact
    k = theta / 7.5
    lo = np.floor(k).astype(int) % 48
    lin = (1 - (k - np.floor(k))) * np.take_along_axis(grid, lo, 1) + (k - np.floor(k)) * np.take_along_axis(
        grid, (lo + 1) % 48, 1)
    assert np.max(np.abs(lin - direct)) > 1e-3


def test_orientation_marginal_and_posterior_match_quadrature():
    """log m_p is the random walk's expectation of the visibility-marginal likelihood, and the sampled
    orientations follow g_j m_pj: checked against an independent fine quadrature."""
    lik = BetaRatioLikelihood(a1=5.69, b1=2.81, a0=0.25, b0=8.08)
    h = np.arange(15)
    rng = np.random.default_rng(1)
    coeffs = (rng.normal(size=15) + 1j * rng.normal(size=15)) * np.exp(-h / 3.0) * 0.3
    coeffs[0] = 0.3
    grid = curve_at(coeffs[None, :], (np.arange(48) * 7.5)[None, :])
    theta0, sigma = np.array([20.0]), 6.0
    log_pv = np.log([[0.3, 0.7]])
    n = 20000
    th, log_m, s, joint = sample_orientation(np.repeat(grid, n, 0), np.repeat(theta0, n), sigma,
                                             np.repeat(log_pv, n, 0), lik.log_likelihood, np.random.default_rng(2))
    # independent check: the same discrete prior, scores from the coefficients directly
    u, log_g = prior_nodes()
    nodes = theta0[0] + sigma * u
    sc = curve_at(coeffs[None, :], nodes[None, :])[0]
    ll = lik.log_likelihood(sc)
    m_j = np.exp(log_pv[0, 0] + ll[:, 0]) + np.exp(log_pv[0, 1] + ll[:, 1])
    expected = np.sum(np.exp(log_g) * m_j)
    assert np.allclose(np.exp(log_m), expected, rtol=1e-12)
    # ... which approximates the continuous Gaussian expectation closely
    fine = np.linspace(-6, 6, 4001)
    scf = curve_at(coeffs[None, :], (theta0[0] + sigma * fine)[None, :])[0]
    llf = lik.log_likelihood(scf)
    mf = np.exp(log_pv[0, 0] + llf[:, 0]) + np.exp(log_pv[0, 1] + llf[:, 1])
    cont = np.trapezoid(stats.norm.pdf(fine) * mf, fine)
    assert abs(expected / cont - 1) < 0.01
    # sampled nodes: frequencies against g_j m_j (chi-square)
    idx = np.rint((th - theta0[0]) / sigma * 4).astype(int) + len(u) // 2
    counts = np.bincount(idx, minlength=len(u))
    p = np.exp(log_g) * m_j
    p /= p.sum()
    keep = p * n > 5
    obs = np.append(counts[keep], counts[~keep].sum())
    exp_ = np.append(p[keep], p[~keep].sum()) * n
    assert stats.chisquare(obs, exp_).pvalue > 1e-3
    # the returned score and joint are those at the sampled angle
    assert np.allclose(s, curve_at(coeffs[None, :], th[:, None])[:, 0])
    assert np.allclose(joint, log_pv + lik.log_likelihood(s))


def _posterior_mean_x(k: int, n: int, seed: int) -> float:
    """One step of the RBPF from a broad prior onto a sharp bump at x = 20 px: posterior mean of x."""
    cfg = RBPFConfig(n_particles=n, candidates=k, ess_threshold_fraction=0.0,
                     motion=NearConstantVelocity(q_x=400.0, q_y=400.0),
                     orientation=OrientationRandomWalk(q_theta=0.0), visibility=VisibilityMarkovChain(p_nv=0.0, p_v=1.0),
                     likelihood=BetaRatioLikelihood(a1=5.69, b1=2.81, a0=0.25, b0=8.08), confine_to_image=False)
    init = InitialState(x=100.0, y=100.0, time=0.0, p_visible=1.0)
    f = RBPF(cfg, init, seed=seed)
    obs = GaussianBumpObservation(time=1.0, target_xy=(120.0, 100.0), sigma_px=12.0, peak=0.5, clutter=0.0)
    st = f.step(1.0, obs)
    return float(st.weights @ st.particles[:, 0]), st


def test_keeping_one_candidate_per_group_is_unbiased():
    """Collapsing N groups of K weighted candidates to one each (drawn by weight, carrying the group's
    total weight) leaves every weighted average unbiased; keeping the best candidate's weight would not."""
    n, k = 3, 4
    x = np.array([-4.0, -2.0, 2.0, 4.0, 10.0, 11.0, 12.0, 13.0, 5.0, 6.0, 7.0, 8.0])
    w = np.array([0.1, 0.1, 0.1, 0.1, 0.3, 1e-3, 1e-3, 1e-3, 0.05, 0.1, 0.05, 0.1])
    lw = np.log(w / w.sum())
    exact = float(np.exp(lw) @ x)
    f = RBPF(RBPFConfig(n_particles=n, candidates=k), InitialState(x=0.0, y=0.0), seed=0)
    est = []
    for rep in range(2000):
        f.particles = np.zeros((n * k, 5))
        f.particles[:, 0] = x
        f.log_pv = np.zeros((n * k, 2))
        f.log_w = lw.copy()
        f.rng = np.random.default_rng(rep)
        keep = f._keep_one_per_group()
        assert np.all(keep // k == np.arange(n))
        est.append(np.exp(f.log_w) @ f.particles[:, 0])
    se = np.std(est) / np.sqrt(len(est))
    assert abs(np.mean(est) - exact) < 4 * se
    # the expectation under the wrong rule (best candidate's weight), exactly: the test would see it
    w = np.exp(lw).reshape(n, k)
    wb = w.max(axis=1)
    wrong = float(wb @ ((w * x.reshape(n, k)).sum(1) / w.sum(1)) / wb.sum())
    assert abs(wrong - exact) > 10 * se


def test_candidates_estimate_the_same_posterior_as_plain_particles():
    """One step from a broad prior onto a bump: K candidates per particle give the posterior mean of
    N*K plain particles, and the filter keeps N particles."""
    ref = np.mean([_posterior_mean_x(1, 4000, s)[0] for s in range(6)])
    mean_k = np.mean([_posterior_mean_x(4, 1000, s)[0] for s in range(6)])
    st = _posterior_mean_x(4, 1000, 0)[1]
    assert len(st.particles) == 1000 and np.isclose(st.weights.sum(), 1.0)
    assert abs(mean_k - ref) < 0.3, (mean_k, ref)
    assert 105 < ref < 119  # between the prior (100) and the bump (120): the prior matters


def test_candidates_make_one_batched_query_and_are_deterministic():
    calls = []

    class Counting(GaussianBumpObservation):
        def score_grid(self, xy):
            calls.append(len(xy))
            return super().score_grid(xy)

    cfg = RBPFConfig(n_particles=50, candidates=3, orientation_proposal="grid")
    init = InitialState(x=100.0, y=100.0, vx=5.0, pos_std=1.0, vel_std=1.0, theta_std=2.0, time=0.0)
    runs = []
    for _ in range(2):
        f = RBPF(cfg, init, seed=7)
        out = [f.step(t / 30, Counting(time=t / 30, target_xy=(100 + 5 * t / 30, 100.0))).map_estimate.image_x
               for t in range(1, 6)]
        runs.append(out)
    assert runs[0] == runs[1]
    assert calls == [150] * 10  # one query of N*K positions per frame


def test_jump_candidates_are_weighted_to_the_models_jump_rate():
    """Candidates drawn half from the plain NCV, half from the jump component, weighted by
    prior / mixture proposal, reproduce the model's moments (variance Q + eps J in position); with
    eps = 0 the jumped candidates get zero weight."""
    from common.tracking.motion import jump_mixture_log_weights

    motion = NearConstantVelocity(q_x=4.0, q_y=4.0)
    q = motion.covariance(1 / 30)
    rng = np.random.default_rng(5)
    m = 400000
    jumped = np.arange(m) % 2 == 1
    r = rng.standard_normal((m, 4)) @ motion.covariance_cholesky(1 / 30).T
    r[jumped, 0] += rng.normal(0, 2.0, jumped.sum())
    r[jumped, 2] += rng.normal(0, 2.0, jumped.sum())
    for eps in (0.05, 0.2):
        w = np.exp(jump_mixture_log_weights(r, q, 2.0, eps, 0.5))
        var_x = np.sum(w * r[:, 0] ** 2) / np.sum(w)
        assert abs(var_x / (q[0, 0] + eps * 4.0) - 1) < 0.05
        assert abs(np.mean(w) - 1) < 0.05  # importance weights average to one
    w0 = np.exp(jump_mixture_log_weights(r, q, 2.0, 0.0, 0.5))
    assert np.max(w0) <= 2.0 + 1e-9  # p / q <= 1 / (1 - share)
    assert abs(np.sum(w0 * r[:, 0] ** 2) / np.sum(w0) / q[0, 0] - 1) < 0.05  # the plain NCV's variance


def test_grid_proposal_without_an_answer_draws_theta_from_its_prior():
    """With the 'grid' proposal, theta is moved by the observation's score curve; when the detector
    does not answer, it must still take its random-walk step, the same as with no observation."""
    from common.tracking.observation import ObservationUnavailable

    class Unanswered(GaussianBumpObservation):
        def score_grid(self, xy):
            raise ObservationUnavailable("detector down")

    cfg = RBPFConfig(n_particles=40, orientation_proposal="grid")
    init = InitialState(x=100.0, y=100.0, vx=5.0, pos_std=1.0, vel_std=1.0, theta_std=2.0, time=0.0)
    a, b = RBPF(cfg, init, seed=3), RBPF(cfg, init, seed=3)
    before = a.particles[:, 4].copy()
    a.step(1 / 30, Unanswered(time=1 / 30, target_xy=(100.0, 100.0)))
    b.step(1 / 30, None)
    assert not np.array_equal(a.particles[:, 4], before)  # theta moved
    assert np.array_equal(a.particles, b.particles)  # exactly as without an observation


@pytest.mark.parametrize("dt", [1 / 30, 1 / 10])
def test_jump_rate_per_second_is_the_same_whatever_the_frame_rate(dt):
    """``jump_rate_per_s`` r: a visible target jumps in a step of dt seconds with probability
    1 - exp(-r dt), so over one second (1/dt steps) with probability 1 - exp(-r) at 10 and 30 fps
    alike; a hidden target does not jump, and a rate of 0 draws no jump (negative controls)."""
    rate, n = 3.0, 20000
    cfg = RBPFConfig(n_particles=n, motion=NearConstantVelocity(q_x=1e-12, q_y=1e-12),
                     jump_rate_per_s=rate, jump_std=50.0)
    f = RBPF(cfg, InitialState(x=0.0, y=0.0, p_visible=1.0, time=0.0), seed=3)
    f.predict(dt)
    moved = np.hypot(f.particles[:, 0], f.particles[:, 2]) > 1e-3
    p = 1 - np.exp(-rate * dt)
    assert abs(moved.mean() - p) < 4 * np.sqrt(p * (1 - p) / n)
    assert f._jump_probability(1.0) == pytest.approx(1 - np.exp(-rate))
    hidden = RBPF(cfg, InitialState(x=0.0, y=0.0, p_visible=0.0, time=0.0), seed=3)
    hidden.predict(dt)
    assert np.max(np.abs(hidden.particles[:, [0, 2]])) < 1e-3
    off = RBPF(cfg.model_copy(update={"jump_rate_per_s": 0.0, "jump_probability": 0.5}),
               InitialState(x=0.0, y=0.0, p_visible=1.0, time=0.0), seed=3)
    off.predict(dt)  # the rate replaces the per-step probability: 0 a second is no jump at all
    assert np.max(np.abs(off.particles[:, [0, 2]])) < 1e-3
