"""Constant-velocity motion applied jointly with the pictorial structure (paper section 4).

A particle of one target is an array (P, 4) of [x, y, vx, vy] per part (pixels, px/s). One step
of length T (seconds), for all particles at once:

    a ~ N(0, body_accel^2 T I)                     shared by every part of the body
    v_p <- v_p + a                                  (constant velocity, common acceleration)
    x_p <- x_p + v_p T + e_p,  e_p ~ N(0, s_p^2 T I) (s_p = part_jitter, half of it for torso and head)
    then, parents first, for every non-root part p with parent q:
    d_p = x_p - x_q;  d_p <- d_p + (1 - e^{-rate T}) (mu_p H - d_p)   (relax to the preferred offset)
    d_p <- mu_p H + clip_to_disc(d_p - mu_p H, max_dev_p H)             (the structure constraint)
    v_p <- v_q + c (v_p - v_q)                                          (limbs move with their parent)

so every predicted configuration satisfies the structure constraint of its body model.
"""

from __future__ import annotations

import numpy as np

from .body import BodyModel
from .config import MotionConfig


def project_to_structure(rel: np.ndarray, body: BodyModel, height: np.ndarray) -> np.ndarray:
    """Clip every non-root relative offset in ``rel`` (..., P, 2) to within max_dev H of its preferred
    offset (radially); ``height`` broadcasts against rel[..., 0, 0]."""
    h = np.asarray(height, float)[..., None, None]
    pref = body.offset * h
    d = rel - pref
    norm = np.linalg.norm(d, axis=-1, keepdims=True)
    lim = body.max_dev[:, None] * h
    scale = np.where(norm > lim, lim / np.maximum(norm, 1e-12), 1.0)
    out = pref + d * scale
    out[..., 0, :] = rel[..., 0, :]
    return out


def predict(particles: np.ndarray, body: BodyModel, height: np.ndarray, dt: float,
            cfg: MotionConfig, rng: np.random.Generator) -> np.ndarray:
    """Sample the transition prior for particles (..., N, P, 4); ``height`` (...,) per target.

    Draw order: body accelerations (..., N, 2), then part jitters (..., N, P, 2).
    """
    if dt <= 0:
        return particles.copy()
    lead = particles.shape[:-2]
    pos, vel = particles[..., :2].copy(), particles[..., 2:].copy()
    vel += cfg.body_accel * np.sqrt(dt) * rng.standard_normal(lead + (2,))[..., None, :]
    jitter = np.full(body.n_parts, cfg.part_jitter)
    jitter[[i for i, n in enumerate(body.names) if n in ("torso", "head")]] *= 0.5
    pos += vel * dt + jitter[:, None] * np.sqrt(dt) * rng.standard_normal(pos.shape)
    h = np.asarray(height, float).reshape(np.shape(height) + (1,) * (len(lead) - np.ndim(height)))
    relax = 1.0 - np.exp(-cfg.structure_rate * dt)
    rel = body.to_relative(pos)
    rel[..., 1:, :] += relax * (body.offset[1:] * h[..., None, None] - rel[..., 1:, :])
    pos = body.to_absolute(project_to_structure(rel, body, h))
    c = body.parent >= 0
    vel[..., c, :] = vel[..., body.parent[c], :] + cfg.velocity_coupling * (vel[..., c, :] - vel[..., body.parent[c], :])
    return np.concatenate([pos, vel], axis=-1)
