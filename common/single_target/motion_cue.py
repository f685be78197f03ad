"""The moving-target cue: where the stabilised frame differs from its recent past, something moves
over the ground.

Settings: :class:`common.settings.MotionCueSettings`. A small target's template is mostly its
surroundings (the P-matrix's footprint is several target lengths across), so the polar match can
hold on to the ground the target stood on while the target drives away: on uav123-truck4 (an
11x8 px truck) the estimate stayed within 3 px of the first frame's ground point for 150 frames,
with p(V=1|Z) = 1 (docs/real-footage.md). The camera's motion is known once the frames are
stabilised, and a vehicle moves over the ground: what moves shows in the difference of the current
frame and past frames carried into it by the stabiliser's homographies.

For a frame at time t, over a square region about the last estimate (``region_lengths`` target
lengths either way), on grey levels, with ``W_s`` the past frame at time t - s warped into the
current one:

    d(x)   = min(|I_t - W_D|, |I_t - W_2D|)            double difference, D = ``baseline_s``
    e(b)   = mean of d over the box b (the target's current size) centred on a hypothesis
    z(b)   = (e(b) - median e) / max(1.4826 MAD e, median e / 2)
                                                         over the target-sized boxes tiling the
                                                         region at half a box's spacing
    log r  = -log(2 P(N(0, 1) >= clip(z, 0, z_cap)))     added to the particle's log weight

The double difference keeps only where the current frame differs from *both* past frames: the
target's present position, not the ground it has just uncovered (a single difference lights up
both, and the ghost holds the track where it was). The robust z-score measures a box's motion
energy against the region's own background (parallax, residual stabilisation error, noise, the
night's grain), so the cue needs no calibration. The ratio is that of a target that surely shows
at least this much motion energy against the background's Gaussian tail, capped at ``z_cap``
(beyond it real backgrounds have heavier tails than a Gaussian). A target that stops shows no
energy: z <= 0 gives ratio 1, and the polar match alone decides; a box on the ground the target
left gives ratio 1 too. Where a past frame does not cover a pixel, d is 0 there (no evidence), and a
box not wholly covered is left out of the region's statistics and scored 0 (after a fast pan or a
jump of the camera much of the frame is ground that has just come into view).

The ratio multiplies the particle's likelihood under both visibility hypotheses: it says where
the target is likely to be, not whether the template sees it there. Added to the visible
hypothesis only, any other mover (a look-alike, a car passing the frame edge while the target
is out of view) raised p(V=1|Z) on its own, for single frames, which reset the loss timer and
paused the search (the synthetic exit sequence: 9 searched frames instead of 30); and on
uav123-truck4 the track held on 2 of 5 seeds instead of 4 (docs/real-footage.md).

The cue works on a Gaussian pyramid level at which the target is at most ``analysis_length_px``
long, so its CPU per frame is bounded whatever the target's size. It is a deterministic function
of the frames and the stabiliser's homographies: the same frames give the same cue in-process,
in the tracker service and on offline replay.
"""

from __future__ import annotations

import math
from collections import deque

import cv2
import numpy as np
from scipy.stats import norm

_BLUR_SIGMA = 1.0
"""Gaussian blur of the difference image (pixels at the analysis level): sensor noise is per
pixel, a moving target's difference is coherent over many."""
_RELATIVE_FLOOR = 0.25
"""Smallest robust spread of the box energies as a fraction of their median: a box must exceed the
region's typical energy by a good part of it, not only by many sigmas of a spread that averaging
over the box has made tiny (a quiet, exactly stabilised background): where only one of the two
differences is noise (the ground a mover has just left), the minimum of the two is about 1.5 times
the background's minimum of two noises. A quarter keeps such a ghost below about 2.5 sigma on the
generated scenes of the tests; half lost truck4 and S1001 (docs/real-footage.md)."""
_MAD_FLOOR = 0.25
"""... and in grey levels: a flat, noiseless region must not turn rounding into a large z."""


