"""Validation gates and the measurements inside them.

Measurements of a part are the local maxima (3x3) of its colour similarity rho over a grid of
candidate centres around the predicted part position, with rho >= min_similarity, inside the gate;
at most ``max_measurements`` of them (the highest rho). All targets' and parts' grids go to the
:class:`~.appearance.PartEvidence` in one batched call.

Gates: fixed (PDA, JPDA): a circle of radius ``gate_size``, area V = pi r^2. Re-estimated (ELPDA):
the ellipse (z - z^)^T S^{-1} (z - z^) <= gamma, gamma = chi2_2^{-1}(P_G), with S = the weighted
covariance of the predicted part positions + R_k, and R_k re-estimated every frame from the
measurement residuals (:func:`update_measurement_cov`); V = pi gamma sqrt(det S), capped at the
searched square.
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
    """Gated measurements of every (target, part)."""

    z: np.ndarray
    """(T, P, M, 2) measurement positions (padding where not valid)."""
    rho: np.ndarray
    """(T, P, M) colour similarity of each measurement (its attribute)."""
    valid: np.ndarray
    """(T, P, M) bool."""
    volume: np.ndarray
    """(T, P) gate area V, px^2."""
    centre: np.ndarray
    """(T, P, 2) gate centre z^ (predicted part position)."""
    s_cov: np.ndarray
    """(T, P, 2, 2) innovation covariance S used for gating and the association probabilities."""


def _grid(half: float, stride: int) -> np.ndarray:
    k = int(math.floor(half / stride))
    a = np.arange(-k, k + 1) * float(stride)
    gx, gy = np.meshgrid(a, a)
    return np.stack([gx, gy], axis=-1)  # (g, g, 2), row = y


def measure(centre: np.ndarray, part_cov: np.ndarray, r_cov: np.ndarray, box_size: np.ndarray,
            references: np.ndarray, evidence: PartEvidence, cfg: GateConfig) -> Measurements:
    """Gate every (target, part) and find its measurements.

    ``centre`` (T, P, 2) predicted part positions, ``part_cov`` (T, P, 2, 2) their covariance over the
    particles, ``r_cov`` (T, P, 2, 2) measurement covariance R, ``box_size`` (T, P, 2) part boxes,
    ``references`` (T, P, B) reference histograms.
    """
    t_n, p_n = centre.shape[:2]
    if cfg.adaptive:
        s_cov = part_cov + r_cov
        half = 2.0 * cfg.gate_size
    else:
        r2 = cfg.gate_size**2
        s_cov = np.broadcast_to(r2 / gate_gamma(cfg.p_gate) * np.eye(2), (t_n, p_n, 2, 2)).copy()
        half = cfg.gate_size
    grid = _grid(half, cfg.stride)
    g = grid.shape[0]
    off = grid.reshape(-1, 2)
    pos = centre[:, :, None, :] + off  # (T, P, K, 2)
    boxes = part_boxes(pos, np.broadcast_to(box_size[:, :, None, :], pos.shape))
    ref_idx = np.broadcast_to(np.arange(t_n * p_n).reshape(t_n, p_n, 1), pos.shape[:3])
    rho = evidence.similarity(boxes.reshape(-1, 4), references.reshape(t_n * p_n, -1), ref_idx.ravel())
    rho = rho.reshape(t_n, p_n, g, g)
    peaks = rho >= maximum_filter(rho, size=(1, 1, 3, 3), mode="constant", cval=-1.0)
    gamma = gate_gamma(cfg.p_gate)
    if cfg.adaptive:
        inside = mahalanobis2(off, s_cov[:, :, None]) <= gamma
        volume = np.minimum(math.pi * gamma * np.sqrt(np.linalg.det(s_cov)), (2 * half) ** 2)
    else:
        inside = np.broadcast_to(np.sum(off * off, axis=-1) <= cfg.gate_size**2, (t_n, p_n, off.shape[0]))
        volume = np.full((t_n, p_n), math.pi * cfg.gate_size**2)
    ok = peaks.reshape(t_n, p_n, -1) & inside & (rho.reshape(t_n, p_n, -1) >= cfg.min_similarity)
    score = np.where(ok, rho.reshape(t_n, p_n, -1), -np.inf)
    m = min(cfg.max_measurements, score.shape[-1])
    top = np.argsort(-score, axis=-1, kind="stable")[..., :m]
    valid = np.take_along_axis(ok, top, axis=-1)
    return Measurements(
        z=np.take_along_axis(pos, top[..., None], axis=2),
        rho=np.take_along_axis(score, top, axis=-1).clip(min=0.0),
        valid=valid, volume=volume, centre=centre, s_cov=s_cov,
    )  # fmt: skip


def update_measurement_cov(r_cov: np.ndarray, meas: Measurements, beta: np.ndarray, estimate: np.ndarray,
                           rate: float, min_sigma: float) -> np.ndarray:
    """R_k = (1 - rate) R_{k-1} + rate (sum_j beta_j e_j e_j^T + beta_0 R_{k-1}), e_j = z_j - estimate,
    floored at min_sigma^2 I: the measurement noise re-estimated from the data (the gate follows)."""
    e = meas.z - estimate[:, :, None, :]
    outer = e[..., :, None] * e[..., None, :]
    b = np.where(meas.valid, beta[..., 1:], 0.0)
    emp = np.einsum("tpm,tpmij->tpij", b, outer) + beta[..., 0, None, None] * r_cov
    new = (1.0 - rate) * r_cov + rate * emp
    floor = min_sigma**2
    w, v = np.linalg.eigh(new)
    return np.einsum("...ij,...j,...kj->...ik", v, np.maximum(w, floor), v)
