"""Constrained genetic moves of the EPMCMC filter (paper sections 3.1.2-3.1.4).

Particles of one population are arrays (N, P, 4) of [x, y, vx, vy] per part. Moves work on the
*relative* representation (root absolute, every other part relative to its parent) so that the
pictorial structure is respected:

* crossover (3.1.2): a pair of particles swaps the relative states of one part and all its
  descendants -- a connected piece of the neighbour graph hung on the edge to its parent (an arm
  with its forearm, a leg, the head); the crossover point is a random non-root part. Offsets only
  ever come from valid configurations, so children satisfy every structure constraint.
* mutation (3.1.3): every component (x, y of every part's offset; vx, vy) mutates with its own
  probability rho_m (0 for components that must not fluctuate) by a Gaussian step -- the real-valued
  counterpart of flipping a bit of the binary string. A mutant outside the structure is rejected
  (MH) or projected back (sampling step).
* exchange (3.1.4): particles of two populations (targets) s, q swap with probability min(1, A),
  A = pi_s(x_q) pi_q(x_s) / (pi_s(x_s) pi_q(x_q))  (eq. 8), which leaves pi_s x pi_q invariant.

All random draws come from the ``rng`` passed in.
"""

from __future__ import annotations

import numpy as np

from .body import BodyModel
from .motion import project_to_structure


def relative_state(particles: np.ndarray, body: BodyModel) -> np.ndarray:
    """(..., P, 4) absolute -> relative (positions and velocities relative to the parent): the
    body's map works column by column, so one call does both."""
    return body.to_relative(particles)


def absolute_state(rel: np.ndarray, body: BodyModel) -> np.ndarray:
    """Inverse of :func:`relative_state`."""
    return body.to_absolute(rel)


def crossover(a: np.ndarray, b: np.ndarray, body: BodyModel, prob: float,
              rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Children of pairs (a[i], b[i]) (both (K, P, 4)) and the (K,) mask of pairs that crossed.

    Draw order: K uniforms (cross or not), K integers (crossover part).
    """
    k_n = a.shape[0]
    do = rng.random(k_n) < prob
    point = rng.integers(1, max(body.n_parts, 2), size=k_n)
    if body.n_parts < 2:
        return a.copy(), b.copy(), np.zeros(k_n, bool)
    masks = np.stack([body.subtree(p) for p in range(body.n_parts)])  # (P, P)
    swap = masks[point] & do[:, None]  # (K, P)
    ra, rb = relative_state(a, body), relative_state(b, body)
    ca = np.where(swap[..., None], rb, ra)
    cb = np.where(swap[..., None], ra, rb)
    return absolute_state(ca, body), absolute_state(cb, body), do


def mutate(particles: np.ndarray, body: BodyModel, height: float, p_position: float, p_velocity: float,
           sigma: float, sigma_velocity: float, rng: np.random.Generator, project: bool,
           velocity_gain: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Mutants of (K, P, 4) particles and the (K,) bool of those that satisfy the structure.

    Each of the 4P relative components mutates independently: positions with probability
    ``p_position`` by N(0, (sigma H)^2), velocities with ``p_velocity`` by N(0, sigma_velocity^2).
    ``project``: clip offending offsets back into the structure (then every mutant is valid).
    ``velocity_gain`` (P, 2): each part's velocity also moves by gain * (its absolute position step),
    per axis -- the regression of velocity on position of the population, so that a move towards
    the evidence carries the velocity that would have brought the part there. Without projection
    the step is a linear map of a symmetric draw, so the proposal stays symmetric (plain MH ratio).
    Draw order: (K, P, 4) uniforms, (K, P, 4) normals.
    """
    rel = relative_state(particles, body)
    u = rng.random(rel.shape)
    step = rng.standard_normal(rel.shape)
    prob = np.array([p_position, p_position, p_velocity, p_velocity])
    scale = np.array([sigma * height, sigma * height, sigma_velocity, sigma_velocity])
    rel = rel + np.where(u < prob, step * scale, 0.0)
    if project:
        rel[..., :2] = project_to_structure(rel[..., :2], body, height)
    out = absolute_state(rel, body)
    if velocity_gain is not None:
        out[..., 2:] += velocity_gain * (out[..., :2] - particles[..., :2])
    return out, body.satisfies(out[..., :2], height)


def exchange_log_ratio(log_s_of_xs: np.ndarray, log_s_of_xq: np.ndarray,
                       log_q_of_xs: np.ndarray, log_q_of_xq: np.ndarray) -> np.ndarray:
    """log A of eq. 8: log pi_s(x_q) + log pi_q(x_s) - log pi_s(x_s) - log pi_q(x_q)."""
    return log_s_of_xq + log_q_of_xs - log_s_of_xs - log_q_of_xq


def exchange(xs: np.ndarray, xq: np.ndarray, log_s_of_xs: np.ndarray, log_s_of_xq: np.ndarray,
             log_q_of_xs: np.ndarray, log_q_of_xq: np.ndarray,
             rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exchange move between paired states xs[k] (chain s) and xq[k] (chain q), (K, ...) each.

    Returns the new states of both chains and the (K,) bool of accepted swaps (min(1, A), eq. 8).
    One uniform per pair.
    """
    acc = mh_accept(exchange_log_ratio(log_s_of_xs, log_s_of_xq, log_q_of_xs, log_q_of_xq), rng)
    a = acc.reshape(acc.shape + (1,) * (xs.ndim - 1))
    return np.where(a, xq, xs), np.where(a, xs, xq), acc


def mh_accept(log_ratio: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Metropolis-Hastings: accept with probability min(1, exp(log_ratio)) (one uniform each)."""
    log_ratio = np.asarray(log_ratio, float)
    u = rng.random(log_ratio.shape)
    return np.log(u) < np.where(np.isnan(log_ratio), -np.inf, log_ratio)
