"""Data association of gated measurements: PDA, ELPDA (paper eqs. 9-13) and JPDA.

Notation (per target and part): m measurements z_j in a gate of area V, predicted measurement z^
with innovation covariance S, detection probability P_D, gate probability P_G, Poisson clutter with
density lambda, so mu_F(m) = e^{-lambda V} (lambda V)^m / m!.

Association probabilities (eqs. 10-12): beta_j ∝ p(z | theta_j, m) p(theta_j | m) with

    p(theta_j | m) = P_D P_G mu_F(m-1) / (m D)   (j >= 1),   (1 - P_D P_G) mu_F(m) / D   (j = 0),
    D = P_D P_G mu_F(m-1) + (1 - P_D P_G) mu_F(m),

(as printed, eq. 12 puts the m of the j >= 1 prior into its denominator next to P_D P_G mu_F(m-1)
only, and the priors then do not sum to one; the version above is Bar-Shalom and Li's, whose
j >= 1 and j = 0 priors add up to one, and which with Poisson clutter reduces to the classical
beta_j ∝ N_j a_j vs beta_0 ∝ lambda (1 - P_D P_G) / P_D),
    p(z | theta_j, m) = V^{-(m-1)} P_G^{-1} N(z_j; z^, S) a_j   (j >= 1),   V^{-m}   (j = 0),     (eq. 11)

where a_j is the attribute likelihood ratio of measurement j (ELPDA: its colour similarity, see
:func:`attribute_ratio`; plain PDA: a_j = 1).

Expected likelihood of a particle x (eq. 13, prior proposal so the q terms cancel):

    p(z | x) = beta_0 V^{-m} + sum_j beta_j V^{-(m-1)} P_G^{-1} N(z_j; h(x), R)
             ∝ beta_0 / V + P_G^{-1} sum_j beta_j N(z_j; h(x), R)      (V^{-(m-1)} is common to all particles)

with R = R_k, the covariance the re-estimated gate learns from the innovations (the paper's
N(z_k, z^j_k, R_k); ``GateConfig.r_in_likelihood``): sharp while the target is measured close to its
prediction, wider while it is missed, so the measurement that finds it again reaches the particles.

Plain PDA (the PDAF, the EPMCMC + PDA baseline) instead collapses the gate into one combined
measurement: nu = sum_j beta_j (z_j - z^), z_c = z^ + nu, with the spread of the innovations
P~ = sum_j beta_j nu_j nu_j^T - nu nu^T, and weighs a particle by

    p(z | x) = N(z_c; h(x), (R + P~) / (1 - beta_0))     (flat when beta_0 = 1: nothing in the gate)

(:func:`pda_log_likelihood`) -- with clutter in the gate z_c lies between the measurements, where the
expected likelihood keeps one mode per measurement.

JPDA (Bar-Shalom; the JPDA-PF baseline of Jaward et al. 2006): targets share one measurement set;
joint events give each target one measurement or none, no measurement to two targets, weight
prod_t [P_D N(z_j(t); z^_t, S_t) / lambda  or  (1 - P_D P_G)]; beta^t_j is the marginal of the events.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from scipy.special import gammaln

LOG_2PI = math.log(2.0 * math.pi)


def mahalanobis2(diff: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """diff^T cov^{-1} diff for 2-D ``diff`` (..., 2) and ``cov`` (..., 2, 2) broadcasting."""
    a, b, d = cov[..., 0, 0], cov[..., 0, 1], cov[..., 1, 1]
    x, y = diff[..., 0], diff[..., 1]
    return (d * x * x - 2 * b * x * y + a * y * y) / (a * d - b * b)


def log_gauss2(diff: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """log N(diff; 0, cov) for 2-D ``diff`` (..., 2) and ``cov`` (..., 2, 2) broadcasting."""
    det = cov[..., 0, 0] * cov[..., 1, 1] - cov[..., 0, 1] * cov[..., 1, 0]
    return -0.5 * mahalanobis2(diff, cov) - 0.5 * np.log(det) - LOG_2PI


def log_poisson(m: np.ndarray, mean: np.ndarray) -> np.ndarray:
    """log mu_F(m) = log Poisson(m; mean); -inf for m < 0."""
    m = np.asarray(m, float)
    out = -mean + m * np.log(mean) - gammaln(np.maximum(m, 0) + 1)
    return np.where(m < 0, -np.inf, out)


def attribute_ratio(rho: np.ndarray, lam: float) -> np.ndarray:
    """g_target(rho) / g_clutter(rho): truncated exponential lam e^{lam (rho-1)} / (1 - e^{-lam}) on [0, 1]
    against a uniform clutter attribute."""
    return lam * np.exp(lam * (np.asarray(rho, float) - 1.0)) / (-math.expm1(-lam))


def association_probabilities(log_gauss: np.ndarray, valid: np.ndarray, volume: np.ndarray,
                              p_detect: float | np.ndarray, p_gate: float, clutter_density: float,
                              attribute: np.ndarray | None = None) -> np.ndarray:
    """beta (..., M+1) of eq. 12 (column 0: no measurement is the target's), summing to 1.

    ``log_gauss`` (..., M): log N(z_j; z^, S); ``valid`` (..., M): which measurement slots are real
    (m = valid.sum(-1)); ``volume`` (...): gate area V; ``attribute`` (..., M) or None: a_j;
    ``p_detect``: a number or one P_D per gate (...) (see :mod:`.occlusion`).
    """
    valid = np.asarray(valid, bool)
    m = valid.sum(axis=-1).astype(float)
    v = np.asarray(volume, float)
    pdpg = np.asarray(p_detect, float) * p_gate
    log_mu_m1 = log_poisson(m - 1, clutter_density * v)
    log_mu_m = log_poisson(m, clutter_density * v)
    # eq. 12 numerators in logs; the common 1/D cancels in the normalisation.
    with np.errstate(divide="ignore"):
        log_pdpg, log_miss = np.log(pdpg), np.log1p(-pdpg)
    log_t = (log_pdpg + log_mu_m1 - np.log(np.maximum(m, 1)) - (m - 1) * np.log(v) - math.log(p_gate))[..., None] + log_gauss
    if attribute is not None:
        log_t = log_t + np.log(attribute)
    log_t = np.where(valid, log_t, -np.inf)
    log_0 = log_miss + log_mu_m - m * np.log(v)
    log_all = np.concatenate([np.asarray(log_0)[..., None] * np.ones(log_t.shape[:-1] + (1,)), log_t], axis=-1)
    mx = np.max(log_all, axis=-1, keepdims=True)
    w = np.exp(log_all - mx)
    return w / w.sum(axis=-1, keepdims=True)


def expected_log_likelihood(diff: np.ndarray, beta: np.ndarray, valid: np.ndarray, volume: np.ndarray,
                            r_cov: np.ndarray, p_gate: float) -> np.ndarray:
    """log of eq. 13 up to a per-gate constant: log(beta_0 / V + P_G^{-1} sum_j beta_j N(z_j; h(x), R)).

    ``diff`` (..., M, 2): z_j - h(x) per particle; ``beta`` (..., M+1) and ``valid`` (..., M),
    ``volume`` (...), ``r_cov`` (..., 2, 2) broadcast against the particle axes.
    """
    lg = log_gauss2(diff, r_cov[..., None, :, :])
    terms = np.where(valid, beta[..., 1:] * np.exp(lg), 0.0).sum(axis=-1) / p_gate
    return np.log(beta[..., 0] / volume + terms)


def pda_log_likelihood(diff_pred: np.ndarray, beta: np.ndarray, valid: np.ndarray, loc_minus_pred: np.ndarray,
                       r_cov: np.ndarray) -> np.ndarray:
    """log N(z_c; h(x), (R + P~) / (1 - beta_0)) of the PDAF's combined measurement, up to a per-gate constant.

    ``diff_pred`` (..., M, 2): z_j - z^ (per gate); ``beta`` (..., M+1), ``valid`` (..., M), ``r_cov``
    (..., 2, 2) per gate; ``loc_minus_pred`` (..., 2): h(x) - z^ per particle (broadcasting against the
    gate axes). Returns 0 where beta_0 = 1.
    """
    b = np.where(valid, beta[..., 1:], 0.0)
    nu = np.einsum("...m,...md->...d", b, diff_pred)
    spread = np.einsum("...m,...mi,...mj->...ij", b, diff_pred, diff_pred) - nu[..., :, None] * nu[..., None, :]
    detect = 1.0 - beta[..., 0]
    cov = (r_cov + spread) / np.maximum(detect, 1e-12)[..., None, None]
    ll = log_gauss2(nu - loc_minus_pred, cov) - log_gauss2(np.zeros_like(nu), cov)  # 0 at the combined measurement
    return np.where(detect > 1e-9, ll, 0.0)


def jpda_probabilities(log_gauss: np.ndarray, gated: np.ndarray, p_detect: float | np.ndarray, p_gate: float,
                       clutter_density: float, max_events: int = 200_000) -> np.ndarray:
    """beta (T, M+1) of joint PDA for T targets sharing M measurements.

    ``log_gauss`` (T, M): log N(z_j; z^_t, S_t); ``gated`` (T, M): z_j inside target t's gate;
    ``p_detect``: a number or one P_D per target (T,).
    Exact enumeration of the feasible joint events (each target: one gated measurement or none, no
    measurement used twice); raises ValueError above ``max_events`` events.
    """
    t_n, m_n = gated.shape
    choices = [[0] + [j + 1 for j in np.flatnonzero(gated[t])] for t in range(t_n)]
    n_events = math.prod(len(c) for c in choices)
    if n_events > max_events:
        raise ValueError(f"JPDA: {n_events} joint events exceed {max_events}; shrink the gates or max_measurements")
    pd = np.broadcast_to(np.asarray(p_detect, float), (t_n,))
    with np.errstate(divide="ignore"):
        log_miss, log_pd = np.log1p(-pd * p_gate), np.log(pd)
    log_hit = np.repeat(log_miss[:, None], m_n + 1, axis=1)
    log_hit[:, 1:] = log_pd[:, None] + log_gauss - math.log(clutter_density)
    events = np.array(list(itertools.product(*choices)), dtype=np.intp).reshape(-1, t_n)
    used = np.sort(events, axis=1)
    ok = ~np.any((used[:, 1:] == used[:, :-1]) & (used[:, 1:] > 0), axis=1)
    events = events[ok]
    log_w = log_hit[np.arange(t_n), events].sum(axis=1)
    w = np.exp(log_w - log_w.max())
    beta = np.zeros((t_n, m_n + 1))
    for t in range(t_n):
        np.add.at(beta[t], events[:, t], w)
    return beta / w.sum()
