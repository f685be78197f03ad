"""The in-process detector as a :class:`common.tracking.observation.FrameObservation`.

One object per frame: it holds the frame, the matcher and the frame cache, and prepares only
the region the queried hypotheses need (once per frame, grown if a later query reaches
outside it). The services offer the same interface over Zenoh.

A hypothesis whose footprint passes the frame's edge while the target it stands for is in view
(``EDGE_SUPPORT_PX`` inside, :func:`common.detector.resample.footprint_valid`) is scored as the
resampled path scores it at any factor: on a crop of the frame reflected across the edge
(:class:`common.detector.resample.ResampledObservation` at ``k`` = 1, whose coefficients are the
full frame's). The full-frame preparation has no reflected margin on its top and left, so without
this a target within a footprint of the edge could not be scored at ``k`` = 1 while the same target
a few percent smaller or larger (resampled) could.
"""

from __future__ import annotations

import numpy as np

from common.detector.frame import FrameCache
from common.detector.layout import N_ANGLES, SUPPORT_RADIUS_PX
from common.detector.matcher import PolarMatcher, check_hypotheses
from common.detector.resample import ResampledObservation, footprint_inside, footprint_valid
from common.detector.sampler import sample_pmatrices


def support_box(xy: np.ndarray, width: int, height: int) -> tuple[float, float, float, float] | None:
    """Bounding box of the hypothesis centres that can be in support in a ``width`` x ``height``
    frame (None if none can): the area a region must cover for them."""
    r = SUPPORT_RADIUS_PX
    ok = (xy[:, 0] >= r) & (xy[:, 0] <= width - 1 - r) & (xy[:, 1] >= r) & (xy[:, 1] <= height - 1 - r)
    if not ok.any():
        return None
    pts = xy[ok]
    return (float(pts[:, 0].min()), float(pts[:, 1].min()), float(pts[:, 0].max()), float(pts[:, 1].max()))


class DetectorObservation:
    """Scores hypotheses on one frame with an in-process :class:`PolarMatcher`."""

    def __init__(self, key: object, time: float, image: np.ndarray, matcher: PolarMatcher,
                 cache: FrameCache, homography: np.ndarray | None = None):
        self.key = key
        self.time = float(time)
        self.image = image
        self.matcher = matcher
        self.cache = cache
        self.homography = homography
        self.image_size = (int(image.shape[1]), int(image.shape[0]))
        self.queries = 0
        self._edge: ResampledObservation | None = None

    def _prep(self, xy: np.ndarray):
        box = support_box(xy, *self.image_size)
        if box is None:
            return None
        return self.cache.get(self.key, self.image, box)

    def _at_edge(self, xy: np.ndarray) -> np.ndarray:
        """Hypotheses whose footprint passes the frame's edge with the target in view."""
        return footprint_valid(xy, 1.0, self.image_size) & ~footprint_inside(xy, 1.0, self.image_size)

    def _edge_observation(self) -> ResampledObservation:
        """The frame's observation on reflected crops, kept for the frame's later queries."""
        if self._edge is None:
            self._edge = ResampledObservation(self.key, self.time, self.image, self.matcher, 1.0, self.homography)
        return self._edge

    def _scored(self, hyps: np.ndarray, plain, edge, shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
        """``plain(prep, hyps)`` on the full-frame preparation for hypotheses whose footprint lies in
        the frame, ``edge(hyps)`` on a reflected crop for those at the edge."""
        scores, valid = np.zeros((len(hyps), *shape)), np.zeros(len(hyps), bool)
        at_edge = self._at_edge(hyps[:, :2])
        prep = self._prep(hyps[:, :2])
        inner = ~at_edge
        if prep is not None and inner.any():
            scores[inner], valid[inner] = plain(prep, hyps[inner])
        if at_edge.any():
            scores[at_edge], valid[at_edge] = edge(hyps[at_edge])
        return scores, valid

    def score_at(self, hyps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        hyps = check_hypotheses(hyps, 3)
        self.queries += 1
        return self._scored(hyps, self.matcher.score_at, lambda h: self._edge_observation().score_at(h), ())

    def score_grid(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xy = check_hypotheses(xy, 2)
        self.queries += 1
        return self._scored(xy, self.matcher.score_grid, lambda h: self._edge_observation().score_grid(h), (N_ANGLES,))

    def refine_peak(self, x: float, y: float) -> tuple[float, float]:
        """Best angle (degrees) and its score at one point; (0, 0) out of support."""
        prep = self._prep(np.array([[float(x), float(y)]]))
        if prep is None or not prep.in_support(np.array([x]), np.array([y]))[0]:
            return 0.0, 0.0
        theta, score, _ = self.matcher.refine_peak(prep, float(x), float(y))
        return theta, score

    def pmatrix_at(self, x: float, y: float) -> np.ndarray | None:
        """The P-matrix (12, 34 C) at one point, None out of support."""
        xs, ys = np.array([float(x)]), np.array([float(y)])
        prep = self._prep(np.column_stack([xs, ys]))
        if prep is None or not prep.in_support(xs, ys)[0]:
            return None
        return sample_pmatrices(prep, xs, ys, np.array([True]))[0]
