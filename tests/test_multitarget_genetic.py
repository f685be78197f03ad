"""EPMCMC genetic moves: structure constraints of crossover and mutation, MH exchange invariance."""

import numpy as np
import pytest

from common.multitarget import genetic
from common.multitarget.body import body_model
from common.multitarget.motion import predict
from common.multitarget.config import MotionConfig

H = 100.0


def _population(n_parts: int, n: int, seed: int) -> np.ndarray:
    """Valid configurations: a standing body moved by the structured motion model for a few steps."""
    body = body_model(n_parts)
    rng = np.random.default_rng(seed)
    pos = np.broadcast_to(body.place((200.0, 150.0), H), (n, body.n_parts, 2))
    x = np.concatenate([pos, np.zeros_like(pos)], axis=-1)
    for _ in range(5):
        x = predict(x, body, np.float64(H), 0.04, MotionConfig(part_jitter=60.0, structure_rate=0.0), rng)
    assert body.satisfies(x[..., :2], H).all()
    return x


@pytest.mark.parametrize("n_parts", [2, 6, 10])
def test_crossover_swaps_connected_subtrees_and_keeps_structure(n_parts):
    body = body_model(n_parts)
    a, b = _population(n_parts, 400, 1), _population(n_parts, 400, 2)
    ca, cb, did = genetic.crossover(a, b, body, 0.7, np.random.default_rng(3))
    assert 0.6 < did.mean() < 0.8
    assert body.satisfies(ca[..., :2], H).all() and body.satisfies(cb[..., :2], H).all()
    ra, rb, rca = (genetic.relative_state(v, body) for v in (a, b, ca))
    for k in range(len(a)):
        from_b = np.all(np.isclose(rca[k], rb[k], atol=1e-9), axis=-1) & ~np.all(np.isclose(ra[k], rb[k], atol=1e-9), axis=-1)
        if not did[k]:
            assert np.array_equal(ca[k], a[k]) and np.array_equal(cb[k], b[k])
            continue
        # the parts taken from the other parent form one subtree: a part and all its descendants,
        # hung on the edge to a parent that stayed (so only neighbours influence each other)
        swapped = np.flatnonzero(from_b)
        root = swapped.min()
        assert root > 0
        assert np.array_equal(from_b, body.subtree(root))
        assert body.parent[root] not in swapped
        # the untouched parts keep their own relative state exactly
        assert np.allclose(rca[k][~from_b], ra[k][~from_b], atol=1e-9)
    # children of the pair conserve the pair's genes (relative states)
    rcb = genetic.relative_state(cb, body)
    assert np.allclose(np.sort(np.stack([rca, rcb]), axis=0), np.sort(np.stack([ra, rb]), axis=0), atol=1e-9)


def test_crossover_is_impossible_with_one_part():
    body = body_model(1)
    a, b = _population(1, 10, 1), _population(1, 10, 2)
    ca, cb, did = genetic.crossover(a, b, body, 1.0, np.random.default_rng(0))
    assert not did.any() and np.array_equal(ca, a) and np.array_equal(cb, b)


@pytest.mark.parametrize("n_parts", [2, 6, 10])
def test_mutation_respects_structure(n_parts):
    body = body_model(n_parts)
    x = _population(n_parts, 2000, 4)
    rng = np.random.default_rng(5)
    proj, ok = genetic.mutate(x, body, H, 0.5, 0.0, 0.2, 5.0, rng, project=True)
    assert ok.all() and body.satisfies(proj[..., :2], H).all()
    raw, ok = genetic.mutate(x, body, H, 0.5, 0.0, 0.04, 5.0, np.random.default_rng(5), project=False)
    assert not ok.all() and ok.any()  # big steps leave the structure: those are flagged (MH rejects them)
    assert np.array_equal(ok, body.satisfies(raw[..., :2], H))
    # per-component probabilities: velocity components with rho_m = 0 never change
    assert np.allclose(genetic.relative_state(raw, body)[..., 2:], genetic.relative_state(x, body)[..., 2:], atol=1e-9)
    changed = ~np.isclose(genetic.relative_state(raw, body)[..., :2], genetic.relative_state(x, body)[..., :2], atol=1e-9)
    assert 0.45 < changed.mean() < 0.55


