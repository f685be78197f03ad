"""Motion models (Pang eqs. 7-11), likelihoods (Pang eqs. 15-19, Nelson eq. 15), homographies, configs."""

import numpy as np
import pytest
from pydantic import ValidationError
from scipy import stats
from scipy.linalg import expm
from scipy.special import beta as beta_fn

from common.tracking import (
    BetaRatioLikelihood,
    ExponentialScoreLikelihood,
    InitialState,
    NearConstantVelocity,
    OrientationRandomWalk,
    RBPFConfig,
    SIRConfig,
    VisibilityMarkovChain,
    WindowedMLConfig,
    wrap_degrees,
)
from common.tracking.camera import apply_homography, homography_jacobian, image_to_world, world_to_image

# ----------------------------------------------------------------------------- NCV


def _q_closed_form(dt, qx, qy):
    """Pang eq. 8, written out entry by entry."""
    return np.array(
        [
            [dt**3 / 3 * qx, dt**2 / 2 * qx, 0, 0],
            [dt**2 / 2 * qx, dt * qx, 0, 0],
            [0, 0, dt**3 / 3 * qy, dt**2 / 2 * qy],
            [0, 0, dt**2 / 2 * qy, dt * qy],
        ]
    )


def _q_van_loan(dt, qx, qy):
    """Q = int_0^T e^{A s} L Qc L^T e^{A^T s} ds for continuous white-noise acceleration, via Van Loan."""
    a = np.zeros((4, 4))
    a[0, 1] = a[2, 3] = 1.0
    qc = np.diag([0.0, qx, 0.0, qy])
    m = np.zeros((8, 8))
    m[:4, :4] = -a
    m[:4, 4:] = qc
    m[4:, 4:] = a.T
    e = expm(m * dt)
    phi = e[4:, 4:].T
    return phi @ e[:4, 4:]


@pytest.mark.parametrize("dt", [1.0 / 3.0, 0.04])
def test_ncv_covariance_closed_form(dt):
    model = NearConstantVelocity(q_x=625.0, q_y=100.0)
    q = model.covariance(dt)
    assert np.allclose(q, _q_closed_form(dt, 625.0, 100.0), rtol=1e-14, atol=0)
    assert np.allclose(q, _q_van_loan(dt, 625.0, 100.0), rtol=1e-9, atol=1e-12)
    chol = model.covariance_cholesky(dt)
    assert np.allclose(chol @ chol.T, q, rtol=1e-12, atol=1e-15)
    assert np.allclose(np.triu(chol, 1), 0.0)
    f = model.transition_matrix(dt)
    assert np.array_equal(f, np.array([[1, dt, 0, 0], [0, 1, 0, 0], [0, 0, 1, dt], [0, 0, 0, 1]]))


def test_ncv_covariance_depends_on_dt():
    m = NearConstantVelocity()
    assert not np.allclose(m.covariance(1 / 3), m.covariance(1 / 30))
    assert np.array_equal(m.covariance(0.0), np.zeros((4, 4)))
    assert np.array_equal(m.covariance_cholesky(0.0), np.zeros((4, 4)))
    with pytest.raises(ValueError):
        m.covariance_cholesky(-0.1)


@pytest.mark.parametrize("dt", [1.0 / 3.0, 0.1])
def test_ncv_sample_moments(dt):
    model = NearConstantVelocity(q_x=625.0, q_y=100.0)
    n = 200_000
    x0 = np.array([3.0, -2.0, 10.0, 5.0])
    rng = np.random.default_rng(2024)
    x1 = model.sample(np.tile(x0, (n, 1)), dt, rng)
    q = model.covariance(dt)
    resid = x1 - model.predict_mean(x0[None], dt)[0]
    # mean: within 5 standard errors
    assert np.all(np.abs(resid.mean(axis=0)) <= 5 * np.sqrt(np.diag(q) / n))
    emp = np.cov(resid.T)
    # sample covariance entry (i, j) has variance (Q_ii Q_jj + Q_ij^2) / n for Gaussian data
    se = np.sqrt((np.outer(np.diag(q), np.diag(q)) + q**2) / n)
    assert np.all(np.abs(emp - q) <= 5 * se + 1e-15)


# ----------------------------------------------------------------------------- theta, V


