"""The orientation's locally optimal proposal from the detector's 48-angle scores (not in the papers).

Pang's RBPF proposes ``theta_t`` from its random-walk prior and scores each particle at that one
angle, so a particle at the right place with an orientation a few degrees off is judged by a
poor score. But one batched ``score_grid`` query (48 angles per position, the same cost as
``score_at``) gives each particle's whole score curve ``s_p(theta)``: the polar-matching
correlation has angular harmonics -6..14 only (:mod:`common.detector.matcher`), so the 48 samples
determine ``s_p`` exactly at every angle (trigonometric interpolation, :func:`curve_at`).

With that curve the orientation is integrated out numerically and then sampled from its
posterior, the locally optimal proposal (Doucet, Godsill & Andrieu 2000) for ``theta``:

    theta_j   = theta_{t-1,p} + sigma u_j,  u_j on a fixed grid over [-span, span]   (prior nodes)
    g_j       ∝ exp(-u_j^2 / 2),  sum_j g_j = 1                      (the random walk, discretised)
    m_pj      = sum_v l(s_p(theta_j) | v) pi^-_p(v)                  (visibility marginalised)
    m_p       = sum_j g_j m_pj                                       (the particle's weight factor)
    j_p       ~ g_j m_pj / m_p;   theta_{t,p} = theta_j_p            (the orientation's posterior)

i.e. the orientation random walk is taken as the discrete distribution ``g`` on the nodes (a
quadrature of the Gaussian at 0.25 sigma spacing), under which this is exact. Everything is in
the log domain; one uniform draw per particle.
"""

from __future__ import annotations

import numpy as np
from scipy.special import logsumexp

from .observation import N_ANGLES as N_GRID
from .resampling import draw_per_row

MAX_HARMONIC = 14
"""Highest angular harmonic of a polar-matching score curve (|h| <= 14: exactly represented by
48 samples, whose Nyquist limit is 23)."""


def prior_nodes(span: float = 4.0, per_sigma: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Standardised nodes ``u`` over [-span, span] at 1/per_sigma spacing and their normalised log
    weights (the discretised standard normal)."""
    n = int(round(span * per_sigma))
    u = np.arange(-n, n + 1) / per_sigma
    lg = -0.5 * u * u
    return u, lg - logsumexp(lg)


def curve_coefficients(grid: np.ndarray) -> np.ndarray:
    """Harmonic coefficients (N, 15) ``c_h`` with ``s(theta) = Re sum_h c_h exp(i h theta)``,
    h = 0..14, from the scores (N, 48) at 0, 7.5, ..., 352.5 degrees."""
    grid = np.asarray(grid, float)
    if grid.ndim != 2 or grid.shape[1] != N_GRID:
        raise ValueError(f"grid scores must be (N, {N_GRID}), got {grid.shape}")
    c = np.fft.rfft(grid, axis=1)[:, :MAX_HARMONIC + 1] / N_GRID
    c[:, 1:] *= 2.0
    return c


def curve_at(coeffs: np.ndarray, theta_deg: np.ndarray) -> np.ndarray:
    """Scores at angles ``theta_deg`` (N, J) of the curves ``coeffs`` (N, 15): (N, J)."""
    th = np.deg2rad(np.asarray(theta_deg, float))
    h = np.arange(coeffs.shape[1])
    basis = np.exp(1j * th[..., None] * h)
    return np.einsum("njh,nh->nj", basis, coeffs).real


def sample_orientation(grid: np.ndarray, theta_prev: np.ndarray, sigma_deg: float, log_pv_prior: np.ndarray,
                       log_likelihood, rng: np.random.Generator, span: float = 4.0,
                       per_sigma: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Sample each particle's orientation from its posterior on the prior's nodes.

    grid (N, 48) scores; theta_prev (N,) degrees; sigma_deg the random walk's step std;
    log_pv_prior (N, 2) predicted log pi^-(v); ``log_likelihood(scores) -> (..., 2)``.
    Returns theta (N,) degrees (unwrapped), log m_p (N,), the score at theta (N,), and the
    joint log l(v) + log pi^-(v) at theta (N, 2). Uses N uniforms from ``rng``.
    """
    n = len(theta_prev)
    coeffs = curve_coefficients(grid)
    if sigma_deg <= 0:
        s = curve_at(coeffs, np.asarray(theta_prev, float)[:, None])[:, 0]
        joint = log_pv_prior + log_likelihood(s)
        rng.uniform(size=n)  # keep the draw count independent of sigma
        return np.asarray(theta_prev, float).copy(), np.logaddexp(joint[:, 0], joint[:, 1]), s, joint
    u, log_g = prior_nodes(span, per_sigma)
    nodes = np.asarray(theta_prev, float)[:, None] + sigma_deg * u[None, :]  # (N, J)
    s = curve_at(coeffs, nodes)
    joint = log_pv_prior[:, None, :] + log_likelihood(s)  # (N, J, 2)
    log_mj = np.logaddexp(joint[..., 0], joint[..., 1]) + log_g  # log g_j m_pj
    log_m = logsumexp(log_mj, axis=1)
    j = draw_per_row(log_mj, log_m, rng)
    rows = np.arange(n)
    return nodes[rows, j], log_m, s[rows, j], joint[rows, j]