def _exchange_chain(rule: str, n_pairs=20000, sweeps=5, seed=11):
    """Pairs of chains with pi_s = N(0, 1) and pi_q = N(2, 0.5^2), started exactly in pi_s x pi_q,
    moved only by exchange proposals accepted by ``rule``; returns the final chain-s and chain-q states."""
    rng = np.random.default_rng(seed)
    xs = rng.standard_normal((n_pairs, 1))
    xq = 2.0 + 0.5 * rng.standard_normal((n_pairs, 1))

    def log_s(x):
        return -0.5 * x[:, 0] ** 2

    def log_q(x):
        return -0.5 * ((x[:, 0] - 2.0) / 0.5) ** 2

    for _ in range(sweeps):
        xq_perm = xq[rng.permutation(n_pairs)]  # random pairing across the populations
        if rule == "mh":
            xs, xq, _ = genetic.exchange(xs, xq_perm, log_s(xs), log_s(xq_perm), log_q(xs), log_q(xq_perm), rng)
        elif rule == "always":
            xs, xq = xq_perm, xs
        elif rule == "one-sided":  # a broken rule: forgets pi_q's ratio
            acc = genetic.mh_accept(log_s(xq_perm) - log_s(xs), rng)[:, None]
            xs, xq = np.where(acc, xq_perm, xs), np.where(acc, xs, xq_perm)
    return xs[:, 0], xq[:, 0]


def _moments_ok(x, mean, std, k=5.0):
    n = len(x)
    se_mean = std / np.sqrt(n)
    se_var = std**2 * np.sqrt(2.0 / (n - 1))
    return abs(x.mean() - mean) < k * se_mean and abs(x.var(ddof=1) - std**2) < k * se_var


def test_exchange_leaves_product_target_invariant():
    xs, xq = _exchange_chain("mh")
    assert _moments_ok(xs, 0.0, 1.0) and _moments_ok(xq, 2.0, 0.5)
    # and swaps did happen (the test is not vacuous)
    rng = np.random.default_rng(0)
    a, b = rng.standard_normal((5000, 1)), 2 + 0.5 * rng.standard_normal((5000, 1))
    _, _, acc = genetic.exchange(a, b, -0.5 * a[:, 0] ** 2, -0.5 * b[:, 0] ** 2,
                                 -2 * (a[:, 0] - 2) ** 2, -2 * (b[:, 0] - 2) ** 2, rng)
    assert 0.02 < acc.mean() < 0.5


@pytest.mark.parametrize("rule", ["always", "one-sided"])
def test_broken_exchange_rules_are_caught(rule):
    """Negative controls: the same statistical check fails for wrong acceptance rules."""
    xs, xq = _exchange_chain(rule)
    assert not (_moments_ok(xs, 0.0, 1.0) and _moments_ok(xq, 2.0, 0.5))


def test_mutation_carries_the_velocity_by_the_given_gain():
    body = body_model(10)
    x = _population(10, 500, 6)
    gain = np.linspace(0.5, 5.0, 20).reshape(10, 2)
    moved, _ = genetic.mutate(x, body, H, 0.5, 0.0, 0.03, 5.0, np.random.default_rng(7), project=False, velocity_gain=gain)
    plain, _ = genetic.mutate(x, body, H, 0.5, 0.0, 0.03, 5.0, np.random.default_rng(7), project=False)
    assert np.array_equal(moved[..., :2], plain[..., :2])  # same draws, same positions
    step = plain[..., :2] - x[..., :2]
    assert np.abs(step).max() > 1.0
    assert np.allclose(moved[..., 2:] - x[..., 2:], gain * step, atol=1e-9)  # every part, both axes
    assert np.allclose(plain[..., 2:], x[..., 2:], atol=1e-9)  # negative control: no gain, velocity untouched


