"""Camera-motion estimation for sources without a homography (stabilisation).

A moving UAV camera moves the whole image; the filters' motion model should describe the
target's motion over the ground, not the camera's. Without a known camera pose the ground is
taken as the first frame's pixels (the world frame), and each frame's world -> image homography
is accumulated from frame-to-frame homographies estimated from the background:

1. corners (``cv2.goodFeaturesToTrack``) in the previous frame, away from a disc around the
   target's last estimate (the target moves differently from the ground);
2. tracked into the current frame by pyramidal Lucas-Kanade (``cv2.calcOpticalFlowPyrLK``),
   kept only where tracking back lands within ``max_fb_error_px`` of the start
   (forward-backward check);
3. a homography (or a simpler model) fitted with RANSAC (``cv2.findHomography``);
4. ``H_t = G_t @ H_{t-1}`` with ``G_t`` the previous-image -> current-image map.

Robustness: too few tracked features, too few RANSAC inliers, or an implausible ``G_t`` (a
frame-to-frame scale change or shear beyond ``max_interframe_scale``) keep the previous
frame-to-frame motion (the camera is assumed to keep moving as it did) and are counted in
:attr:`CameraMotionEstimator.fallbacks`.

Determinism: every step is a deterministic function of the two images (OpenCV's RANSAC uses its
own fixed-seed generator, corner and flow computations are per pixel / per point), so the same
frames give bit-identical homographies, whatever OpenCV's thread count (checked with 1, 2, 4 and
8 threads; the tests run 1 and 4 in separate processes). The thread count is therefore left
alone (``cv2.setNumThreads`` is process-wide).

Cost: frames are analysed at most ``max_side_px`` on their long side (landscape or portrait alike);
most of the cost is the forward and backward Lucas-Kanade passes over the ``max_features`` corners.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import cv2
import numpy as np
from pydantic import AliasChoices, BaseModel, ConfigDict, Field


class StabiliserConfig(BaseModel):
    """How the camera motion is estimated (see :mod:`common.single_target.stabilise`)."""

    model_config = ConfigDict(frozen=True, extra="forbid", use_attribute_docstrings=True)

    model: Literal["homography", "affine", "similarity"] = "homography"
    """Frame-to-frame motion model: a full homography (a planar ground seen by a moving, rotating
    camera), a 6-parameter affine map, or a 4-parameter similarity."""
    max_features: int = Field(150, ge=8)
    """Corners detected per frame (a homography needs 4; RANSAC over 150 spread over the frame, each
    checked forward and backward, is plenty)."""
    quality_level: float = Field(0.01, gt=0, lt=1)
    """goodFeaturesToTrack quality level."""
    min_distance_fraction: float = Field(0.01, gt=0, le=0.2)
    """Minimum corner spacing as a fraction of the image diagonal (spreads the features over the frame
    whatever the resolution)."""
    exclusion_lengths: float = Field(2.0, ge=0)
    """Radius of the disc around the target's last estimate where no feature is taken, in target lengths
    (the target's long side at its current scale)."""
    min_exclusion_px: float = Field(16.0, ge=0)
    """... and at least this many pixels."""
    lk_window_px: int = Field(21, ge=5)
    """Lucas-Kanade window side (pixels, odd)."""
    lk_levels: int = Field(4, ge=0, le=8)
    """Lucas-Kanade pyramid levels above the full image (4: displacements up to about a window times 2^4
    per frame)."""
    max_fb_error_px: float = Field(1.0, gt=0)
    """Forward-backward tracking error above which a feature is dropped."""
    ransac_threshold_px: float = Field(2.0, gt=0)
    """RANSAC inlier threshold (reprojection, pixels)."""
    min_inliers: int = Field(12, ge=4)
    """Fewer RANSAC inliers than this: keep the previous motion."""
    min_inlier_fraction: float = Field(0.25, ge=0, le=1)
    """... or fewer than this fraction of the tracked features."""
    max_interframe_scale: float = Field(1.25, gt=1)
    """Largest plausible frame-to-frame change of scale (or ratio of the two axis scales, for shear):
    beyond it the estimate is rejected as a fallback."""
    max_side_px: int = Field(640, ge=64, validation_alias=AliasChoices("max_side_px", "max_width_px"))
    """Frames whose long side exceeds this are analysed downscaled to it (the homography is rescaled to
    full-resolution pixels). The long side, not the width: a portrait frame is analysed at the
    resolution of the same frame turned landscape (with the width, a 720 x 1280 frame was worked
    at 1.8 times the resolution of a 1280 x 720 one, its features, windows and thresholds at another
    scale). Recorded runs' ``max_width_px`` (its name before) is read as this."""


def grey(image: np.ndarray, factor: float = 1.0) -> np.ndarray:
    """``image`` (RGB or grey, any dtype) as contiguous uint8 grey, resized by ``factor`` (INTER_AREA)."""
    img = np.asarray(image)
    if img.ndim == 3:
        if img.dtype != np.uint8:
            img = np.clip(img, 0, 255).astype(np.uint8)
        g = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    else:
        g = np.clip(img, 0, 255).astype(np.uint8) if img.dtype != np.uint8 else img
    if factor != 1.0:
        g = cv2.resize(g, (round(g.shape[1] * factor), round(g.shape[0] * factor)), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(g)


@dataclass
class MotionEstimate:
    """One frame's result."""

    interframe: np.ndarray
    """3x3 previous image -> this image."""
    world_to_image: np.ndarray
    """3x3 world (first frame pixels) -> this image."""
    features: int
    """Features tracked (after the forward-backward check)."""
    inliers: int
    fallback: bool
    """True when the estimate was rejected and the previous motion kept."""


@dataclass
class CameraMotionEstimator:
    """Accumulates world (first frame pixels) -> image homographies frame by frame.

    ``start(first_image)`` once, then ``update(image, exclude_xy, exclude_radius)`` for each
    later frame in order, with the target's estimate in the PREVIOUS frame (image pixels) and
    the radius of the disc kept free of features.
    """

    config: StabiliserConfig = field(default_factory=StabiliserConfig)
    homography: np.ndarray = field(default_factory=lambda: np.eye(3))
    """World -> image of the latest frame."""
    frames: int = 0
    fallbacks: int = 0
    last: MotionEstimate | None = None
    last_points: np.ndarray | None = None
    """The features tracked in the latest estimate (previous frame, full-resolution pixels)."""
    _prev: np.ndarray | None = None
    _factor: float = 1.0
    _motion: np.ndarray = field(default_factory=lambda: np.eye(3))

    def start(self, image: np.ndarray) -> np.ndarray:
        h, w = np.asarray(image).shape[:2]
        self._factor = min(1.0, self.config.max_side_px / float(max(w, h)))
        self._prev = grey(image, self._factor)
        self.homography = np.eye(3)
        self._motion = np.eye(3)
        self.frames = 1
        self.fallbacks = 0
        self.last = None
        return self.homography.copy()

    # -- estimation ---------------------------------------------------------------------------
    def estimate_interframe(self, prev: np.ndarray, cur: np.ndarray, exclude_xy=None,
                            exclude_radius: float = 0.0) -> tuple[np.ndarray | None, int, int]:
        """(G or None, features tracked, inliers) between two grey images at the working scale."""
        cfg = self.config
        h, w = prev.shape[:2]
        mask = None
        if exclude_xy is not None and exclude_radius > 0 and np.all(np.isfinite(exclude_xy)):
            ex, ey = float(exclude_xy[0]), float(exclude_xy[1])
            radius = min(float(exclude_radius), float(np.hypot(w, h)))
            # only a disc that can reach the image (an estimate far outside it excludes nothing)
            if -radius <= ex <= w + radius and -radius <= ey <= h + radius:
                mask = np.full((h, w), 255, np.uint8)
                cv2.circle(mask, (int(round(ex)), int(round(ey))), int(np.ceil(radius)), 0, -1)
                if not mask.any():
                    mask = None  # the disc covers the frame: use every feature rather than none
        min_dist = max(1.0, cfg.min_distance_fraction * float(np.hypot(w, h)))
        pts = cv2.goodFeaturesToTrack(prev, cfg.max_features, cfg.quality_level, min_dist, mask=mask,
                                      blockSize=7)
        self.last_points = np.zeros((0, 2))
        if pts is None or len(pts) < 4:
            return None, 0, 0
        pts = pts.astype(np.float32)
        lk = dict(winSize=(cfg.lk_window_px, cfg.lk_window_px), maxLevel=cfg.lk_levels,
                  criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))
        nxt, st, _ = cv2.calcOpticalFlowPyrLK(prev, cur, pts, None, **lk)
        back, st2, _ = cv2.calcOpticalFlowPyrLK(cur, prev, nxt, None, **lk)
        fb = np.linalg.norm((back - pts).reshape(-1, 2), axis=1)
        ok = (st.ravel() == 1) & (st2.ravel() == 1) & (fb < cfg.max_fb_error_px * self._factor)
        src, dst = pts.reshape(-1, 2)[ok], nxt.reshape(-1, 2)[ok]
        self.last_points = src / self._factor  # full-resolution pixels of the previous frame
        n = int(len(src))
        if n < max(4, cfg.min_inliers):
            return None, n, 0
        thr = cfg.ransac_threshold_px * self._factor
        if cfg.model == "homography":
            G, inl = cv2.findHomography(src, dst, cv2.RANSAC, thr, maxIters=2000, confidence=0.995)
        else:
            fit = cv2.estimateAffine2D if cfg.model == "affine" else cv2.estimateAffinePartial2D
            A, inl = fit(src, dst, method=cv2.RANSAC, ransacReprojThreshold=thr, maxIters=2000,
                         confidence=0.995, refineIters=10)
            G = None if A is None else np.vstack([A, [0.0, 0.0, 1.0]])
        if G is None or inl is None:
            return None, n, 0
        n_in = int(inl.sum())
        if n_in < cfg.min_inliers or n_in < cfg.min_inlier_fraction * n:
            return None, n, n_in
        return np.asarray(G, np.float64), n, n_in

    def _plausible(self, G: np.ndarray, size: tuple[int, int]) -> bool:
        if not np.all(np.isfinite(G)) or abs(G[2, 2]) < 1e-12:
            return False
        G = G / G[2, 2]
        w, h = size
        c = np.array([w / 2.0, h / 2.0])
        # local linear part at the image centre
        den = G[2, 0] * c[0] + G[2, 1] * c[1] + G[2, 2]
        if den <= 0:
            return False
        uv = (G[:2, :2] @ c + G[:2, 2]) / den
        J = (G[:2, :2] - np.outer(uv, G[2, :2])) / den
        sv = np.linalg.svd(J, compute_uv=False)
        m = self.config.max_interframe_scale
        return bool(np.linalg.det(J) > 0 and sv[0] < m and sv[1] > 1.0 / m and sv[0] / sv[1] < m)

    def update(self, image: np.ndarray, exclude_xy=None, exclude_radius: float = 0.0) -> np.ndarray:
        """World -> image homography of ``image``, the frame after the previous call's.

        ``exclude_xy``: the target's estimate in the previous frame (full-resolution pixels);
        ``exclude_radius``: radius (pixels) of the disc about it where no feature is taken."""
        if self._prev is None:
            return self.start(image)
        f = self._factor
        cur = grey(image, f)
        ex = None if exclude_xy is None else np.asarray(exclude_xy, float) * f
        G, n, n_in = self.estimate_interframe(self._prev, cur, ex, exclude_radius * f)
        fallback = G is None or not self._plausible(G, (cur.shape[1], cur.shape[0]))
        if fallback:
            Gf = self._motion  # keep the previous frame-to-frame motion (full resolution)
            self.fallbacks += 1
        else:
            G = G / G[2, 2]
            S = np.diag([f, f, 1.0])
            Gf = np.linalg.inv(S) @ G @ S  # working scale -> full-resolution pixels
            self._motion = Gf
        H = Gf @ self.homography
        self.homography = H / H[2, 2]
        self._prev = cur
        self.frames += 1
        self.last = MotionEstimate(interframe=Gf.copy(), world_to_image=self.homography.copy(),
                                   features=n, inliers=n_in, fallback=fallback)
        return self.homography.copy()