class MotionCue:
    """The cue of one track (see the module docstring): ``update`` once a frame before the filter
    step, then ``log_ratio`` for the hypotheses of that frame."""

    def __init__(self, cfg, box_size: tuple[float, float]):
        self.cfg = cfg
        self.box_size = (float(box_size[0]), float(box_size[1]))
        """The first box's (w, h), image pixels; a hypothesis' box is this times the scale s."""
        self._history: deque[tuple[float, np.ndarray, np.ndarray]] = deque()
        self._integral: np.ndarray | None = None
        self._origin = (0.0, 0.0)
        self._factor = 1.0
        self._stats: tuple[float, float] | None = None
        self._grid = np.zeros((0, 2))
        self._diff: np.ndarray | None = None
        self._blobs: tuple[np.ndarray, np.ndarray] | None = None
        """The difference map's moving blobs (labels, stats), found once per map (:meth:`blob_box`)."""
        self._seen: np.ndarray | None = None
        """Analysis pixels both past frames saw (where d is a measurement)."""
        self._seen_integral: np.ndarray | None = None
        self._scale = 1.0
        self.frames_with_cue = 0

    def update(self, time: float, image: np.ndarray, homography: np.ndarray, centre: tuple[float, float],
               scale: float) -> None:
        """Take frame ``image`` at ``time`` with its accumulated ``homography`` (first frame's pixels ->
        this image), and prepare the cue around ``centre`` (the last estimate, image pixels) for
        boxes of the target at scale ``scale``: :meth:`push` then :meth:`prepare`."""
        self.push(time, image, homography)
        self.prepare(centre, scale)

    def push(self, time: float, image: np.ndarray, homography: np.ndarray) -> None:
        """Take frame ``image`` at ``time`` with its accumulated ``homography`` (first frame's pixels ->
        this image); the cue is unprepared until :meth:`prepare`."""
        grey = image if image.ndim == 2 else cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
        self._history.append((float(time), grey, np.asarray(homography, float)))
        horizon = float(time) - 2 * self.cfg.baseline_s
        while len(self._history) > 3 and self._history[1][0] <= horizon + 1e-9:
            self._history.popleft()
        self._integral = None
        self._stats = None

    def prepare(self, centre: tuple[float, float], scale: float) -> None:
        """Prepare the cue of the latest frame pushed around ``centre`` (image pixels) for boxes of the
        target at scale ``scale``."""
        self._integral = None
        self._stats = None
        self._scale = float(scale)
        if not self._history or not all(math.isfinite(v) for v in centre):
            return
        time, grey, h_now = self._history[-1]
        pair = self._past_pair(time)
        if pair is None:
            return
        length = max(self.box_size) * self._scale
        r = self.cfg.region_lengths * length + 2 * length
        height, width = grey.shape[:2]
        rect = (max(0, int(centre[0] - r)), max(0, int(centre[1] - r)),
                min(width, int(math.ceil(centre[0] + r))), min(height, int(math.ceil(centre[1] + r))))
        if self._prepare(grey, h_now, pair, rect, margin=0.0):
            self.frames_with_cue += 1

    def movers(self, scale: float) -> tuple[np.ndarray, np.ndarray]:
        """The whole latest frame's target-sized boxes at scale ``scale`` (half a box apart, at least a
        box length inside the frame's edge, where the past frames' coverage ends) and the robust
        z-score of each one's motion energy against all of them: (xy (n, 2) image pixels, z (n,));
        empty when the history is too short. Replaces the prepared cue (call :meth:`prepare` after)."""
        self._scale = float(scale)
        empty = (np.zeros((0, 2)), np.zeros(0))
        if not self._history:
            return empty
        time, grey, h_now = self._history[-1]
        pair = self._past_pair(time)
        height, width = grey.shape[:2]
        if pair is None or not self._prepare(grey, h_now, pair, (0, 0, width, height),
                                             margin=max(self._box())):
            return empty
        return self._grid, self.z_scores(self._grid)

    def _past_pair(self, time: float):
        """The frames about ``baseline_s`` and twice that before ``time``; before the history holds
        that much, the longest whole baseline it holds (from the third frame on)."""
        past = list(self._history)[:-1]
        if len(past) < 2:
            return None
        d = self.cfg.baseline_s
        if time - past[0][0] < 2 * d - 1e-9:
            n = len(past) // 2
            return past[-n], past[-2 * n]
        a = min(past, key=lambda h: abs(h[0] - (time - d)))
        b = min(past, key=lambda h: abs(h[0] - (time - 2 * d)))
        return (a, b) if a is not b else None

    def _prepare(self, grey: np.ndarray, h_now: np.ndarray, pair, rect: tuple[int, int, int, int],
                 margin: float) -> bool:
        """The double difference's integral image over ``rect`` (x0, y0, x1, y1) of the current image
        and the median and spread of the target-sized boxes tiling it (``margin`` pixels inside it):
        whether there were enough boxes."""
        cfg = self.cfg
        self._integral = None
        self._stats = None
        length = max(self.box_size) * self._scale
        level = max(0, int(math.ceil(math.log2(max(length / cfg.analysis_length_px, 1.0)) - 1e-9)))
        f = 0.5 ** level
        x0, y0, x1, y1 = rect
        out_w, out_h = int((x1 - x0) * f), int((y1 - y0) * f)
        if out_w < 8 or out_h < 8:
            return False
        # current-image pixels -> analysis pixels
        to_out = np.array([[f, 0, -x0 * f], [0, f, -y0 * f], [0, 0, 1.0]])
        cur, _ = _warped(grey, to_out, level, (out_w, out_h), coverage=False)
        diffs = []
        seen = np.ones((out_h, out_w), bool)
        for _, past, h_past in pair:
            try:
                m = to_out @ h_now @ np.linalg.inv(h_past)  # past image -> analysis pixels
                w, covered = _warped(past, m, level, (out_w, out_h))
            except np.linalg.LinAlgError:
                return False
            diffs.append(np.where(covered, np.abs(cur - w), 0.0).astype(np.float32))
            seen &= covered
        d = cv2.GaussianBlur(np.minimum(diffs[0], diffs[1]), (0, 0), _BLUR_SIGMA)
        self._integral = cv2.integral(d, sdepth=cv2.CV_64F)
        self._seen_integral = cv2.integral(seen.astype(np.uint8), sdepth=cv2.CV_64F)
        self._diff = d
        self._blobs = None
        self._seen = seen
        self._origin = (float(x0), float(y0))
        self._factor = f
        # the background: boxes of the target's size tiling the region
        bw, bh = self._box()
        step = max(bw, bh) / 2  # boxes overlapping by half: the strongest box is near the peak
        gx, gy = np.meshgrid(np.arange(x0 + max(bw / 2, margin), x1 - max(bw / 2, margin) + 1e-9, step),
                             np.arange(y0 + max(bh / 2, margin), y1 - max(bh / 2, margin) + 1e-9, step))
        grid = np.stack([gx.ravel(), gy.ravel()], axis=1)
        e = self._box_means(grid)
        ok = np.isfinite(e)
        if ok.sum() < cfg.min_boxes:
            self._integral = None
            return False
        self._grid = grid[ok]
        e = e[ok]
        med = float(np.median(e))
        spread = max(1.4826 * float(np.median(np.abs(e - med))), _RELATIVE_FLOOR * med, _MAD_FLOOR)
        self._stats = (med, spread)
        return True

    def blob_box(self, xy: tuple[float, float]) -> tuple[float, float, float, float] | None:
        """The moving blob at ``xy`` (image pixels) of the map last prepared: the pixels of the
        difference image above the map's median by three robust sigmas, connected to ``xy`` (the
        largest such component within three analysis pixels). Its bounding box (x0, y0, w, h),
        image pixels; None: no blob there."""
        d = self._diff
        if self._integral is None or d is None or not self._seen.any():
            return None
        if self._blobs is None:  # the map's statistics and components: once for all the blobs asked of it
            known = d[self._seen]  # where both past frames saw the ground (elsewhere d is no evidence)
            med = float(np.median(known))
            spread = max(1.4826 * float(np.median(np.abs(known - med))), _MAD_FLOOR)
            mask = ((d > med + 3.0 * spread) & self._seen).astype(np.uint8)
            self._blobs = cv2.connectedComponentsWithStats(mask, connectivity=8)[1:3]
        labels, stats = self._blobs
        f = self._factor
        px = int(round((xy[0] - self._origin[0]) * f))
        py = int(round((xy[1] - self._origin[1]) * f))
        r = 3
        window = labels[max(0, py - r):py + r + 1, max(0, px - r):px + r + 1]
        ids = [int(i) for i in np.unique(window) if i > 0]
        if not ids:
            return None
        i = max(ids, key=lambda i: stats[i, cv2.CC_STAT_AREA])
        return (float(stats[i, cv2.CC_STAT_LEFT] / f + self._origin[0]),
                float(stats[i, cv2.CC_STAT_TOP] / f + self._origin[1]),
                float(stats[i, cv2.CC_STAT_WIDTH] / f), float(stats[i, cv2.CC_STAT_HEIGHT] / f))

    def blob_scale(self, xy: tuple[float, float]) -> float | None:
        """The target's scale s read off the moving blob at ``xy`` (:meth:`blob_box`): the blob spans
        the target and, along its direction of travel, the ground it crossed within the baseline;
        across it, the target's own extent. Its bounding box's short side over the first box's short
        side (None: no blob there)."""
        box = self.blob_box(xy)
        if box is None:
            return None
        return float(min(box[2], box[3]) / min(self.box_size))

    def _box(self) -> tuple[float, float]:
        return (max(self.box_size[0] * self._scale, 2.0), max(self.box_size[1] * self._scale, 2.0))

    def _box_means(self, xy: np.ndarray) -> np.ndarray:
        """Mean of d over the target-sized box centred on each image point (NaN off the region, and
        where a past frame did not see all of the box: a box half on ground that has just come into
        view is not a box of little motion, and counted as one it pulls the background's median
        down and every box's z up)."""
        ii = self._integral
        hh, ww = ii.shape[0] - 1, ii.shape[1] - 1
        bw, bh = self._box()
        f = self._factor
        x = (xy[:, 0] - self._origin[0]) * f
        y = (xy[:, 1] - self._origin[1]) * f
        with np.errstate(invalid="ignore"):
            xa = np.clip(np.round(x - bw * f / 2), 0, ww).astype(np.int64)
            xb = np.clip(np.round(x + bw * f / 2), 0, ww).astype(np.int64)
            ya = np.clip(np.round(y - bh * f / 2), 0, hh).astype(np.int64)
            yb = np.clip(np.round(y + bh * f / 2), 0, hh).astype(np.int64)
        area = (xb - xa) * (yb - ya)
        s = ii[yb, xb] - ii[ya, xb] - ii[yb, xa] + ii[ya, xa]
        cv = self._seen_integral
        seen = cv[yb, xb] - cv[ya, xb] - cv[yb, xa] + cv[ya, xa]
        ok = (area > 0) & np.isfinite(x) & np.isfinite(y) & (seen >= area)
        return np.where(ok, s / np.maximum(area, 1), np.nan)

    def z_scores(self, image_xy: np.ndarray) -> np.ndarray:
        """The robust z-score of each hypothesis box's motion energy (0 where there is no cue)."""
        xy = np.asarray(image_xy, float).reshape(-1, 2)
        if self._integral is None or self._stats is None:
            return np.zeros(len(xy))
        med, spread = self._stats
        z = (self._box_means(xy) - med) / spread
        return np.where(np.isfinite(z), z, 0.0)

    def log_ratio(self, image_xy: np.ndarray) -> np.ndarray:
        """log r per hypothesis (image pixels): the cue's likelihood ratio for the target's position
        there (0: no evidence)."""
        z = np.clip(self.z_scores(image_xy), 0.0, self.cfg.z_cap)
        return -(norm.logsf(z) + math.log(2.0))


