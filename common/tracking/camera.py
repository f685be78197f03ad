"""Ground-plane homographies: world (x, y) <-> image pixels (Pang eq. 3, H known).

``None`` stands for the identity (the image is the world frame, in pixels).
"""

from __future__ import annotations

import numpy as np


def _as_points(pts: np.ndarray) -> np.ndarray:
    pts = np.asarray(pts, dtype=float)
    if pts.shape[-1] != 2:
        raise ValueError(f"points must have shape (..., 2), got {pts.shape}")
    return pts


def apply_homography(h: np.ndarray | None, pts: np.ndarray) -> np.ndarray:
    """Map points (..., 2) through the 3x3 homography ``h``: [u, v, w]^T = h [x, y, 1]^T, -> (u/w, v/w)."""
    pts = _as_points(pts)
    if h is None:
        return pts.copy()
    h = np.asarray(h, dtype=float)
    num = pts @ h[:2, :2].T + h[:2, 2]
    w = pts @ h[2, :2] + h[2, 2]
    return num / w[..., None]


def invert_homography(h: np.ndarray | None) -> np.ndarray | None:
    """The inverse homography (None stays None)."""
    return None if h is None else np.linalg.inv(np.asarray(h, dtype=float))


def world_to_image(h: np.ndarray | None, world_xy: np.ndarray) -> np.ndarray:
    """Ground-plane points (..., 2) -> image pixels (..., 2) through the world->image homography ``h``."""
    return apply_homography(h, world_xy)


def image_to_world(h: np.ndarray | None, image_xy: np.ndarray) -> np.ndarray:
    """Image pixels (..., 2) -> ground-plane points, inverting the world->image homography ``h``."""
    return apply_homography(invert_homography(h), image_xy)


def homography_jacobian(h: np.ndarray | None, pts: np.ndarray) -> np.ndarray:
    """d(u, v)/d(x, y) of the homography at each point: (..., 2, 2).

    With w = h20 x + h21 y + h22 and (u, v) the mapped point,
    du/dx = (h00 - u h20)/w, du/dy = (h01 - u h21)/w, dv/dx = (h10 - v h20)/w, dv/dy = (h11 - v h21)/w.
    """
    pts = _as_points(pts)
    if h is None:
        return np.broadcast_to(np.eye(2), pts.shape[:-1] + (2, 2)).copy()
    h = np.asarray(h, dtype=float)
    uv = apply_homography(h, pts)
    w = pts @ h[2, :2] + h[2, 2]
    jac = h[:2, :2] - uv[..., :, None] * h[2, :2]
    return jac / w[..., None, None]