def test_orientation_random_walk():
    per_frame = OrientationRandomWalk(q_theta=16.0)
    per_second = OrientationRandomWalk(q_theta=16.0, per="second")
    assert per_frame.variance(1 / 3) == per_frame.variance(1 / 30) == 16.0
    assert per_second.variance(0.5) == pytest.approx(8.0)
    rng = np.random.default_rng(0)
    th = per_frame.sample(np.zeros(100_000), 1 / 3, rng)
    assert np.std(th) == pytest.approx(4.0, rel=0.02)
    wrapped = per_frame.sample(np.full(1000, 179.0), 1.0, rng)
    assert np.all((wrapped >= -180.0) & (wrapped < 180.0))
    assert np.allclose(wrap_degrees([180.0, -180.0, 190.0, -190.0, 540.0]), [-180.0, -180.0, -170.0, 170.0, -180.0])


def test_visibility_chain():
    chain = VisibilityMarkovChain(p_nv=0.1, p_v=0.25)
    a = chain.transition_matrix()
    assert np.allclose(a.sum(axis=1), 1.0)
    assert a[1, 0] == 0.1 and a[0, 1] == 0.25  # p(V_t=0|V_t-1=1) = P_NV, p(V_t=1|V_t-1=0) = P_V
    p = np.array([0.0, 0.3, 1.0])
    assert np.allclose(chain.predict(p), [0.25, 0.3 * 0.9 + 0.7 * 0.25, 0.9])
    with np.errstate(divide="ignore"):
        logp = np.log(np.stack([1 - p, p], axis=1))
    assert np.allclose(np.exp(chain.predict_log(logp))[:, 1], chain.predict(p), rtol=1e-14)
    rng = np.random.default_rng(1)
    n = 200_000
    from_vis = chain.sample(np.ones(n, np.int8), rng)
    from_occ = chain.sample(np.zeros(n, np.int8), rng)
    assert from_vis.mean() == pytest.approx(0.9, abs=5 * np.sqrt(0.09 / n))
    assert from_occ.mean() == pytest.approx(0.25, abs=5 * np.sqrt(0.1875 / n))


# ----------------------------------------------------------------------------- likelihoods


@pytest.mark.parametrize("params", [(5, 7, 1, 7), (3.5, 2.0, 1.2, 4.0), (1, 1, 1, 1)])
def test_beta_ratio_matches_scipy(params):
    a1, b1, a0, b0 = params
    lik = BetaRatioLikelihood(a1=a1, b1=b1, a0=a0, b0=b0)
    z = np.linspace(0.001, 0.999, 201)
    ref = stats.beta.logpdf(z, a1, b1) - stats.beta.logpdf(z, a0, b0)
    assert np.allclose(lik.log_ratio(z), ref, rtol=1e-12, atol=1e-12)
    ll = lik.log_likelihood(z)
    assert ll.shape == (201, 2)
    assert np.array_equal(ll[:, 0], np.zeros(201))  # V = 0: ratio 1 (Pang eq. 16)
    assert np.array_equal(ll[:, 1], lik.log_ratio(z))


def test_beta_ratio_defaults_and_edges():
    lik = BetaRatioLikelihood()
    assert (lik.a1, lik.b1, lik.a0, lik.b0) == (5.0, 7.0, 1.0, 7.0)  # Pang eq. 18
    # Pang eq. 19: B(1,7)/B(5,7) Z^4 = 330 Z^4
    assert beta_fn(1, 7) / beta_fn(5, 7) == pytest.approx(330.0)
    z = np.array([0.1, 0.5, 0.9])
    assert np.allclose(np.exp(lik.log_ratio(z)), 330.0 * z**4, rtol=1e-12)
    # robust at 0, 1 and below 0 (negative scores are treated as 0)
    edge = lik.log_ratio(np.array([-0.5, 0.0, 1.0, 1.5]))
    assert np.all(np.isfinite(edge))
    assert edge[0] == edge[1] == pytest.approx(np.log(330.0) + 4 * np.log(lik.eps))
    assert edge[2] == edge[3] == pytest.approx(np.log(330.0), abs=1e-4)
    # with b1 != b0 the 1 - Z term is active and still finite at Z = 1
    assert np.all(np.isfinite(BetaRatioLikelihood(b1=2.0).log_ratio(np.array([0.0, 1.0]))))


