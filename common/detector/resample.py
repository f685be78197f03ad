"""Matching on a resampled image: the template's fixed footprint at the target's original size.

The P-matrix footprint is fixed in pixels (levels 2..5, ``SUPPORT_RADIUS_PX`` = 64 px), designed
for a car about 50 px long. A target much smaller than that (real UAV footage: 15-20 px cars),
or one whose apparent size changes (zoom, approach), is matched on a copy of the image resampled
by a factor ``k`` (``k > 1`` enlarges). Hypotheses keep original pixel coordinates: pixel centre
``x`` of the frame sits at ``k * x`` in the resampled image (a scaling about pixel 0), so a
hypothesis' position maps exactly and only the image content is resampled.

Only the area the queried hypotheses need is resampled: their bounding box, times ``k``, plus
``SUPPORT_RADIUS_PX + KERNEL_MARGIN_PX`` resampled pixels on every side (the same margin rule as
:func:`common.detector.frame.prepare_frame` uses for a region), and that crop is prepared whole.
Where the crop passes the frame edge it is filled by symmetric reflection, as the full-frame
preparation pads; a hypothesis is valid (in support) when the target it stands for is in the
frame, ``EDGE_SUPPORT_PX / k`` original pixels about it (the footprint's outer context may read the
reflection). The plain path at ``k == 1`` (:class:`common.detector.observation.DetectorObservation`)
keeps the whole-footprint rule: its full-frame preparation has no reflected margin on the top and
left.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from common.detector.frame import KERNEL_MARGIN_PX, PreparedFrame, prepare_frame
from common.detector.layout import BLOCK, DESIGN_TARGET_PX, N_ANGLES, SUPPORT_RADIUS_PX
from common.detector.matcher import PolarMatcher, check_hypotheses
from common.detector.sampler import sample_pmatrices

CROP_MARGIN_PX = SUPPORT_RADIUS_PX + KERNEL_MARGIN_PX
"""Resampled pixels around the hypotheses' box in a resampled crop (support plus kernel margin)."""

MAX_CROP_PX = 1.0e6
"""Default cap on a resampled crop's pixels (about 150 ms of preparation for RGB here)."""


def quantise_factor(k: float, steps_per_octave: int = 12) -> float:
    """``k`` rounded to the nearest ``2 ** (n / steps_per_octave)`` (exactly 1.0 near 1).

    Quantising keeps the resampling factor constant while the scale drifts by less than half a
    step (3 percent with 12 steps an octave, well inside the matcher's scale tolerance), so the
    plain full-resolution path is kept whenever no resampling is needed."""
    if not math.isfinite(k) or k <= 0:
        raise ValueError(f"resampling factor must be positive and finite, got {k}")
    n = round(math.log2(k) * steps_per_octave)
    return 1.0 if n == 0 else float(2.0 ** (n / steps_per_octave))


