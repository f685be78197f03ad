"""Validation gates and the measurements inside them.

Association units (``GateConfig.level``): ``structure`` associates the whole pictorial structure
(paper section 3.2: "with respect to the whole graph representing the target"): a measurement is a
candidate position z of the root (torso) where the target's predicted configuration, shifted so that
its root is at z, matches the target's colour histograms -- on its core, the parts held rigidly to the
root (torso and head, ``GateConfig.core_deviation``): the limbs swing by more than their boxes, and
shifting the predicted limbs along pulls the match off the torso; ``part`` gates and associates every
part on its own. A measurement's attribute is the match, the mean Bhattacharyya coefficient rho over
the unit's matched parts. Candidates are the local maxima (3x3) of rho over a grid of shifts around the
prediction, with rho >= min_similarity, inside the gate; at most ``max_measurements`` of them (the
highest). All targets' and units' grids go to the :class:`~.appearance.PartEvidence` in one batched
call.

Gates: fixed (PDA, JPDA): a circle of radius ``gate_size``, area V = pi r^2. Re-estimated (ELPDA):
the ellipse (z - z^)^T S^{-1} (z - z^) <= gamma, gamma = chi2_2^{-1}(P_G), with S = the weighted
covariance of the unit's predicted located-part positions + R_k, and R_k re-estimated every frame from the
innovations (:func:`update_measurement_cov`); V = pi gamma sqrt(det S), capped at the searched
square.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import maximum_filter

from .appearance import PartEvidence, part_boxes
from .association import mahalanobis2
from .config import GateConfig


def gate_gamma(p_gate: float) -> float:
    """gamma with P(chi2_2 <= gamma) = P_G: -2 log(1 - P_G)."""
    return -2.0 * math.log1p(-p_gate)


@dataclass(frozen=True)
class Measurements:
    """Gated measurements of every target and association unit (the whole structure, or each part)."""

    z: np.ndarray
    """(T, Q, M, 2) measured positions of each unit's located part (padding where not valid)."""
    rho: np.ndarray
    """(T, Q, M) mean colour similarity of the unit's shifted parts (the measurement's attribute)."""
    valid: np.ndarray
    """(T, Q, M) bool."""
    volume: np.ndarray
    """(T, Q) gate area V, px^2."""
    centre: np.ndarray
    """(T, Q, 2) gate centre z^ (predicted position of the unit's located part)."""
    s_cov: np.ndarray
    """(T, Q, 2, 2) innovation covariance S used for gating and the association probabilities."""
    pred_cov: np.ndarray
    """(T, Q, 2, 2) covariance of the predicted located part over the particles (the prediction's share of S)."""


