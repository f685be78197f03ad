"""The target's own change of size between two frames, measured from its pixels (median flow).

Between scale searches the scale state is predicted by the camera's zoom at the target's ground
point (:meth:`common.single_target.scale.ScaleTracker.predict`). That is the target's change of
size only while the target stays on that ground point: a car driving across an oblique ground
crosses the perspective's scale field, and there the ground's zoom and the car's size part
(uav123-car16: the ground zooms 2000x over 24 s while the car stays within 0.3-1.7x a second,
``tools/zoom_probe.py``). This measures the target's own change instead, as Median Flow does
(Kalal, Mikolajczyk and Matas, "Forward-Backward Error", ICPR 2010):

1. corners (``cv2.goodFeaturesToTrack``) inside an ellipse inscribed in the target's oriented box
   in the previous frame, on a crop about the target resampled so the target is at most
   ``work_length_px`` long (the cost does not grow with the target);
2. tracked into the current frame by pyramidal Lucas-Kanade, each started where the camera's
   motion (the stabiliser's frame-to-frame map) took the ground under it, kept where tracking
   back lands within ``max_fb_error_px`` (forward-backward check);
3. the change of log size is the median over pairs of points of ``log(|q_i - q_j| / |p_i - p_j|)``,
   robust to a minority of points on the background; its variance is the pairs' spread
   (1.4826 MAD)^2 over the number of points, plus the points' own tracking error
   ``point_noise_px`` over the target's size.

:meth:`ScaleTracker.predict` fuses it with the camera's zoom by inverse variance, the zoom's
variance being how far the target's size departs from its ground point's, estimated on line from
the innovations (an adaptive Kalman filter in the manner of Sage and Husa, 1969): it is large
where the two part for seconds (car16's oblique following shot) and small where they agree to
within the measurement's noise (a camera looking down on a flat road, where the zoom is the
better measure of a small target's size).
Deterministic: a function of the two images and the box only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from common.single_target.stabilise import grey


class TargetFlowConfig(BaseModel):
    """The target's own scale change (see :mod:`common.single_target.target_flow`)."""

    model_config = ConfigDict(frozen=True, extra="forbid", use_attribute_docstrings=True)

    enabled: bool = True
    """Measure the target's own change of size and fuse it with the camera's zoom (stabilised sources
    with the scale search only)."""
    min_p_visible: float = Field(0.5, ge=0, le=1)
    """Measure only where the previous estimate's p(V=1|Z) is at least this (the track's "held"): below
    it the box is not known to hold the target, and where the template does not see the target its
    points have little of it to track either (a 17-px truck blurred by fast motion read +11 to +18 %
    a frame while it grew 3 %)."""
    inner_fraction: float = Field(0.9, gt=0, le=1)
    """Corners are taken in the ellipse inscribed in the box shrunk by this (the box's corners are
    background)."""
    work_length_px: float = Field(96.0, ge=16)
    """The crop is resampled so the target's long side is at most this many pixels."""
    max_points: int = Field(60, ge=4)
    """Corners taken on the target."""
    min_points: int = Field(6, ge=3)
    """Fewer points tracked forward and back than this: no measurement (a tiny or textureless target)."""
    min_spacing_fraction: float = Field(0.08, gt=0, le=0.5)
    """Minimum corner spacing as a fraction of the box's short side (at least 2 working pixels)."""
    lk_window_px: int = Field(11, ge=5)
    """Lucas-Kanade window side (working pixels, odd)."""
    lk_levels: int = Field(3, ge=0, le=6)
    """Lucas-Kanade pyramid levels."""
    max_fb_error_px: float = Field(1.0, gt=0)
    """Forward-backward error above which a point is dropped (working pixels)."""
    point_noise_px: float = Field(0.25, gt=0)
    """A tracked point's error (working pixels, 1 sigma): Lucas-Kanade's sub-pixel accuracy. Sets the
    floor of the measurement's variance, (2 sqrt 2 sigma / L)^2 for a target L working pixels long."""
    departure_per_sqrt_s: float = Field(0.5, gt=0)
    """How far the target's change of log size departs from the camera's zoom at its ground point, as
    a random walk (1 sigma per sqrt(second)), before any measurement: a car crossing an oblique view's
    scale field, turning, or climbing a slope. The zoom's variance in the fusion is q = d^2 dt, with d^2
    then estimated from the innovations (see ``departure_time_constant_s``)."""
    departure_time_constant_s: float = Field(1.0, gt=0)
    """The departure's variance is re-estimated from the innovations (the target's own measurement less
    the zoom): their square less the measurement's variance, averaged over this many seconds (an
    exponential window; Sage and Husa's adaptive filter). A camera looking down on a flat road makes
    the two agree to within the measurement's noise, and the zoom is kept; a car driving through an
    oblique view makes them part, and its own measurement is taken."""


@dataclass(frozen=True)
class FlowMeasurement:
    """One frame pair's measurement."""

    dlog: float
    """Change of the target's log size, previous frame -> this frame."""
    var: float
    """Its variance."""
    points: int
    """Points tracked forward and back."""
    length_px: float = float("nan")
    """The target's length in the working pixels it was measured in (the noise floor's L)."""


def noise_floor(point_noise_px: float, length_px: float) -> float:
    """The variance a measurement has whatever its points agree on: each point's tracking error
    ``point_noise_px`` over a target ``length_px`` long (working pixels), (2 sqrt 2 sigma / L)^2."""
    return (2.0 * math.sqrt(2.0) * point_noise_px / length_px) ** 2


