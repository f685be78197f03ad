"""PDA / ELPDA association probabilities (eqs. 10-12), the expected likelihood (eq. 13), JPDA, gates."""

import math

import numpy as np
import pytest

from common.multitarget import association as da
from common.multitarget.gating import gate_gamma, update_measurement_cov
from common.tracking import resampling


def _case(attribute=None):
    # two measurements in a gate of area V = 100 px^2, Poisson clutter lambda = 0.01 / px^2 (lambda V = 1)
    n = np.array([0.01, 0.002])  # N(z_j; z^, S)
    return da.association_probabilities(np.log(n), np.array([True, True]), np.array(100.0),
                                        p_detect=0.9, p_gate=0.95, clutter_density=0.01, attribute=attribute)


def test_pda_probabilities_match_hand_computation():
    beta = _case()
    # by hand from eqs. 10-11 with p(theta_j | m) = P_D P_G mu_F(m-1) / (m D), p(theta_0 | m) = (1 - P_D P_G) mu_F(m) / D:
    mu1, mu2 = math.exp(-1.0), math.exp(-1.0) / 2.0  # Poisson(1; 1), Poisson(2; 1)
    t1 = 100.0**-1 / 0.95 * 0.01 * 0.9 * 0.95 * mu1 / 2
    t2 = 100.0**-1 / 0.95 * 0.002 * 0.9 * 0.95 * mu1 / 2
    t0 = 100.0**-2 * (1 - 0.9 * 0.95) * mu2
    expect = np.array([t0, t1, t2]) / (t0 + t1 + t2)
    assert beta == pytest.approx(expect, rel=1e-12)
    assert beta.sum() == pytest.approx(1.0, abs=1e-15)
    # the classical parametric-PDA form: beta_0 : beta_j = lambda (1 - P_D P_G) / P_D : N_j
    b = 0.01 * (1 - 0.855) / 0.9
    assert beta == pytest.approx(np.array([b, 0.01, 0.002]) / (b + 0.012), rel=1e-12)


def test_elpda_attributes_reweight_and_still_sum_to_one():
    rho = np.array([0.5, 0.95])  # the farther measurement looks much more like the part
    a = da.attribute_ratio(rho, 12.0)
    beta = _case(attribute=a)
    assert beta.sum() == pytest.approx(1.0, abs=1e-15)
    plain = _case()
    assert beta[2] > plain[2] and beta[1] < plain[1]
    t = np.array([plain[0], plain[1] * a[0], plain[2] * a[1]])
    assert beta == pytest.approx(t / t.sum(), rel=1e-12)
    # attribute density: a proper density on [0, 1] against a uniform clutter density
    r = np.linspace(0, 1, 200001)
    assert np.trapezoid(da.attribute_ratio(r, 12.0), r) == pytest.approx(1.0, abs=1e-6)


def test_probabilities_sum_to_one_in_batches_with_missing_measurements():
    rng = np.random.default_rng(0)
    lg = rng.normal(-8, 2, size=(7, 5, 4))
    valid = rng.random((7, 5, 4)) < 0.5
    valid[0, 0] = False  # no measurement: beta_0 = 1
    vol = rng.uniform(50, 500, size=(7, 5))
    beta = da.association_probabilities(lg, valid, vol, 0.9, 0.95, 1e-3, da.attribute_ratio(rng.random((7, 5, 4)), 12.0))
    assert np.allclose(beta.sum(axis=-1), 1.0, atol=1e-12)
    assert np.all(beta[..., 1:][~valid] == 0.0)
    assert beta[0, 0, 0] == 1.0