class _ScriptedScores:
    """Given scores for the filter's particles, in its order, and a given cue's log ratios."""

    homography = None
    image_size = (1000, 1000)

    def __init__(self, scores, cue):
        self.scores, self.cue = np.asarray(scores, float), np.asarray(cue, float)

    def score_at(self, hyps):
        return self.scores.copy(), np.ones(len(self.scores), bool)

    def cue_log_ratio(self, image_xy):
        return self.cue.copy()


def test_a_tempered_likelihood_counts_a_frame_as_that_fraction_of_an_observation():
    """``rbpf.temper`` raises the matcher's likelihood to its power in the weight update, not the
    cue's ratio: w_p ∝ r_p (pi^-_p(0) + pi^-_p(1) ratio(z_p)^T), checked against that expression by
    hand for three particles; 1 is the model as fitted, bit for bit; the real profile takes
    ``REAL_LIKELIHOOD_TEMPER``, the synthetic one the model."""
    from common.settings import REAL_LIKELIHOOD_TEMPER, profile_for
    from common.sources import open_source
    from common.tracking import RBPF, NearConstantVelocity, RBPFConfig

    lik = BetaRatioLikelihood(a1=5.69, b1=2.81, a0=0.25, b0=8.08)
    z = np.array([0.8, 0.6, 0.1])  # a look-alike, the half-hidden target, the ground
    cue = np.array([0.0, 1.5, -0.5])
    p_vis = np.array([0.9, 0.5, 0.2])
    particles = np.array([[10.0, 0.0, 10.0, 0.0, 0.0], [20.0, 0.0, 10.0, 0.0, 0.0], [30.0, 0.0, 10.0, 0.0, 0.0]])

    def weights(temper=None):
        upd = {"likelihood": lik, "motion": NearConstantVelocity(q_x=0.0, q_y=0.0), "n_particles": 3}
        if temper is not None:
            upd["temper"] = temper
        f = RBPF.from_particles(RBPFConfig(**upd), particles, p_visible=p_vis, time=0.0)
        return f.step(1.0, _ScriptedScores(z, cue)).weights

    pred = p_vis * 0.9 + (1 - p_vis) * 0.1  # pi^-(1), Pang's chain at 0.1 either way
    for t in (1.0, 0.5, 0.3):
        m = np.exp(cue) * ((1 - pred) + pred * np.exp(t * lik.log_ratio(z)))
        np.testing.assert_allclose(weights(t), m / m.sum(), rtol=1e-12)
    assert np.array_equal(weights(1.0), weights())
    # the look-alike's lead over the half-hidden target shrinks: at 1 it takes almost all the weight
    w1, wh = weights(1.0), weights(0.5)
    assert w1[0] / w1[1] > 2 * wh[0] / wh[1]
    for bad in (0.0, 1.5):
        with pytest.raises(ValidationError):
            RBPFConfig(temper=bad)
    assert REAL_LIKELIHOOD_TEMPER == 0.5
    assert profile_for(open_source("exit:0", n_frames=2), seed=0).rbpf.temper == REAL_LIKELIHOOD_TEMPER
    assert profile_for(open_source("synthetic:0", n_frames=2), seed=0).rbpf.temper == 1.0


def test_exponential_likelihood():
    lik = ExponentialScoreLikelihood()
    assert (lik.k, lik.nv_c) == (5.0, 0.2)  # Nelson Table I
    s = np.array([-0.4, 0.0, 0.3, 0.95])
    ll = lik.log_likelihood(s)
    # default: NV_c on the score scale (the paper's prose): occluded term exp(k * NV_c)
    assert np.allclose(ll[:, 1], 5.0 * s) and np.allclose(ll[:, 0], 1.0)
    # eq. 15 as printed: exp(NV_c)
    ll2 = ExponentialScoreLikelihood(nv_c_on_score_scale=False).log_likelihood(s)
    assert np.allclose(ll2[:, 0], 0.2) and np.allclose(ll2[:, 1], 5.0 * s)


# ----------------------------------------------------------------------------- camera


H = np.array([[1.8, -0.4, 40.0], [0.5, 2.1, 25.0], [2e-4, -1e-4, 1.0]])