def measure_scale_change(cfg: TargetFlowConfig, prev: np.ndarray, cur: np.ndarray,
                         box: tuple[float, float, float, float, float],
                         interframe: np.ndarray | None = None) -> FlowMeasurement | None:
    """The target's change of log size from ``prev`` to ``cur`` (images, RGB or grey, same size),
    the target being in ``box`` = (cx, cy, w, h, theta_deg anticlockwise as displayed) of ``prev``;
    ``interframe`` (3x3, previous -> current pixels: the camera's motion) starts each point's
    tracking where the ground under it went, so the flow only has to find the target's own motion.
    None when too few points on it track (or the box is degenerate or off the frame)."""
    cx, cy, w, h, theta = (float(v) for v in box)
    if not all(math.isfinite(v) for v in (cx, cy, w, h, theta)) or w <= 0 or h <= 0:
        return None
    height, width = np.asarray(prev).shape[:2]
    length = max(w, h)
    f = min(1.0, cfg.work_length_px / length)
    shift = np.zeros(2)
    if interframe is not None:
        g = np.asarray(interframe, float)
        d = g[2, 0] * cx + g[2, 1] * cy + g[2, 2]
        if abs(d) > 1e-12:
            shift = (g[:2, :2] @ [cx, cy] + g[:2, 2]) / d - [cx, cy]
        if not np.all(np.isfinite(shift)) or np.hypot(*shift) > max(width, height):
            shift, interframe = np.zeros(2), None
    # the target (half a length) and its own motion (up to a quarter length a frame: a car at 10 m/s
    # filmed at 10 fps), beyond the camera's
    margin = 0.75 * length + np.abs(shift).max() + cfg.lk_window_px / f
    x0, y0 = max(0, int(math.floor(cx - margin))), max(0, int(math.floor(cy - margin)))
    x1, y1 = min(width, int(math.ceil(cx + margin))), min(height, int(math.ceil(cy + margin)))
    if x1 - x0 < 8 or y1 - y0 < 8:
        return None
    p_img, c_img = grey(np.asarray(prev)[y0:y1, x0:x1]), grey(np.asarray(cur)[y0:y1, x0:x1])
    if f < 1.0:
        size = (max(8, round((x1 - x0) * f)), max(8, round((y1 - y0) * f)))
        p_img = cv2.resize(p_img, size, interpolation=cv2.INTER_AREA)
        c_img = cv2.resize(c_img, size, interpolation=cv2.INTER_AREA)
    fx, fy = p_img.shape[1] / (x1 - x0), p_img.shape[0] / (y1 - y0)
    mask = np.zeros_like(p_img)
    axes = (max(1, int(round(0.5 * cfg.inner_fraction * w * fx))), max(1, int(round(0.5 * cfg.inner_fraction * h * fy))))
    cv2.ellipse(mask, (int(round((cx - x0) * fx)), int(round((cy - y0) * fy))), axes, -theta, 0, 360, 255, -1)
    spacing = max(2.0, cfg.min_spacing_fraction * min(w, h) * f)
    pts = cv2.goodFeaturesToTrack(p_img, cfg.max_points, 0.01, spacing, mask=mask, blockSize=5)
    if pts is None or len(pts) < cfg.min_points:
        return None
    pts = pts.astype(np.float32)
    lk = dict(winSize=(cfg.lk_window_px, cfg.lk_window_px), maxLevel=cfg.lk_levels,
              criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))
    if interframe is not None:
        # each point's start: where the camera's motion took the ground under it (working pixels)
        full = pts.reshape(-1, 2).astype(np.float64) / [fx, fy] + [x0, y0]
        moved = cv2.perspectiveTransform(full.reshape(-1, 1, 2), np.asarray(interframe, float)).reshape(-1, 2)
        guess = ((moved - [x0, y0]) * [fx, fy]).astype(np.float32).reshape(-1, 1, 2)
        if not np.all(np.isfinite(guess)):
            guess = pts.copy()
        nxt, st, _ = cv2.calcOpticalFlowPyrLK(p_img, c_img, pts, guess.copy(), flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **lk)
    else:
        nxt, st, _ = cv2.calcOpticalFlowPyrLK(p_img, c_img, pts, None, **lk)
    # back from where each point went, started by the camera's inverse motion (the same prior as forward)
    start = nxt - (guess - pts) if interframe is not None else nxt.copy()
    back, st2, _ = cv2.calcOpticalFlowPyrLK(c_img, p_img, nxt, start, flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **lk)
    fb = np.linalg.norm((back - pts).reshape(-1, 2), axis=1)
    ok = (st.ravel() == 1) & (st2.ravel() == 1) & (fb < cfg.max_fb_error_px)
    p, q = pts.reshape(-1, 2)[ok].astype(np.float64), nxt.reshape(-1, 2)[ok].astype(np.float64)
    n = len(p)
    if n < cfg.min_points:
        return None
    i, j = np.triu_indices(n, 1)
    dp = np.linalg.norm(p[i] - p[j], axis=1)
    dq = np.linalg.norm(q[i] - q[j], axis=1)
    use = (dp >= spacing) & (dq > 0)
    if use.sum() < cfg.min_points:
        return None
    lr = np.log(dq[use] / dp[use])
    med = float(np.median(lr))
    mad = 1.4826 * float(np.median(np.abs(lr - med)))
    return FlowMeasurement(dlog=med, var=mad ** 2 / n + noise_floor(cfg.point_noise_px, length * f), points=n,
                           length_px=length * f)