def test_expected_likelihood_is_eq13():
    z = np.array([[3.0, 0.0], [0.0, 10.0]])
    valid = np.array([True, True])
    beta = np.array([0.2, 0.5, 0.3])
    r = 4.0 * np.eye(2)
    x = np.array([[0.0, 0.0], [3.0, 1.0]])  # two particles
    got = da.expected_log_likelihood(z[None] - x[:, None], beta, valid, np.array(150.0), r, 0.95)
    def n(d):
        return math.exp(-0.5 * (d @ d) / 4.0) / (2 * math.pi * 4.0)
    for k in range(2):
        want = 0.2 / 150.0 + (0.5 * n(z[0] - x[k]) + 0.3 * n(z[1] - x[k])) / 0.95
        assert got[k] == pytest.approx(math.log(want), rel=1e-12)


def test_jpda_two_targets_one_measurement_by_hand():
    lg = np.log(np.array([[0.02], [0.005]]))
    gated = np.array([[True], [True]])
    beta = da.jpda_probabilities(lg, gated, 0.9, 0.95, 0.01)
    miss = 1 - 0.855
    hit = 0.9 * np.array([0.02, 0.005]) / 0.01
    events = {"none": miss * miss, "t1": hit[0] * miss, "t2": miss * hit[1]}  # both cannot take it
    tot = sum(events.values())
    assert beta[0] == pytest.approx([(events["none"] + events["t2"]) / tot, events["t1"] / tot])
    assert beta[1] == pytest.approx([(events["none"] + events["t1"]) / tot, events["t2"] / tot])
    assert np.allclose(beta.sum(axis=1), 1.0)


def test_gate_is_re_estimated_from_innovations():
    from common.multitarget.gating import Measurements

    r = np.broadcast_to(25.0 * np.eye(2), (1, 1, 2, 2)).copy()
    z = np.array([[[[2.0, 0.0], [0.0, 0.0]]]])
    meas = Measurements(z=z, rho=np.ones((1, 1, 2)), valid=np.array([[[True, False]]]),
                        volume=np.ones((1, 1)), centre=np.zeros((1, 1, 2)), s_cov=r, pred_cov=np.zeros((1, 1, 2, 2)))
    beta = np.array([[[0.0, 1.0, 0.0]]])
    for _ in range(30):
        r = update_measurement_cov(r, meas, beta, rate=0.3, min_sigma=1.0, max_sigma=10.0)
    # innovation (2, 0) against the prediction every frame: R -> diag(4, floor 1)
    assert np.allclose(r[0, 0], np.diag([4.0, 1.0]), atol=1e-3)
    # a missed target (beta_0 = 1) gets its gate widened back to the largest R
    for _ in range(30):
        r = update_measurement_cov(r, meas, np.array([[[1.0, 0.0, 0.0]]]), rate=0.3, min_sigma=1.0, max_sigma=10.0)
    assert np.allclose(r[0, 0], 100.0 * np.eye(2), atol=1e-2)
    assert gate_gamma(0.95) == pytest.approx(5.991464547, rel=1e-9)



def test_re_estimated_r_leaves_out_the_predictions_spread():
    # covariance matching: the innovations' covariance is P + R, so R = E[nu nu^T] - P
    from common.multitarget.gating import Measurements

    r = np.broadcast_to(25.0 * np.eye(2), (1, 1, 2, 2)).copy()
    z = np.array([[[[3.0, 0.0], [0.0, 0.0]]]])
    beta = np.array([[[0.0, 1.0, 0.0]]])
    for pred, expect in ((np.diag([4.0, 0.5]), np.diag([5.0, 1.0])), (np.zeros((2, 2)), np.diag([9.0, 1.0]))):
        meas = Measurements(z=z, rho=np.ones((1, 1, 2)), valid=np.array([[[True, False]]]), volume=np.ones((1, 1)),
                            centre=np.zeros((1, 1, 2)), s_cov=r + pred, pred_cov=pred[None, None])
        rk = r
        for _ in range(40):
            rk = update_measurement_cov(rk, meas, beta, rate=0.3, min_sigma=1.0, max_sigma=10.0)
        assert np.allclose(rk[0, 0], expect, atol=1e-3)  # 9 - 4 = 5 along x; y at the floor either way