@pytest.mark.parametrize("coupled", [True, False])
def test_coupled_mutation_keeps_a_correlated_position_velocity_target_invariant(coupled):
    """MH with the coupled mutation (a symmetric proposal, plain ratio) started in a correlated Gaussian
    (x, v) target stays in it; it mixes the velocity only when coupled (rho_m of velocities is 0)."""
    body = body_model(1)
    rho, sx, sv = 0.8, 2.0, 10.0
    gain = np.full((1, 2), rho * sv / sx if coupled else 0.0)

    def log_pi(s):
        zx, zv = s[..., 0, :2] / sx, s[..., 0, 2:] / sv
        return -0.5 * np.sum((zx * zx - 2 * rho * zx * zv + zv * zv) / (1 - rho * rho), axis=-1)

    rng = np.random.default_rng(8)
    n = 20000
    zx = rng.standard_normal((n, 2))
    x0 = np.concatenate([sx * zx, sv * (rho * zx + np.sqrt(1 - rho * rho) * rng.standard_normal((n, 2)))], axis=-1)[:, None]
    x, lp = x0.copy(), log_pi(x0)
    for _ in range(30):
        prop, ok = genetic.mutate(x, body, H, 1.0, 0.0, 0.02, 1.0, rng, project=False, velocity_gain=gain)
        lpp = log_pi(prop)
        acc = genetic.mh_accept(np.where(ok, lpp - lp, -np.inf), rng)
        x[acc], lp[acc] = prop[acc], lpp[acc]
    pos, vel = x[:, 0, 0], x[:, 0, 2]
    assert abs(pos.std() - sx) < 0.05 * sx and abs(vel.std() - sv) < 0.05 * sv
    assert abs(np.corrcoef(pos, vel)[0, 1] - rho) < 0.03
    moved = np.mean(np.abs(vel - x0[:, 0, 2]) > 1e-9)
    assert (moved > 0.9) if coupled else (moved == 0.0)


def test_mcmc_target_keeps_the_predicted_populations_position_velocity_correlation():
    """EPMCMC's MCMC target pi_t = L x (Gaussian fit to the predicted population): with
    ``couple_velocity`` the fit keeps each part's position-velocity correlation per axis, and its log
    density matches the bivariate normal's; the mutation's velocity gain is the regression slope."""
    from scipy.stats import multivariate_normal

    from common.multitarget import HistogramEvidence, MultiInit, make_filter, method_config

    img = np.full((100, 100, 3), 128, np.uint8)
    init = MultiInit(parts=np.array([[[50.0, 50.0]]]), height=np.array([40.0]))
    rng = np.random.default_rng(9)
    zx, zv = rng.standard_normal((2, 4000, 2))
    sx, sv, rho = 3.0, 20.0, -0.6
    cloud = np.concatenate([50 + sx * zx, sv * (rho * zx + np.sqrt(1 - rho * rho) * zv)], axis=-1)[None, :, None]
    pts = cloud[:, :5]
    fits = {}
    for coupled in (True, False):
        cfg = method_config("epmcmc-elpda", n_parts=1, n_particles=4000)
        cfg = cfg.model_copy(update={"evolution": cfg.evolution.model_copy(update={"couple_velocity": coupled})})
        flt = make_filter(cfg, init, HistogramEvidence(img), 0)
        flt.particles = cloud.copy()
        flt._fit_prior()
        fits[coupled] = flt
    c = fits[True]
    assert np.allclose(c._prior_rho[0, 0], rho, atol=0.05)
    assert np.allclose(c._velocity_gain[0, 0], rho * sv / sx, rtol=0.1)
    assert np.array_equal(fits[False]._prior_rho, np.zeros_like(c._prior_rho))
    assert np.array_equal(fits[False]._velocity_gain, np.zeros_like(c._velocity_gain))
    for coupled, flt in fits.items():
        m, s, r = flt._prior_mean[0, 0], flt._prior_std[0, 0], flt._prior_rho[0, 0]
        want = sum(multivariate_normal([m[a], m[2 + a]], [[s[a] ** 2, r[a] * s[a] * s[2 + a]],
                                                           [r[a] * s[a] * s[2 + a], s[2 + a] ** 2]]).logpdf(pts[0, :, 0][:, [a, 2 + a]])
                   for a in range(2))
        got = flt._log_prior(pts, np.array([0]))[0]
        assert np.allclose(got - got[0], want - want[0], atol=1e-9)  # up to the normalising constant
