"""Pinhole camera over the ground plane: pose -> 3x3 homography, and the camera's slow motion.

World frame: x east, y north, z up, metres; the ground is z = 0. Image: x right, y down, pixel
centres at integer coordinates (OpenCV's convention). For a ground point (x, y),
``H @ [x, y, 1]`` is proportional to ``[u, v, 1]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d

from .config import SceneConfig


@dataclass(frozen=True)
class CameraPose:
    """Camera looking down at ``ground_point`` from ``altitude`` metres.

    ``yaw``: direction of the image's x axis on the ground, radians anticlockwise from east.
    ``tilt``: angle of the optical axis from nadir, leaning towards the image's top (radians).
    ``focal``: focal length in pixels; ``cx, cy``: principal point.
    """

    ground_point: tuple[float, float]
    altitude: float
    yaw: float
    tilt: float
    focal: float
    cx: float
    cy: float

    def rotation(self) -> np.ndarray:
        """World -> camera rotation (rows: the camera's x, y, z axes in world coordinates)."""
        cps, sps = np.cos(self.yaw), np.sin(self.yaw)
        x = np.array([cps, sps, 0.0])  # image right
        y = np.array([sps, -cps, 0.0])  # image down (nadir)
        z = np.array([0.0, 0.0, -1.0])  # looking down
        ct, st = np.cos(self.tilt), np.sin(self.tilt)
        y2 = ct * y + st * z
        z2 = ct * z - st * y  # optical axis leans towards the image's top
        return np.stack([x, y2, z2])

    def centre(self) -> np.ndarray:
        """Camera centre in the world (its optical axis hits the ground at ``ground_point``)."""
        r = self.rotation()
        dist = self.altitude / np.cos(self.tilt)
        return np.array([*self.ground_point, 0.0]) - dist * r[2]

    def homography(self) -> np.ndarray:
        """3x3 map from ground (x, y, 1) to image pixels (homogeneous), normalised to H[2, 2] = 1."""
        r = self.rotation()
        c = self.centre()
        k = np.array([[self.focal, 0, self.cx], [0, self.focal, self.cy], [0, 0, 1.0]])
        h = k @ np.column_stack([r[:, 0], r[:, 1], -r @ c])
        return h / h[2, 2]


def project(h: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply homography ``h`` to (..., 2) points."""
    pts = np.asarray(pts, float)
    q = pts @ h[:, :2].T + h[:, 2]
    return q[..., :2] / q[..., 2:3]


FOLLOW_REACH = 0.8
"""The smoothed target path stays within this fraction of the frame's half short side of the
camera's ground point (at the first frame's zoom)."""


def camera_trajectory(
    cfg: SceneConfig, target_xy: np.ndarray, rng: np.random.Generator
) -> tuple[list[CameraPose], np.ndarray]:
    """Per-frame camera poses and homographies ((n, 3, 3), float64).

    The camera's ground point is the mean of the target path, pulled ``camera_follow`` of the way
    towards a heavily smoothed copy of it (and no further from it than :data:`FOLLOW_REACH`),
    plus a smooth drift and a small wobble. Its yaw starts
    with the image's long side along the path's main direction and turns by
    ``camera_rotation_deg``; its focal length changes by ``camera_zoom_change``.
    """
    n = cfg.n_frames
    t = np.arange(n) / cfg.fps
    ramp = 0.5 - 0.5 * np.cos(np.pi * np.arange(n) / max(n - 1, 1))  # 0 -> 1, smooth

    centre = target_xy.mean(axis=0)
    smooth = gaussian_filter1d(target_xy, sigma=2.0 * cfg.fps, axis=0, mode="nearest")
    drift_dir = rng.uniform(-np.pi, np.pi)
    drift = cfg.camera_drift_m * (ramp - 0.5)[:, None] * np.array([np.cos(drift_dir), np.sin(drift_dir)])
    freqs = rng.uniform(0.3, 1.2, size=(2, 2))
    phases = rng.uniform(0, 2 * np.pi, size=(2, 2))
    wobble = cfg.camera_jitter_m * np.stack(
        [np.sin(2 * np.pi * freqs[a, 0] * t + phases[a, 0]) * 0.6
         + np.sin(2 * np.pi * freqs[a, 1] * t + phases[a, 1]) * 0.4 for a in range(2)],
        axis=1,
    )
    ground = centre + cfg.camera_follow * (smooth - centre)
    # A camera that follows the target keeps it in view however long the run: the smoothed path
    # never further from the ground point than FOLLOW_REACH of the frame's half short side. (Only
    # long scenes reach it: over 30 minutes the path spans kilometres, and half of it away from
    # the mean had left the car ~40 km off the image.)
    reach = FOLLOW_REACH * 0.5 * min(cfg.width, cfg.height) / cfg.pixels_per_metre
    away = ground - smooth
    dist = np.linalg.norm(away, axis=1, keepdims=True)
    ground = np.where(dist > reach, smooth + away * (reach / np.maximum(dist, 1e-12)), ground)
    ground = ground + drift + wobble

    # image x along the main direction of the path (so the landscape frame holds it best)
    d = target_xy - centre
    evals, evecs = np.linalg.eigh(d.T @ d)
    main = evecs[:, np.argmax(evals)]
    yaw0 = np.arctan2(main[1], main[0]) + rng.uniform(-0.15, 0.15)
    yaw = yaw0 + np.deg2rad(cfg.camera_rotation_deg) * (ramp - 0.5)

    tilt = np.deg2rad(cfg.camera_tilt_deg)
    f0 = cfg.pixels_per_metre * cfg.camera_altitude_m / np.cos(tilt)
    focal = f0 * (1.0 + cfg.camera_zoom_change * ramp)
    cx, cy = (cfg.width - 1) / 2.0, (cfg.height - 1) / 2.0
    poses = [
        CameraPose((float(ground[i, 0]), float(ground[i, 1])), cfg.camera_altitude_m, float(yaw[i]),
                   float(tilt), float(focal[i]), cx, cy)
        for i in range(n)
    ]
    hs = np.stack([p.homography() for p in poses])
    return poses, hs