def test_residual_resampling_is_available_as_a_plain_function():
    w = np.array([0.5, 0.25, 0.125, 0.125])
    idx = resampling.residual(w, np.random.default_rng(0))
    assert np.array_equal(idx, [0, 0, 1, 2]) or np.array_equal(idx, [0, 0, 1, 3])
    assert resampling.get_scheme("residual") is resampling.residual


def test_plain_pda_uses_the_combined_measurement():
    # two measurements: the PDAF's combined measurement z_c = z^ + sum_j beta_j nu_j lies between them
    diff_pred = np.array([[4.0, 0.0], [-2.0, 0.0]])
    beta = np.array([0.2, 0.5, 0.3])
    valid = np.array([True, True])
    r = 9.0 * np.eye(2)
    nu = 0.5 * diff_pred[0] + 0.3 * diff_pred[1]
    spread = 0.5 * np.outer(diff_pred[0], diff_pred[0]) + 0.3 * np.outer(diff_pred[1], diff_pred[1]) - np.outer(nu, nu)
    cov = (r + spread) / 0.8
    x = np.array([[0.0, 0.0], [nu[0], nu[1]], [4.0, 0.0]])  # h(x) - z^ of three particles
    got = da.pda_log_likelihood(diff_pred, beta, valid, x, r)
    inv = np.linalg.inv(cov)
    want = [-0.5 * (nu - xi) @ inv @ (nu - xi) for xi in x]
    assert got == pytest.approx(want, rel=1e-12, abs=1e-12)
    assert got[1] == 0.0 and got[2] < got[0]  # the particle on a measurement is not favoured
    # nothing in the gate: flat
    assert np.all(da.pda_log_likelihood(diff_pred, np.array([1.0, 0.0, 0.0]), np.array([False, False]), x, r) == 0.0)


def test_adaptive_gate_searches_its_bounding_box_only_and_finds_the_same_measurements(monkeypatch):
    from common.multitarget import gating
    from common.multitarget.appearance import HistogramEvidence
    from common.multitarget.body import body_model
    from common.multitarget.config import GateConfig
    from common.multitarget.state import MultiInit
    from common.scene.people import PeopleScene, PeopleSceneConfig

    f = PeopleScene(PeopleSceneConfig(n_people=3, n_frames=10), seed=4).frame(3)
    body = body_model(10)
    init = MultiInit.from_truth(f.truth.parts, f.truth.boxes, body)
    ev = HistogramEvidence(f.image)
    refs = ev.histograms(gating.part_boxes(init.parts, body.box[None] * init.height[:, None, None]).reshape(-1, 4))
    refs = refs.reshape(3, body.n_parts, -1)
    parts = init.parts + np.array([3.0, -2.0])  # a prediction a little off the people
    part_cov = np.broadcast_to(4.0 * np.eye(2), (3, body.n_parts, 2, 2))
    r_cov = np.broadcast_to(np.diag([9.0, 16.0]), (3, 1, 2, 2))
    cfg = GateConfig(adaptive=True)
    asked = []
    real = ev.similarity
    monkeypatch.setattr(ev, "similarity", lambda b, r, i: asked.append(len(b)) or real(b, r, i))
    small = gating.measure(parts, part_cov, r_cov, body.box[None] * init.height[:, None, None], refs, ev, cfg)
    full_grid = gating._grid
    monkeypatch.setattr(gating, "_grid", lambda half, stride, reach=None: full_grid(half, stride))
    full = gating.measure(parts, part_cov, r_cov, body.box[None] * init.height[:, None, None], refs, ev, cfg)
    assert asked[0] < asked[1] / 3  # the gate (std about 4 px) needs far fewer boxes than the 61x61 px square
    assert small.valid.sum() > 0
    for a in ("valid", "volume", "s_cov", "centre"):
        assert np.array_equal(getattr(small, a), getattr(full, a))
    assert np.array_equal(small.z[small.valid], full.z[full.valid])
    assert np.array_equal(small.rho[small.valid], full.rho[full.valid])
