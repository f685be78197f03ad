"""Test images: analytically rotated Gaussian blobs, rotation of real photographs, data paths."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
from scipy import ndimage

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("POLARTRACK_DATA", REPO.parent / "shared" / "data"))


def blob_image(angle_deg: float, size: int = 256, n: int = 60, seed: int = 0,
               centre: tuple[float, float] | None = None, channels: int = 1) -> np.ndarray:
    """Anisotropic Gaussian blobs rendered already rotated anticlockwise (as displayed) by
    ``angle_deg`` about ``centre``: no resampling error. Same seed -> same blob layout."""
    rng = np.random.default_rng(seed)
    cx, cy = centre if centre is not None else (size / 2, size / 2)
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64)
    a = np.deg2rad(angle_deg)
    img = np.zeros((size, size, channels))
    for _ in range(n):
        dx0, dy0 = rng.uniform(-0.4 * size, 0.4 * size, 2)
        sx, sy = rng.uniform(2, 8, 2)
        th = rng.uniform(0, np.pi)
        amp = rng.uniform(-1, 1, channels)
        # anticlockwise as displayed: y points down
        px = cx + dx0 * np.cos(a) + dy0 * np.sin(a)
        py = cy - dx0 * np.sin(a) + dy0 * np.cos(a)
        t = th + a
        dx, dy = xx - px, yy - py
        u = dx * np.cos(t) - dy * np.sin(t)
        v = dx * np.sin(t) + dy * np.cos(t)
        img += amp * np.exp(-0.5 * (u**2 / sx**2 + v**2 / sy**2))[:, :, None]
    return img[:, :, 0] if channels == 1 else img


def rotate_about(img: np.ndarray, centre: tuple[float, float], angle_deg: float, order: int = 5) -> np.ndarray:
    """Rotate ``img`` anticlockwise (as displayed) by ``angle_deg`` about pixel ``centre`` with a
    spline of ``order`` (mirror boundary)."""
    m = cv2.getRotationMatrix2D((float(centre[0]), float(centre[1])), float(angle_deg), 1.0)
    fwd = np.vstack([m, [0, 0, 1]])
    inv = np.linalg.inv(fwd)
    # ndimage works in (row, col): swap x and y
    p = np.array([[0, 1, 0], [1, 0, 0], [0, 0, 1]], float)
    inv_rc = p @ inv @ p
    src = np.asarray(img, np.float64)
    chans = src[:, :, None] if src.ndim == 2 else src
    out = np.stack([ndimage.affine_transform(chans[:, :, c], inv_rc[:2, :2], offset=inv_rc[:2, 2],
                                             order=order, mode="mirror") for c in range(chans.shape[2])], axis=2)
    return out[:, :, 0] if src.ndim == 2 else out


def angle_error(measured: float, truth: float) -> float:
    return float((measured - truth + 180.0) % 360.0 - 180.0)
