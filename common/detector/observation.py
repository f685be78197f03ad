"""The in-process detector as a :class:`common.tracking.observation.FrameObservation`.

One object per frame: it holds the frame, the matcher and the frame cache, and prepares only
the region the queried hypotheses need (once per frame, grown if a later query reaches
outside it). The services offer the same interface over Zenoh.
"""

from __future__ import annotations

import numpy as np

from common.detector.frame import FrameCache
from common.detector.layout import N_ANGLES, SUPPORT_RADIUS_PX
from common.detector.matcher import PolarMatcher, check_hypotheses
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

    def _prep(self, xy: np.ndarray):
        box = support_box(xy, *self.image_size)
        if box is None:
            return None
        return self.cache.get(self.key, self.image, box)

    def score_at(self, hyps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        hyps = check_hypotheses(hyps, 3)
        self.queries += 1
        prep = self._prep(hyps[:, :2])
        if prep is None:
            return np.zeros(len(hyps)), np.zeros(len(hyps), bool)
        return self.matcher.score_at(prep, hyps)

    def score_grid(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xy = check_hypotheses(xy, 2)
        self.queries += 1
        prep = self._prep(xy)
        if prep is None:
            return np.zeros((len(xy), N_ANGLES)), np.zeros(len(xy), bool)
        return self.matcher.score_grid(prep, xy)

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
