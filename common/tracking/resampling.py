"""Resampling schemes and weight helpers, all in one place.

Every scheme is a plain function ``(weights, rng) -> ancestor indices`` (as in
Chopin's ``particles.resampling``): ``weights`` are the N normalised weights
(they are renormalised defensively), ``rng`` is the caller's
:class:`numpy.random.Generator` (the only source of randomness), and the result
is an ``int`` array of N ancestor indices, sorted ascending for the
inverse-CDF schemes. A particle of zero weight is never selected.

All four schemes are unbiased: E[#offspring of i] = N * w_i. They differ in
variance: multinomial >= residual, stratified >= systematic in practice
(Douc, Cappé & Moulines 2005). Systematic resampling (Kitagawa 1996) is the
scheme used by both Pang et al. (2010, §6) and Nelson et al. (2008, §III-E);
its offspring count for particle i is always floor(N w_i) or ceil(N w_i).

Log-domain helpers: weights are carried as unnormalised log weights and
normalised with log-sum-exp.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

Resampler = Callable[[np.ndarray, np.random.Generator], np.ndarray]
"""A resampling scheme: (normalised weights (N,), rng) -> ancestor indices (N,)."""


# ----------------------------------------------------------------------------- log-domain helpers


def logsumexp(log_w: np.ndarray) -> float:
    """log(sum(exp(log_w))), stable; -inf when every entry is -inf."""
    log_w = np.asarray(log_w, dtype=float)
    m = np.max(log_w)
    if not np.isfinite(m):
        return float(m)  # all -inf -> -inf (or +inf / nan propagate)
    return float(m + np.log(np.sum(np.exp(log_w - m))))


def normalise_log_weights(log_w: np.ndarray) -> np.ndarray:
    """log W_i = log w_i - logsumexp(log w): the normalised log weights.

    Raises ``FloatingPointError`` if every weight is zero (log weight -inf) or
    a log weight is NaN/+inf: there is no distribution to normalise.
    """
    lse = logsumexp(log_w)
    if not np.isfinite(lse):
        raise FloatingPointError(f"cannot normalise log weights (logsumexp = {lse})")
    return np.asarray(log_w, dtype=float) - lse


def weights_from_log(log_w: np.ndarray) -> np.ndarray:
    """Normalised linear weights W_i = exp(log w_i - logsumexp(log w)), summing to 1."""
    w = np.exp(normalise_log_weights(log_w))
    return w / w.sum()  # absorb the last ulp so that sum(W) == 1 to machine precision


def ess(weights: np.ndarray) -> float:
    """Effective sample size N_eff = 1 / sum(W_i^2) of (re)normalised weights.

    Kong, Liu & Wong (1994); Pang et al. (2010) eq. 23. 1 <= N_eff <= N, with
    N_eff = N for uniform weights and 1 when one particle holds all the weight.
    """
    w = np.asarray(weights, dtype=float)
    w = w / w.sum()
    return float(1.0 / np.sum(w * w))


def log_ess(log_w: np.ndarray) -> float:
    """log N_eff from unnormalised log weights: 2 logsumexp(log w) - logsumexp(2 log w)."""
    log_w = np.asarray(log_w, dtype=float)
    return 2.0 * logsumexp(log_w) - logsumexp(2.0 * log_w)


# ----------------------------------------------------------------------------- schemes


def _inverse_cdf(weights: np.ndarray, uniforms: np.ndarray) -> np.ndarray:
    """Ancestor index of each uniform in [0, 1): the i with C_{i-1} <= u < C_i.

    C is the cumulative sum of the weights, scaled so that C_{N-1} == 1 exactly;
    a zero-weight particle has an empty interval and is never chosen.
    """
    w = np.asarray(weights, dtype=float)
    if w.ndim != 1 or w.size == 0:
        raise ValueError("weights must be a non-empty 1-D array")
    if np.any(w < 0) or not np.all(np.isfinite(w)):
        raise ValueError("weights must be finite and non-negative")
    cdf = np.cumsum(w)
    if cdf[-1] <= 0:
        raise ValueError("weights sum to zero")
    cdf /= cdf[-1]
    cdf[-1] = 1.0
    idx = np.searchsorted(cdf, uniforms, side="right")
    return np.minimum(idx, w.size - 1).astype(np.intp)


def systematic(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Systematic resampling: one uniform U, points u_k = (k + U) / N, k = 0..N-1."""
    n = np.asarray(weights).size
    u = (np.arange(n) + rng.random()) / n
    return _inverse_cdf(weights, u)


def stratified(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Stratified resampling: one uniform per stratum, u_k = (k + U_k) / N."""
    n = np.asarray(weights).size
    u = (np.arange(n) + rng.random(n)) / n
    return _inverse_cdf(weights, u)


def multinomial(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Multinomial resampling: N i.i.d. draws from the categorical distribution W."""
    n = np.asarray(weights).size
    u = np.sort(rng.random(n))
    return _inverse_cdf(weights, u)


def residual(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Residual resampling: floor(N W_i) deterministic copies of i, then R = N - sum floor(N W_i)
    multinomial draws from the residual weights (N W_i - floor(N W_i)) / R (Liu & Chen 1998)."""
    w = np.asarray(weights, dtype=float)
    w = w / w.sum()
    n = w.size
    nw = n * w
    copies = np.floor(nw).astype(np.intp)
    deterministic = np.repeat(np.arange(n), copies)
    r = n - deterministic.size
    if r == 0:
        return deterministic
    frac = nw - copies
    rest = _inverse_cdf(frac, np.sort(rng.random(r)))
    return np.sort(np.concatenate([deterministic, rest]))


SCHEMES: dict[str, Resampler] = {
    "systematic": systematic,
    "stratified": stratified,
    "multinomial": multinomial,
    "residual": residual,
}
"""Schemes by name, as used in the filter configs' ``resampling`` field."""


def get_scheme(name: str) -> Resampler:
    """The resampling function called ``name`` (one of :data:`SCHEMES`)."""
    try:
        return SCHEMES[name]
    except KeyError:
        raise ValueError(f"unknown resampling scheme {name!r}; choose from {sorted(SCHEMES)}") from None


def draw_per_row(log_p: np.ndarray, log_total: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One index per row of the unnormalised log probabilities ``log_p`` (N, K), given each row's
    ``log_total`` = logsumexp(log_p, axis=1); a row with no finite total is drawn uniformly.
    N uniforms from ``rng``. (The RBPF's candidate selection and orientation sampling.)"""
    n, k = log_p.shape
    finite = np.isfinite(log_total)
    p = np.exp(log_p - np.where(finite, log_total, 0.0)[:, None])
    p[~finite] = 1.0 / k
    cdf = np.cumsum(p, axis=1)
    return np.minimum((cdf < rng.uniform(size=n)[:, None] * cdf[:, -1:]).sum(axis=1), k - 1)
