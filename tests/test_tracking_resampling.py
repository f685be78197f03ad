"""Resampling schemes: unbiasedness, systematic's floor/ceil property, ESS bounds, log-weight helpers."""

import numpy as np
import pytest

from common.tracking import resampling

SCHEMES = sorted(resampling.SCHEMES)


def _offspring(idx: np.ndarray, n: int) -> np.ndarray:
    return np.bincount(idx, minlength=n)


@pytest.mark.parametrize("name", SCHEMES)
def test_scheme_is_unbiased(name):
    """E[#offspring_i] = N w_i, checked against a 5-standard-error band from the empirical variance."""
    scheme = resampling.get_scheme(name)
    rng = np.random.default_rng(12345)
    n = 12
    w = rng.dirichlet(np.full(n, 0.7))
    w[3] = 0.0  # a zero-weight particle must never be chosen
    w /= w.sum()
    reps = 10000
    counts = np.empty((reps, n))
    for r in range(reps):
        idx = scheme(w, rng)
        assert idx.shape == (n,) and idx.dtype.kind == "i"
        counts[r] = _offspring(idx, n)
    assert np.all(counts.sum(axis=1) == n)
    assert np.all(counts[:, 3] == 0)
    mean = counts.mean(axis=0)
    se = np.sqrt(counts.var(axis=0, ddof=1) / reps)
    assert np.all(np.abs(mean - n * w) <= 5.0 * se + 1e-12), (mean, n * w, se)
    # and the band is meaningful: most particles have genuinely random offspring counts
    assert np.sum(se > 0) >= n - 2


def test_biased_scheme_would_be_caught():
    """Sanity check of the test's power: always taking the heaviest particle's neighbour fails the band."""
    rng = np.random.default_rng(0)
    n = 12
    w = rng.dirichlet(np.full(n, 0.7))
    counts = np.array([_offspring(resampling.multinomial(np.roll(w, 1), rng), n) for _ in range(2000)])
    se = np.sqrt(counts.var(axis=0, ddof=1) / len(counts))
    assert np.any(np.abs(counts.mean(axis=0) - n * w) > 5.0 * se + 1e-12)


def test_systematic_offspring_is_floor_or_ceil():
    rng = np.random.default_rng(7)
    for trial in range(500):
        n = int(rng.integers(1, 60))
        alpha = [0.05, 0.5, 5.0][trial % 3]
        w = rng.dirichlet(np.full(n, alpha))
        if trial % 7 == 0:
            w[rng.integers(n)] = 0.0
            w = w / w.sum() if w.sum() > 0 else np.full(n, 1.0 / n)
        c = _offspring(resampling.systematic(w, rng), n)
        nw = n * w
        assert c.sum() == n
        assert np.all((c == np.floor(nw)) | (c == np.ceil(nw)) | np.isclose(c, nw, atol=1e-9)), (w, c)


def test_residual_keeps_deterministic_copies():
    rng = np.random.default_rng(3)
    w = np.array([0.5, 0.26, 0.24, 0.0])
    for _ in range(200):
        c = _offspring(resampling.residual(w, rng), 4)
        assert c[0] >= 2 and c[1] >= 1 and c[3] == 0 and c.sum() == 4


def test_scheme_outputs_are_reproducible():
    w = np.random.default_rng(1).dirichlet(np.ones(30))
    for name in SCHEMES:
        a = resampling.get_scheme(name)(w, np.random.default_rng(99))
        b = resampling.get_scheme(name)(w, np.random.default_rng(99))
        assert np.array_equal(a, b)
    with pytest.raises(ValueError):
        resampling.get_scheme("nope")


def test_ess_bounds():
    n = 50
    assert resampling.ess(np.full(n, 1.0 / n)) == pytest.approx(n, rel=1e-12)
    delta = np.zeros(n)
    delta[17] = 1.0
    assert resampling.ess(delta) == pytest.approx(1.0, rel=1e-12)
    rng = np.random.default_rng(5)
    for _ in range(100):
        w = rng.dirichlet(np.full(n, rng.uniform(0.01, 5)))
        e = resampling.ess(w)
        assert 1.0 - 1e-9 <= e <= n + 1e-9
        # log-domain version agrees, from unnormalised log weights with a huge offset
        with np.errstate(divide="ignore"):
            lw = np.log(w) + 1234.5
        assert resampling.log_ess(lw) == pytest.approx(np.log(e), abs=1e-9)
    # two equal particles out of n -> ESS = 2
    w = np.zeros(n)
    w[[3, 9]] = 0.5
    assert resampling.ess(w) == pytest.approx(2.0)


def test_log_weight_normalisation():
    lw = np.array([-1000.0, -1001.0, -np.inf, -999.0])
    w = resampling.weights_from_log(lw)
    ref = np.exp(lw - lw[3])
    assert np.allclose(w, ref / ref.sum(), rtol=1e-14)
    assert w[2] == 0.0 and w.sum() == pytest.approx(1.0, abs=1e-15)
    assert resampling.logsumexp(resampling.normalise_log_weights(lw)) == pytest.approx(0.0, abs=1e-12)
    assert resampling.logsumexp(np.array([-np.inf, -np.inf])) == -np.inf
    with pytest.raises(FloatingPointError):
        resampling.normalise_log_weights(np.array([-np.inf, -np.inf]))
