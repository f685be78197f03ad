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
