"""The template re-registered on a segmentation of the target (settings:
:class:`common.settings.SegmentRegistration`).

Template adaptation (:mod:`common.single_target.adaptation`) takes each update where the template
itself matches best, so where it is registered a little off the target it stays off, and the
offset grows update after update; a track can then sit on the road behind the car it follows, its
box twice the car's size (uav123-car16, docs/real-footage.md). A measurement independent of the
template fixes the registration: GrabCut (Rother, Kolmogorov and Blake 2004, OpenCV's
``cv2.grabCut``) separates the target from its surroundings by colour, with the square a target
length either side of the estimate as "probably the target" and a margin about it as the
background. Its largest connected component, where it is shaped like a vehicle (area and
solidity, :func:`segment_target`), gives the target's centre and its length.

The segment's centre is taken as the target's centre, and its length, in the relation the first
box's own segment had to the box (``Registrar.start``: a loose first box, a segment less than one
box long), as the target's length. The first box's centre is not carried over as an offset from
its segment: on real footage that offset is a few pixels of shadow, of the side an oblique camera
sees and of the box's rounding, fixed in the image rather than turning with the target and not
growing with it, so carried in target lengths and turned by the track's angle it moves the
registration off the target (docs/real-footage.md, stop 36). Nothing here needs the ground truth.

A template that matches well is not moved (its segment can be bistable), yet it may hold a point
of the target away from its centre (a car's textured end). For the reported box, not for the
template, the target is segmented every interval whatever the score (``Registrar.centre``), and the
box takes the segment's centre and extent (its second moments; ``SegmentRegistration.centre_box``,
kept by :class:`common.single_target.runner.Tracker`).

GrabCut initialises its colour models with k-means, which draws from OpenCV's random generator;
it is seeded before every call from the run's seed and the frame's index, so the same frame gives
the same segment in-process, multi-process and on replay.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import cv2
import numpy as np

_SEED_TAG = 7
"""The segmentation's stream of the run's seed (``default_rng([seed, _SEED_TAG, frame_index])``)."""


@dataclass(frozen=True)
class Segment:
    """The target's segment in image pixels."""

    x: float
    y: float
    """Centre of the component (its pixels' mean)."""
    length_px: float
    """Long side of its minimum-area rectangle."""
    area_px: float
    solidity: float
    """Its area over its minimum-area rectangle's."""
    cov: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Its pixels' second central moments (xx, xy, yy), image pixels squared: a filled w x h
    rectangle along the axes has (w^2 / 12, 0, h^2 / 12)."""


def segment_target(image: np.ndarray, centre: tuple[float, float], length_px: float, cfg, seed: int,
                   box_area_px: float | None = None) -> Segment | None:
    """The target's segment about ``centre`` on ``image`` (RGB, uint8): GrabCut's largest foreground
    component in the square ``cfg.reach_lengths`` target lengths either side, the crop a further
    ``cfg.margin_lengths`` wide worked at ``cfg.work_px``; None where the square is not wholly inside
    the frame (a target cut by the frame's edge: its segment is a part of it), nothing is segmented,
    or (``box_area_px`` given) the component's area is outside ``cfg.area_range`` of it or its
    solidity under ``cfg.min_solidity``."""
    h, w = image.shape[:2]
    cx, cy = float(centre[0]), float(centre[1])
    if not (math.isfinite(cx) and math.isfinite(cy) and math.isfinite(length_px) and length_px > 0):
        return None
    inner = cfg.reach_lengths * length_px
    outer = inner + cfg.margin_lengths * length_px
    x0, y0 = int(max(0.0, math.floor(cx - outer))), int(max(0.0, math.floor(cy - outer)))
    x1, y1 = int(min(w, math.ceil(cx + outer))), int(min(h, math.ceil(cy + outer)))
    if cx - inner < 0 or cy - inner < 0 or cx + inner > w or cy + inner > h or x1 - x0 < 16 or y1 - y0 < 16:
        return None
    f = min(1.0, cfg.work_px / max(x1 - x0, y1 - y0))
    crop = image[y0:y1, x0:x1]
    small = cv2.resize(crop, (max(8, round((x1 - x0) * f)), max(8, round((y1 - y0) * f))),
                       interpolation=cv2.INTER_AREA) if f < 1.0 else np.ascontiguousarray(crop)
    sh, sw = small.shape[:2]
    rx0, ry0 = max(1, int((cx - inner - x0) * f)), max(1, int((cy - inner - y0) * f))
    rx1, ry1 = min(sw - 1, int(math.ceil((cx + inner - x0) * f))), min(sh - 1, int(math.ceil((cy + inner - y0) * f)))
    if rx1 - rx0 < 4 or ry1 - ry0 < 4:
        return None
    mask = np.zeros((sh, sw), np.uint8)
    cv2.setRNGSeed(int(seed))
    try:
        cv2.grabCut(small, mask, (rx0, ry0, rx1 - rx0, ry1 - ry0), np.zeros((1, 65)), np.zeros((1, 65)),
                    cfg.iterations, cv2.GC_INIT_WITH_RECT)
    except cv2.error:
        return None  # a degenerate colour model (one colour in the crop): nothing to separate
    fg = ((mask == cv2.GC_FGD) | (mask == cv2.GC_PR_FGD)).astype(np.uint8)
    n, labels, stats, centres = cv2.connectedComponentsWithStats(fg, connectivity=8)
    if n <= 1:
        return None
    i = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    pts = np.argwhere(labels == i)[:, ::-1].astype(np.float32)
    _, (rw, rh), _ = cv2.minAreaRect(pts)
    area = float(stats[i, cv2.CC_STAT_AREA])
    cov = (np.cov(pts, rowvar=False, bias=True) + np.eye(2) / 12) / (f * f)  # with each pixel's own extent
    seg = Segment(x=x0 + (float(centres[i, 0]) + 0.5) / f - 0.5, y=y0 + (float(centres[i, 1]) + 0.5) / f - 0.5,
                  length_px=(max(rw, rh) + 1.0) / f, area_px=area / (f * f),
                  solidity=area / ((rw + 1.0) * (rh + 1.0)),
                  cov=(float(cov[0, 0]), float(cov[0, 1]), float(cov[1, 1])))
    if box_area_px is not None:
        lo, hi = cfg.area_range
        if not lo * box_area_px <= seg.area_px <= hi * box_area_px or seg.solidity < cfg.min_solidity:
            return None
    return seg


class Registrar:
    """When to segment, and what a segment says: ``start`` on the first frame's box, then, on a
    frame where ``due``, ``measure`` (None where nothing plausible is found); for the box's centre,
    where ``centre_due``, ``centre``."""

    def __init__(self, cfg, seed: int, max_score: float = 1.0):
        self.cfg = cfg
        self.seed = int(seed)
        self.max_score = float(max_score)
        """Segment only while the estimate's score is below this (``cfg.score_quantile``)."""
        self.first_length_px: float | None = None
        """The first box's segment's length: the length of a segment at scale 1 (None: the target
        did not segment on the first frame, and is not re-registered)."""
        self._first_box_length_px = 1.0
        self._last_time = -math.inf
        self._last_centre_time = -math.inf
        self.attempts = 0
        self.registrations = 0
        self.centrings = 0
        """Segmentations for the box's centre (``cfg.centre_box``), found or not."""
        self.seconds = 0.0
        """Wall time spent segmenting (a statistic for the benchmarks)."""

    def _seed(self, frame_index: int) -> int:
        return int(np.random.default_rng([self.seed, _SEED_TAG, int(frame_index)]).integers(0, 2**31 - 1))

    def start(self, image: np.ndarray, frame_index: int, time_s: float, box: tuple[float, float, float, float]) -> None:
        """Calibrate on the first box: the segment's length relative to the box's long side (the first
        re-registration one interval later)."""
        x, y, w, h = (float(v) for v in box)
        seg = segment_target(image, (x + w / 2, y + h / 2), max(w, h), self.cfg, self._seed(frame_index), w * h)
        self.first_length_px = None if seg is None else seg.length_px
        self._first_box_length_px = max(w, h)
        self._last_time = self._last_centre_time = time_s

    @property
    def ratio(self) -> float | None:
        """The first box's segment's length over the box's long side (a loose first box: under one)."""
        return None if self.first_length_px is None else self.first_length_px / self._first_box_length_px

    def due(self, time_s: float, p_visible: float, score: float | None) -> bool:
        return (self.first_length_px is not None and p_visible >= self.cfg.min_p_visible
                and score is not None and score < self.max_score
                and time_s - self._last_time >= self.cfg.interval_s - 1e-9)

    def measure(self, image: np.ndarray, frame_index: int, time_s: float, centre: tuple[float, float],
                box_size: tuple[float, float], length_px: float) -> tuple[tuple[float, float], float] | None:
        """The target's centre and scale from its segment about ``centre`` (the track's box
        ``box_size``, its length ``length_px``): the segment's centre, and its length over the first
        segment's; None where no plausible segment is found. Counts as this interval's attempt
        either way."""
        self._last_time = time_s
        self.attempts += 1
        seg = self._segment(image, frame_index, centre, box_size, length_px)
        if seg is None:
            return None
        self.registrations += 1
        return (seg.x, seg.y), seg.length_px / self.first_length_px

    def centre_due(self, time_s: float, p_visible: float) -> bool:
        """Whether to segment for the box's centre (``cfg.centre_box``): once an interval while held,
        whatever the score."""
        return (self.cfg.centre_box and self.first_length_px is not None and p_visible >= self.cfg.min_p_visible
                and time_s - self._last_centre_time >= self.cfg.interval_s - 1e-9)

    def centre(self, image: np.ndarray, frame_index: int, time_s: float, centre: tuple[float, float],
               box_size: tuple[float, float], length_px: float) -> Segment | None:
        """The target's segment about ``centre`` (as :meth:`measure`, for the box rather than the
        template); None where no plausible segment is found."""
        self._last_centre_time = time_s
        self.centrings += 1
        return self._segment(image, frame_index, centre, box_size, length_px)

    def _segment(self, image: np.ndarray, frame_index: int, centre: tuple[float, float],
                 box_size: tuple[float, float], length_px: float) -> Segment | None:
        t0 = time.perf_counter()
        try:
            return segment_target(image, centre, length_px, self.cfg, self._seed(frame_index),
                                  box_size[0] * box_size[1])
        finally:
            self.seconds += time.perf_counter() - t0  # a statistic only: never read by the tracking

    def stats(self) -> dict:
        n = self.attempts + self.centrings
        return {"segmentations": self.attempts, "registrations": self.registrations, "centrings": self.centrings,
                "ms_per_segmentation": round(1e3 * self.seconds / n, 2) if n else 0.0}