def test_homography_round_trip_and_identity():
    rng = np.random.default_rng(0)
    world = rng.uniform(-50, 150, (40, 2))
    img = world_to_image(H, world)
    assert np.allclose(image_to_world(H, img), world, atol=1e-9)
    assert np.array_equal(world_to_image(None, world), world)
    assert np.allclose(apply_homography(np.eye(3) * 3.0, world), world)  # scale of H is irrelevant
    # matches the homogeneous-coordinates definition
    hom = np.column_stack([world, np.ones(40)]) @ H.T
    assert np.allclose(img, hom[:, :2] / hom[:, 2:], rtol=1e-13)


def test_homography_jacobian_finite_differences():
    pts = np.array([[10.0, 20.0], [-30.0, 75.0]])
    jac = homography_jacobian(H, pts)
    eps = 1e-6
    for k in range(2):
        d = np.zeros(2)
        d[k] = eps
        fd = (world_to_image(H, pts + d) - world_to_image(H, pts - d)) / (2 * eps)
        assert np.allclose(jac[:, :, k], fd, rtol=1e-7, atol=1e-9)
    assert np.array_equal(homography_jacobian(None, pts), np.broadcast_to(np.eye(2), (2, 2, 2)))


def test_initial_state_from_image_box():
    init = InitialState.from_image_box((100, 50, 120, 70), H, time=1.5)
    assert np.allclose(world_to_image(H, np.array([init.x, init.y])), [110.0, 60.0])
    assert init.time == 1.5 and init.theta == 0.0 and init.p_visible == 1.0
    init2 = InitialState.from_image_box((100, 50, 120, 70), None)
    assert (init2.x, init2.y) == (110.0, 60.0)


# ----------------------------------------------------------------------------- configs


def test_config_defaults_are_the_papers():
    r = RBPFConfig()  # Pang 2010 Table 1
    assert r.n_particles == 200 and r.ess_threshold_fraction * r.n_particles == pytest.approx(180)
    assert (r.motion.q_x, r.motion.q_y, r.orientation.q_theta) == (625.0, 625.0, 16.0)
    assert (r.visibility.p_nv, r.visibility.p_v) == (0.1, 0.1)
    assert r.likelihood.kind == "beta_ratio" and r.resampling == "systematic"
    s = SIRConfig()  # Nelson 2008 Table I
    assert s.n_particles == 300 and (s.motion.q_x, s.motion.q_y) == (1600.0, 1600.0)
    assert (s.visibility.p_nv, s.visibility.p_v) == (0.1, 0.25)
    assert s.likelihood.kind == "exponential" and (s.likelihood.k, s.likelihood.nv_c) == (5.0, 0.2)
    w = WindowedMLConfig()  # Pang 2010 §8
    assert (w.window_px, w.threshold) == (25, 0.6)


def test_configs_validate_and_round_trip():
    with pytest.raises(ValidationError):
        VisibilityMarkovChain(p_nv=1.5)
    with pytest.raises(ValidationError):
        RBPFConfig(n_particles=0)
    with pytest.raises(ValidationError):
        RBPFConfig(bogus=1)
    cfg = RBPFConfig(likelihood=ExponentialScoreLikelihood(k=3.0), resampling="residual")
    again = RBPFConfig.model_validate_json(cfg.model_dump_json())
    assert again == cfg and isinstance(again.likelihood, ExponentialScoreLikelihood)


def test_rounding_near_a_perfect_score_carries_no_weight():
    """Identical particles on the template's own frame score 1 up to single-precision rounding
    (seen: 0.99999987 and 0.99999999 for two identical rows of one batch). With a calibrated
    b1 < b0 the ratio diverges at Z = 1: the rounding must not separate them. A real difference
    (0.95 against 0.9) still does (negative control)."""
    lik = BetaRatioLikelihood(a1=5.69, b1=2.81, a0=0.25, b0=8.08)
    near_one = lik.log_ratio(np.array([0.999999871245068, 0.9999999891537743, 1.0000000756542367]))
    assert near_one[0] == near_one[1] == near_one[2]
    apart = lik.log_ratio(np.array([0.9, 0.95]))
    assert apart[1] - apart[0] > 1.0
