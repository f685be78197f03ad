"""Dynamical models (Pang et al. 2010 §4; Nelson et al. 2008 §III-C).

The transition factorises (Pang eq. 6) into three independent components, each
a small frozen pydantic model that declares its parameters (with units and
paper source) and does its own maths:

* :class:`NearConstantVelocity` -- X = [x, vx, y, vy], X_t = F X_{t-1} + w_t,
  w_t ~ N(0, Q_w) with the exact discretised white-noise-acceleration
  covariance of Pang eq. 8, T taken from the frame timestamps.
* :class:`OrientationRandomWalk` -- theta_t ~ N(theta_{t-1}, q_theta) (Pang eq. 10),
  in degrees, wrapped to [-180, 180).
* :class:`VisibilityMarkovChain` -- V in {0, 1} with
  p(V_t=0 | V_{t-1}=1) = P_NV and p(V_t=1 | V_{t-1}=0) = P_V (Pang eq. 11).

Units. Positions/velocities are in *world* units: metres and m/s when the
observation supplies a ground-plane homography, pixels and px/s when it does
not (the image is then the world frame). q_x, q_y are in world-units^2 / s^3
(Pang Table 1 gives 625 m^2 s^-3).
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field


class _Component(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", use_attribute_docstrings=True)


def wrap_degrees(theta: np.ndarray | float) -> np.ndarray:
    """Wrap angles in degrees to [-180, 180)."""
    return (np.asarray(theta, dtype=float) + 180.0) % 360.0 - 180.0


class NearConstantVelocity(_Component):
    """Near-constant-velocity (white-noise acceleration) model on X = [x, vx, y, vy].

    X_t = F(T) X_{t-1} + w_t,  w_t ~ N(0, Q_w(T)),  with, per axis a in {x, y},

        F_a = [[1, T], [0, 1]],    Q_a = q_a [[T^3/3, T^2/2], [T^2/2, T]]      (Pang eqs. 7-8)

    and T the elapsed time between the two frames' timestamps (seconds).
    """

    q_x: float = Field(625.0, ge=0.0)
    """Driving-noise (acceleration) spectral density along world x, world-units^2/s^3.
    Pang 2010 Table 1: 625 m^2 s^-3 (Nelson 2008 Table I uses S_x = 1600)."""
    q_y: float = Field(625.0, ge=0.0)
    """Driving-noise spectral density along world y, world-units^2/s^3. Pang 2010 Table 1: 625."""

    def transition_matrix(self, dt: float) -> np.ndarray:
        """F(T) of Pang eq. 7, (4, 4)."""
        f = np.eye(4)
        f[0, 1] = f[2, 3] = dt
        return f

    def covariance(self, dt: float) -> np.ndarray:
        """Q_w(T) of Pang eq. 8, (4, 4)."""
        block = np.array([[dt**3 / 3.0, dt**2 / 2.0], [dt**2 / 2.0, dt]])
        q = np.zeros((4, 4))
        q[:2, :2] = self.q_x * block
        q[2:, 2:] = self.q_y * block
        return q

    def covariance_cholesky(self, dt: float) -> np.ndarray:
        """Lower-triangular L with L L^T = Q_w(T), in closed form (valid at T = 0).

        Per axis: L_a = sqrt(q_a) [[T^{3/2}/sqrt(3), 0], [sqrt(3)/2 T^{1/2}, 1/2 T^{1/2}]].
        """
        if dt < 0:
            raise ValueError(f"dt must be >= 0, got {dt}")
        r = np.sqrt(dt)
        block = np.array([[dt * r / np.sqrt(3.0), 0.0], [np.sqrt(3.0) / 2.0 * r, 0.5 * r]])
        chol = np.zeros((4, 4))
        chol[:2, :2] = np.sqrt(self.q_x) * block
        chol[2:, 2:] = np.sqrt(self.q_y) * block
        return chol

    def predict_mean(self, states: np.ndarray, dt: float) -> np.ndarray:
        """F X for each row of ``states`` (N, 4)."""
        return np.asarray(states, dtype=float) @ self.transition_matrix(dt).T

    def sample(self, states: np.ndarray, dt: float, rng: np.random.Generator) -> np.ndarray:
        """Draw X_t ~ N(F X_{t-1}, Q_w) for each row of ``states`` (N, 4).

        Uses exactly N*4 standard normals from ``rng`` (row-major), so runs are reproducible.
        """
        states = np.asarray(states, dtype=float)
        noise = rng.standard_normal(states.shape)
        return states @ self.transition_matrix(dt).T + noise @ self.covariance_cholesky(dt).T


def jump_mixture_log_weights(residual: np.ndarray, q: np.ndarray, jump_std: float, eps: np.ndarray | float,
                             share: float) -> np.ndarray:
    """log p(x' | x) / q(x' | x) for candidates drawn from a two-component proposal.

    The model: x' = F x + w (+ j with probability ``eps``), w ~ N(0, Q), j ~ N(0, jump_std^2) on
    the two position components; so p = (1 - eps) N(r; 0, Q) + eps N(r; 0, Q + J) with r = x' - F x
    (``residual``, (M, 4); ``eps`` scalar or per candidate). A fraction ``share`` of the candidates
    was drawn from N(0, Q + J), the rest from N(0, Q); every candidate is weighted against the
    mixture of the two, q = (1 - share) N(r; 0, Q) + share N(r; 0, Q + J) (deterministic-mixture
    multiple importance sampling: unbiased, and unlike weighting each candidate against its own
    component, of bounded variance where the jump component is far wider than the NCV one).
    """
    r = np.asarray(residual, float)
    big = q.copy()
    big[0, 0] += jump_std**2
    big[2, 2] += jump_std**2

    def logpdf(cov):
        sign, logdet = np.linalg.slogdet(cov)
        if sign <= 0:
            raise ValueError("motion covariance is not positive definite (dt = 0?)")
        sol = np.linalg.solve(cov, r.T).T
        return -0.5 * (np.einsum("ij,ij->i", r, sol) + logdet + 4 * np.log(2 * np.pi))

    l_small, l_big = logpdf(q), logpdf(big)
    eps = np.broadcast_to(np.asarray(eps, float), l_small.shape)
    with np.errstate(divide="ignore"):
        log_p = np.logaddexp(np.log1p(-eps) + l_small, np.log(eps) + l_big)
    log_q = np.logaddexp(np.log1p(-share) + l_small, np.log(share) + l_big) if share < 1 else l_big
    return log_p - log_q


class OrientationRandomWalk(_Component):
    """theta_t | theta_{t-1} ~ N(theta_{t-1}, var), theta in degrees, result wrapped to [-180, 180).

    theta is the target's in-image orientation relative to the template,
    anticlockwise as displayed (the Polar Matching angle; Pang §3).
    """

    q_theta: float = Field(16.0, ge=0.0)
    """Driving-noise variance of the orientation random walk. deg^2 per frame when per='frame'
    (Pang 2010 Table 1: 16 deg^2, at T = 1/3 s), deg^2/s when per='second'."""
    per: Literal["frame", "second"] = "frame"
    """'frame': variance q_theta per filter step whatever the elapsed time (Pang eq. 10 as published);
    'second': variance q_theta * T, a Brownian walk in continuous time."""

    def variance(self, dt: float) -> float:
        """Variance (deg^2) of one step of elapsed time ``dt`` seconds."""
        return self.q_theta if self.per == "frame" else self.q_theta * dt

    def sample(self, theta: np.ndarray, dt: float, rng: np.random.Generator) -> np.ndarray:
        """Draw theta_t for each entry of ``theta`` (N,), using N standard normals."""
        theta = np.asarray(theta, dtype=float)
        return wrap_degrees(theta + np.sqrt(self.variance(dt)) * rng.standard_normal(theta.shape))


class VisibilityMarkovChain(_Component):
    """Two-state Markov chain on V in {0 (occluded), 1 (visible)}, one transition per filter step.

        p(V_t = 0 | V_{t-1} = 1) = P_NV,     p(V_t = 1 | V_{t-1} = 0) = P_V      (Pang eq. 11)
    """

    p_nv: float = Field(0.1, ge=0.0, le=1.0)
    """P_NV, probability that a visible target becomes occluded at the next frame.
    Pang 2010 Table 1: 0.1 (Nelson 2008 Table I: 0.1)."""
    p_v: float = Field(0.1, ge=0.0, le=1.0)
    """P_V, probability that an occluded target becomes visible at the next frame.
    Pang 2010 Table 1: 0.1 (Nelson 2008 Table I: 0.25)."""

    def transition_matrix(self) -> np.ndarray:
        """A[i, j] = p(V_t = j | V_{t-1} = i), rows/columns ordered (0 = occluded, 1 = visible)."""
        return np.array([[1.0 - self.p_v, self.p_v], [self.p_nv, 1.0 - self.p_nv]])

    def predict(self, p_visible: np.ndarray) -> np.ndarray:
        """p(V_t = 1) = p(V_{t-1} = 1)(1 - P_NV) + p(V_{t-1} = 0) P_V   (Pang eq. 25, A.3)."""
        p = np.asarray(p_visible, dtype=float)
        return p * (1.0 - self.p_nv) + (1.0 - p) * self.p_v

    def predict_log(self, log_p: np.ndarray) -> np.ndarray:
        """Log-domain prediction: log p(V_t = j) = logsumexp_i [log p(V_{t-1} = i) + log A[i, j]].

        ``log_p`` is (N, 2) with columns (V = 0, V = 1); returns (N, 2).
        """
        with np.errstate(divide="ignore"):
            log_a = np.log(self.transition_matrix())
        return np.logaddexp(log_p[:, [0]] + log_a[0], log_p[:, [1]] + log_a[1])

    def sample(self, v: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Draw V_t given V_{t-1} for each entry of ``v`` (N,) of 0/1, using N uniforms. Returns int8."""
        v = np.asarray(v).astype(bool)
        u = rng.random(v.shape)
        stay_visible = u >= self.p_nv  # visible -> visible with prob 1 - P_NV
        become_visible = u < self.p_v  # occluded -> visible with prob P_V
        return np.where(v, stay_visible, become_visible).astype(np.int8)