class ResampledRegion:
    """One prepared, resampled crop of a frame: maps original pixels to the crop and back."""

    def __init__(self, image: np.ndarray, k: float, box: tuple[float, float, float, float]):
        """Resample ``image`` by ``k`` over the hypothesis-centre ``box`` (x0, y0, x1, y1),
        original pixels, plus the margin, and prepare the crop for polar matching."""
        if not (k > 0 and math.isfinite(k)):
            raise ValueError(f"resampling factor must be positive and finite, got {k}")
        img = np.asarray(image)
        h, w = img.shape[:2]
        m = CROP_MARGIN_PX
        # The crop's origin is on the resampled image's 32-pixel block grid (as a region of a
        # full-frame preparation is), so the DTCWT's sampling lattice does not depend on where
        # the hypotheses happen to be: k = 1 gives the full frame's coefficients.
        X0 = int(math.floor((k * box[0] - m) / BLOCK)) * BLOCK
        Y0 = int(math.floor((k * box[1] - m) / BLOCK)) * BLOCK
        X1 = int(math.ceil(k * box[2])) + m + 1
        Y1 = int(math.ceil(k * box[3])) + m + 1
        W = -(-(X1 - X0) // BLOCK) * BLOCK
        H = -(-(Y1 - Y0) // BLOCK) * BLOCK
        # Source pixels needed (a few more for the interpolation kernel and the blur), clipped to
        # the frame: reflection then happens at the true frame edges only.
        blur = 0.5 * (1.0 / k - 1.0) if k < 1.0 else 0.0
        pad = 4 + int(math.ceil(3 * blur))
        sx0 = max(0, int(math.floor(X0 / k)) - pad)
        sy0 = max(0, int(math.floor(Y0 / k)) - pad)
        sx1 = min(w, int(math.ceil((X0 + W) / k)) + pad + 1)
        sy1 = min(h, int(math.ceil((Y0 + H) / k)) + pad + 1)
        if sx1 <= sx0 or sy1 <= sy0:
            # The box lies entirely outside the frame: take the nearest edge pixels (reflected).
            sx0, sx1 = min(max(0, sx0), w - 1), min(max(1, sx1), w)
            sy0, sy1 = min(max(0, sy0), h - 1), min(max(1, sy1), h)
            sx1, sy1 = max(sx1, sx0 + 1), max(sy1, sy0 + 1)
        src = np.asarray(img[sy0:sy1, sx0:sx1], np.float32)
        if blur > 0:
            # Anti-aliasing before shrinking (the usual sigma = (1/k - 1) / 2).
            src = cv2.GaussianBlur(src, (0, 0), blur, borderType=cv2.BORDER_REFLECT)
        if k == 1.0:
            interp = cv2.INTER_NEAREST  # an integer shift: exact
        else:
            interp = cv2.INTER_CUBIC
        M = np.array([[k, 0.0, k * sx0 - X0], [0.0, k, k * sy0 - Y0]], np.float64)
        out = cv2.warpAffine(src, M, (W, H), flags=interp, borderMode=cv2.BORDER_REFLECT)
        self.k = float(k)
        self.offset = (X0, Y0)
        self.frame_size = (w, h)
        self.prep: PreparedFrame = prepare_frame(out)

    def to_crop(self, xy: np.ndarray) -> np.ndarray:
        """Original pixel centres (N, 2) -> crop pixel centres."""
        return np.column_stack([self.k * xy[:, 0] - self.offset[0], self.k * xy[:, 1] - self.offset[1]])

    def covers(self, xy: np.ndarray) -> bool:
        """Whether every hypothesis lies at least the full margin inside the crop."""
        c = self.to_crop(xy)
        m = CROP_MARGIN_PX
        return bool(np.all((c[:, 0] >= m) & (c[:, 0] <= self.prep.width - 1 - m)
                           & (c[:, 1] >= m) & (c[:, 1] <= self.prep.height - 1 - m)))


EDGE_SUPPORT_PX = DESIGN_TARGET_PX / 2
"""A resampled hypothesis is scored while this many matched pixels about it, half the target length
the layout is designed for, lie in the frame: the target it stands for is in view. The rest of the
footprint (out to ``SUPPORT_RADIUS_PX``) may reach beyond the frame's edge, where the crop holds the
frame reflected (``BORDER_REFLECT``): the context there matches less, the target's own rings as
well as anywhere. Requiring the whole footprint lost a large target near the edge: uav123-truck4's
last 40 frames, a 67 px truck within 1.5 footprints of the bottom edge (docs/real-footage.md)."""


def footprint_valid(xy: np.ndarray, k: float, size: tuple[int, int]) -> np.ndarray:
    """Hypotheses scored at factor ``k`` in the ``size`` = (width, height) frame: at least
    ``EDGE_SUPPORT_PX / k`` original pixels inside it, the footprint (``SUPPORT_RADIUS_PX / k``
    either way) no wider than the frame, so that it passes at most one edge on each axis (a
    footprint larger than the frame would read mostly reflections: no hypothesis is valid then)."""
    if 2 * SUPPORT_RADIUS_PX / k > min(size) - 1:
        return np.zeros(len(xy), bool)
    return _inside_by(xy, EDGE_SUPPORT_PX / k, size)


def footprint_inside(xy: np.ndarray, k: float, size: tuple[int, int]) -> np.ndarray:
    """Hypotheses whose whole footprint (``SUPPORT_RADIUS_PX / k`` original pixels) lies in the frame."""
    return _inside_by(xy, SUPPORT_RADIUS_PX / k, size)


def _inside_by(xy: np.ndarray, r: float, size: tuple[int, int]) -> np.ndarray:
    """Points (N, 2) at least ``r`` pixels inside the ``size`` = (width, height) frame."""
    w, h = size
    return (xy[:, 0] >= r) & (xy[:, 0] <= w - 1 - r) & (xy[:, 1] >= r) & (xy[:, 1] <= h - 1 - r)


def crop_box(box: tuple[float, float, float, float], crop, k: float, size: tuple[int, int],
             max_crop_px: float = MAX_CROP_PX) -> tuple[float, float, float, float] | None:
    """The box (x0, y0, x1, y1, original pixels) a query naming ``crop`` is prepared over: ``crop``,
    clipped to the ``size`` = (width, height) frame, joined with the hypotheses' ``box``. None (the
    hypotheses' box alone) without a crop, or where the joined box at factor ``k`` would pass
    ``max_crop_px`` resampled pixels with its margins."""
    if crop is None or len(crop) == 0:
        return None
    w, h = size
    c = (min(max(float(crop[0]), 0.0), w - 1.0), min(max(float(crop[1]), 0.0), h - 1.0),
         min(max(float(crop[2]), 0.0), w - 1.0), min(max(float(crop[3]), 0.0), h - 1.0))
    out = (min(c[0], box[0]), min(c[1], box[1]), max(c[2], box[2]), max(c[3], box[3]))
    side_x = k * (out[2] - out[0]) + 2 * CROP_MARGIN_PX
    side_y = k * (out[3] - out[1]) + 2 * CROP_MARGIN_PX
    return out if side_x * side_y <= max_crop_px else None


def check_crop(crop) -> tuple[float, float, float, float] | None:
    """A query's crop box as a tuple (None when empty); ValueError unless it is four finite values
    with x0 <= x1 and y0 <= y1."""
    if crop is None or len(crop) == 0:
        return None
    c = tuple(float(v) for v in crop)
    if len(c) != 4 or not all(math.isfinite(v) for v in c) or c[0] > c[2] or c[1] > c[3]:
        raise ValueError(f"crop must be four finite values x0 <= x1, y0 <= y1, got {list(c)}")
    return c


def sample_template_pmatrix(image: np.ndarray, centre: tuple[float, float], k: float) -> np.ndarray:
    """The (12, 34 C) P-matrix at ``centre`` (original pixels) of ``image`` resampled by ``k``."""
    xy = np.array([[float(centre[0]), float(centre[1])]])
    region = ResampledRegion(image, k, (xy[0, 0], xy[0, 1], xy[0, 0], xy[0, 1]))
    c = region.to_crop(xy)
    return sample_pmatrices(region.prep, c[:, 0], c[:, 1], np.array([True]))[0]


class ResampledObservation:
    """A :class:`common.tracking.observation.FrameObservation` matching on the frame resampled by
    ``k`` (hypotheses in original pixels). ``k == 1`` gives the same scores as
    :class:`common.detector.observation.DetectorObservation` up to the crop's margin rule.

    The prepared crop is kept and reused by later queries of the same frame that it covers (the
    filter's query, then the template update at the estimate)."""

    def __init__(self, key: object, time: float, image: np.ndarray, matcher: PolarMatcher, k: float,
                 homography: np.ndarray | None = None, max_crop_px: float = MAX_CROP_PX,
                 whole_footprint: bool = False, crop: tuple[float, float, float, float] | None = None,
                 regions: dict | None = None):
        """``whole_footprint``: score only hypotheses whose whole footprint lies in the frame
        (:func:`footprint_inside`) instead of those whose target does (:func:`footprint_valid`).

        ``crop`` (x0, y0, x1, y1, original pixels): prepare the crop over this box together with the
        hypotheses' box (:func:`crop_box`), taking it from ``regions`` (a dict shared by the
        queries of one frame) when a query before prepared the same box: the preparation is a
        function of the frame, ``k`` and the box alone, so sharing it changes no number."""
        self.key = key
        self.whole_footprint = bool(whole_footprint)
        self.time = float(time)
        self.image = image
        self.matcher = matcher
        self.k = float(k)
        self.homography = homography
        self.image_size = (int(image.shape[1]), int(image.shape[0]))
        self.max_crop_px = float(max_crop_px)
        self.queries = 0
        self.preparations = 0
        self.dropped = 0
        """Hypotheses declared out of support to keep the crop within ``max_crop_px``."""
        self._region: ResampledRegion | None = None
        self.crop = crop
        self.regions = regions

    def region_for(self, xy: np.ndarray) -> ResampledRegion:
        """A prepared crop covering the hypotheses ``xy`` (N, 2), reused when it already does."""
        if self._region is not None and self._region.covers(xy):
            return self._region
        box = (float(xy[:, 0].min()), float(xy[:, 1].min()), float(xy[:, 0].max()), float(xy[:, 1].max()))
        shared = crop_box(box, self.crop, self.k, self.image_size, self.max_crop_px)
        if shared is not None:
            key = (self.k, shared)
            region = None if self.regions is None else self.regions.get(key)
            if region is None:
                region = ResampledRegion(self.image, self.k, shared)
                self.preparations += 1
                if self.regions is not None:
                    self.regions[key] = region
            self._region = region
            return region
        if self._region is not None:
            # grow rather than replace: later queries of this frame usually fall in the old area
            x0, y0 = (self._region.offset[0] + CROP_MARGIN_PX) / self.k, (self._region.offset[1] + CROP_MARGIN_PX) / self.k
            x1 = (self._region.offset[0] + self._region.prep.width - CROP_MARGIN_PX) / self.k
            y1 = (self._region.offset[1] + self._region.prep.height - CROP_MARGIN_PX) / self.k
            box = (min(box[0], x0), min(box[1], y0), max(box[2], x1), max(box[3], y1))
        self._region = ResampledRegion(self.image, self.k, box)
        self.preparations += 1
        return self._region

    def _valid(self, xy: np.ndarray) -> np.ndarray:
        """In support, and within the largest square window about the hypotheses' median whose
        resampled crop stays within ``max_crop_px`` pixels (a cloud spread over the whole frame at
        a high factor would otherwise cost seconds): the rest count as out of support."""
        valid = footprint_valid(xy, self.k, self.image_size)
        if self.whole_footprint:
            valid &= footprint_inside(xy, self.k, self.image_size)
        if valid.sum() < 2:
            return valid
        side = math.sqrt(self.max_crop_px) - 2 * CROP_MARGIN_PX
        half = max(side, 0.0) / (2.0 * self.k)  # original pixels
        pts = xy[valid]
        if (np.ptp(pts[:, 0]) + 1) * (np.ptp(pts[:, 1]) + 1) * self.k ** 2 <= side ** 2:
            return valid
        med = np.median(pts, axis=0)
        near = np.all(np.abs(xy - med) <= half, axis=1)
        self.dropped += int(np.sum(valid & ~near))
        return valid & near

    def score_at(self, hyps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        hyps = check_hypotheses(hyps, 3)
        self.queries += 1
        valid = self._valid(hyps[:, :2])
        scores = np.zeros(len(hyps))
        if not valid.any():
            return scores, valid
        region = self.region_for(hyps[valid, :2])
        c = region.to_crop(hyps[valid, :2])
        s, ok = self.matcher.score_at(region.prep, np.column_stack([c, hyps[valid, 2]]))
        scores[valid] = s
        out_valid = valid.copy()
        out_valid[valid] = ok
        return scores, out_valid

    def score_grid(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xy = check_hypotheses(xy, 2)
        self.queries += 1
        valid = self._valid(xy)
        scores = np.zeros((len(xy), N_ANGLES))
        if not valid.any():
            return scores, valid
        region = self.region_for(xy[valid])
        s, ok = self.matcher.score_grid(region.prep, region.to_crop(xy[valid]))
        scores[valid] = s
        out_valid = valid.copy()
        out_valid[valid] = ok
        return scores, out_valid

    def refine_peak(self, x: float, y: float) -> tuple[float, float]:
        """Best angle (degrees) and its score at one point (original pixels); (0, 0) out of support."""
        xy = np.array([[float(x), float(y)]])
        if not self._valid(xy)[0]:
            return 0.0, 0.0
        region = self.region_for(xy)
        c = region.to_crop(xy)[0]
        theta, score, _ = self.matcher.refine_peak(region.prep, float(c[0]), float(c[1]))
        return theta, score

    def pmatrix_at(self, x: float, y: float) -> np.ndarray | None:
        """The P-matrix (12, 34 C) at one point (original pixels), None unless its whole footprint
        lies in the frame: a sample (the template adaptation's) must not take in the reflection
        beyond the frame's edge that a score may read."""
        xy = np.array([[float(x), float(y)]])
        if not (self._valid(xy)[0] and footprint_inside(xy, self.k, self.image_size)[0]):
            return None
        region = self.region_for(xy)
        c = region.to_crop(xy)
        return sample_pmatrices(region.prep, c[:, 0], c[:, 1], np.array([True]))[0]