def units(n_parts: int, level: str, core: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Association units: (Q, P) bool membership and (Q,) located part of each unit.

    ``structure``: one unit located by the root, matched on the parts in ``core`` ((P,) bool; None:
    all parts); ``part``: one unit per part."""
    if level == "structure":
        members = np.ones((1, n_parts), bool) if core is None else np.asarray(core, bool)[None].copy()
        return members, np.zeros(1, np.intp)
    return np.eye(n_parts, dtype=bool), np.arange(n_parts)


def _grid(half: float, stride: int, reach: tuple[float, float] | None = None) -> np.ndarray:
    """(gy, gx, 2) offsets k * stride, |k * stride| <= half; with ``reach`` (x, y) only the offsets within
    one stride beyond it, so that every offset inside the reach keeps all its 3x3 neighbours (the local
    maxima there are those of the full grid)."""
    k = int(math.floor(half / stride))
    kx, ky = (k, k) if reach is None else (min(k, int(math.ceil(r / stride)) + 1) for r in reach)
    gx, gy = np.meshgrid(np.arange(-kx, kx + 1) * float(stride), np.arange(-ky, ky + 1) * float(stride))
    return np.stack([gx, gy], axis=-1)  # (gy, gx, 2), row = y


def measure(parts: np.ndarray, part_cov: np.ndarray, r_cov: np.ndarray, box_size: np.ndarray,
            references: np.ndarray, evidence: PartEvidence, cfg: GateConfig,
            core: np.ndarray | None = None) -> Measurements:
    """Gate every target and unit and find the measurements.

    ``parts`` (T, P, 2) predicted part centres, ``part_cov`` (T, P, 2, 2) their covariance over the
    particles, ``r_cov`` (T, Q, 2, 2) the gates' R, ``box_size`` (T, P, 2) part boxes, ``references``
    (T, P, B) reference histograms, ``core`` (P,) bool or None: the parts a structure-level match
    shifts (see :func:`units`).
    """
    t_n, p_n = parts.shape[:2]
    members, loc = units(p_n, cfg.level, core)
    q_n = len(loc)
    gamma = gate_gamma(cfg.p_gate)
    if cfg.adaptive:
        s_cov = part_cov[:, loc] + r_cov
        half = 2.0 * cfg.gate_size
        # only the ellipses' bounding box is searched: no offset outside it can be inside a gate
        reach = tuple(float(np.sqrt(gamma * np.max(s_cov[..., i, i]))) for i in range(2))
    else:
        s_cov = np.broadcast_to(cfg.gate_size**2 / gate_gamma(cfg.p_gate) * np.eye(2), (t_n, q_n, 2, 2)).copy()
        half = cfg.gate_size
        reach = None
    grid = _grid(half, cfg.stride, reach)
    gy, gx = grid.shape[:2]
    off = grid.reshape(-1, 2)  # (K, 2)
    k_n = len(off)
    pq, pp = np.nonzero(members)  # (unit, part) pairs queried
    pos = parts[:, pp][:, :, None, :] + off  # (T, pairs, K, 2)
    boxes = part_boxes(pos, np.broadcast_to(box_size[:, pp][:, :, None, :], pos.shape))
    ref_idx = np.broadcast_to((np.arange(t_n)[:, None] * p_n + pp)[:, :, None], pos.shape[:3])
    rho = evidence.similarity(boxes.reshape(-1, 4), references.reshape(t_n * p_n, -1), ref_idx.ravel())
    mix = (pq[None, :] == np.arange(q_n)[:, None]) / members.sum(axis=1, keepdims=True)  # (Q, pairs): mean over a unit's parts
    rho = np.einsum("qa,tak->tqk", mix, rho.reshape(t_n, len(pp), k_n))  # (T, Q, K)
    rg = rho.reshape(t_n, q_n, gy, gx)
    peaks = (rg >= maximum_filter(rg, size=(1, 1, 3, 3), mode="constant", cval=-1.0)).reshape(t_n, q_n, k_n)
    if cfg.adaptive:
        inside = mahalanobis2(off, s_cov[:, :, None]) <= gamma
        volume = np.minimum(math.pi * gamma * np.sqrt(np.linalg.det(s_cov)), (2 * half) ** 2)
    else:
        inside = np.broadcast_to(np.sum(off * off, axis=-1) <= cfg.gate_size**2, (t_n, q_n, k_n))
        volume = np.full((t_n, q_n), math.pi * cfg.gate_size**2)
    ok = peaks & inside & (rho >= cfg.min_similarity)
    score = np.where(ok, rho, -np.inf)
    m = min(cfg.max_measurements, k_n)
    top = np.argsort(-score, axis=-1, kind="stable")[..., :m]
    centre = parts[:, loc]
    return Measurements(
        z=centre[:, :, None] + off[top], rho=np.take_along_axis(score, top, axis=-1).clip(min=0.0),
        valid=np.take_along_axis(ok, top, axis=-1), volume=volume, centre=centre, s_cov=s_cov,
        pred_cov=part_cov[:, loc],
    )  # fmt: skip


def update_measurement_cov(r_cov: np.ndarray, meas: Measurements, beta: np.ndarray, rate: float,
                           min_sigma: float, max_sigma: float) -> np.ndarray:
    """The gate's R_k re-estimated from this frame's innovations nu_j = z_j - z^ (z^ the prediction),
    by covariance matching (Mehra 1972: the innovations' covariance is P + R, P the prediction's):

        R_k = (1 - rate) R_{k-1} + rate (sum_j beta_j nu_j nu_j^T + beta_0 max_sigma^2 I - P),

    eigenvalues clipped to [min_sigma^2, max_sigma^2]. The innovations are taken against the
    prediction, not the posterior (which the measurement itself pulls in, so its residuals would
    shrink R frame after frame); the prediction's own spread P (``meas.pred_cov``) is taken out, so
    that a prediction that is off (a velocity too high) does not widen R -- a wide R in eq. 13 would
    weaken the very measurement that corrects it (traced on seed 1: R held the error and the
    estimated speed ran from 35 to 95 px/s). The share beta_0 of "no measurement is the target's"
    relaxes R back to the widest gate, so that a target that is missed gets a wider gate rather than
    keeping a narrow one. Shapes: r_cov (..., 2, 2), meas.z (..., M, 2), beta (..., M+1)."""
    e = meas.z - meas.centre[..., None, :]
    outer = e[..., :, None] * e[..., None, :]
    b = np.where(meas.valid, beta[..., 1:], 0.0)
    emp = np.einsum("...m,...mij->...ij", b, outer) + beta[..., 0, None, None] * max_sigma**2 * np.eye(2) - meas.pred_cov
    new = (1.0 - rate) * r_cov + rate * emp
    w, v = np.linalg.eigh(new)
    return np.einsum("...ij,...j,...kj->...ik", v, np.clip(w, min_sigma**2, max_sigma**2), v)