def _warped(image: np.ndarray, m: np.ndarray, level: int, size: tuple[int, int],
            coverage: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """``image`` mapped by ``m`` (its pixels -> output pixels) onto an output of ``size``, float32, and
    the output pixels the image covers (None without ``coverage``). Only the part of ``image`` that
    maps into the output is read, taken down ``level`` Gaussian pyramid levels first (``m`` maps
    full-resolution pixels: no aliasing at the analysis resolution)."""
    height, width = image.shape[:2]
    out_w, out_h = size
    step = 2 ** level
    margin = (3 * step if level else 0) + 2  # the pyramid's 5-tap kernels at every level
    corners = np.array([[0, 0, 1], [out_w, 0, 1], [0, out_h, 1], [out_w, out_h, 1]], float)
    src = corners @ np.linalg.inv(m).T
    src = src[:, :2] / src[:, 2:3]
    if not np.all(np.isfinite(src)):
        raise np.linalg.LinAlgError("the map sends the output region to infinity")
    x0 = int(np.clip(np.floor(src[:, 0].min()) - margin, 0, width))
    x1 = int(np.clip(np.ceil(src[:, 0].max()) + margin, 0, width))
    y0 = int(np.clip(np.floor(src[:, 1].min()) - margin, 0, height))
    y1 = int(np.clip(np.ceil(src[:, 1].max()) + margin, 0, height))
    if x1 - x0 < 2 * step or y1 - y0 < 2 * step:
        return np.zeros((out_h, out_w), np.float32), np.zeros((out_h, out_w), bool)
    crop = np.asarray(image[y0:y1, x0:x1], np.float32)
    for _ in range(level):
        crop = cv2.pyrDown(crop)  # pixel u of the level is pixel 2u of the one below
    mc = m @ np.array([[step, 0, x0], [0, step, y0], [0, 0, 1.0]])
    out = cv2.warpPerspective(crop, mc, (out_w, out_h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    if not coverage:
        return out, None
    # covered: the output pixels whose source lies inside the image (not only inside the crop)
    inside = cv2.warpPerspective(np.ones(crop.shape[:2], np.uint8), mc, (out_w, out_h), flags=cv2.INTER_NEAREST,
                                 borderMode=cv2.BORDER_CONSTANT, borderValue=0) > 0
    return out, inside
