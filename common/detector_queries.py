"""The Tracker's detector client over query/reply messages (the bus, or a recording of it).

:class:`QueryDetector` implements :class:`common.detector.client.DetectorClient` by turning each
operation into a :class:`ScoreQuery` handed to ``ask`` (the tracker service sends it to the
detector service; offline replay looks up the recorded reply) and each :class:`ScoreReply` back
into numbers:

- ``build_template`` -> TEMPLATE at the factor (the reply carries the template and its version);
- the frame observation's ``score_at`` / ``score_grid`` -> AT / GRID at the factor;
  ``refine_peak`` (and the ``pmatrix_at`` that follows it at the same point) -> one PEAK;
- ``scale_grid`` -> GRID with ``one_off`` (a fresh resampled crop, as the in-process search);
- ``use_template`` -> the next version, handed to ``publish`` (the tracker service puts it on the
  ``template`` key, where the detector installs it); every query carries the version it needs.

A missing or failed reply raises :class:`ObservationUnavailable`: no observation (the filter
predicts only), no scale correction, no template update.
"""

from __future__ import annotations

import itertools
from typing import Callable

import numpy as np

from common.detector.layout import N_ANGLES, N_ROWS
from common.detector.matcher import check_hypotheses
from common.detector.template import Template
from common.msgs import ScoreQuery, ScoreReply, unpack
from common.msgs.convert import msg_to_template, pmatrix_from_bytes, score_query
from common.msgs.convert import reply_scores as codec_reply_scores
from common.tracking.observation import ObservationUnavailable

Ask = Callable[[ScoreQuery], "ScoreReply | None"]


def _unpack(data: bytes, dtype, shape: tuple[int, ...]) -> np.ndarray:
    try:
        return unpack(data, dtype, shape)
    except ValueError as exc:
        raise ObservationUnavailable(f"detector: malformed reply: {exc}") from None


def reply_scores(rep: ScoreReply, n: int, angles: int | None) -> tuple[np.ndarray, np.ndarray]:
    """Scores (n,) for ``angles`` None (AT) or (n, angles), and valid (n,), from a reply."""
    try:
        return codec_reply_scores(rep, n, angles)
    except ValueError as exc:
        raise ObservationUnavailable(f"detector: malformed reply: {exc}") from None


class QueryDetector:
    """A detector client whose every operation is one query answered by ``ask``."""

    def __init__(self, ask: Ask, client: str, publish: Callable[[Template, int], None] | None = None):
        self.ask = ask
        self.client = client
        self.publish = publish
        self.version = 0
        """Template version the queries carry."""
        self._ids = itertools.count(1)

    def query(self, frame, kind: int, hyps: np.ndarray, k: float, one_off: bool = False) -> ScoreReply:
        """The OK reply to one query about ``frame``; ObservationUnavailable otherwise."""
        q = score_query(next(self._ids), self.client, frame.index, kind, hyps, template_version=self.version,
                        factor=float(k), one_off=one_off)
        rep = self.ask(q)
        if rep is None:
            raise ObservationUnavailable(f"no reply for frame {frame.index}")
        if rep.status != ScoreReply.OK:
            raise ObservationUnavailable(f"detector: {ScoreReply.Status.Name(rep.status)}: {rep.error}")
        return rep

    def build_template(self, frame, centre, box, k: float) -> Template:
        row = np.array([[float(centre[0]), float(centre[1]), *(float(v) for v in box)]])
        rep = self.query(frame, ScoreQuery.TEMPLATE, row, k)
        try:
            template = msg_to_template(rep.template)
        except ValueError as exc:
            raise ObservationUnavailable(f"detector: bad template: {exc}") from None
        self.version = int(rep.template.version)
        return template

    def use_template(self, template: Template) -> None:
        self.version += 1
        if self.publish is not None:
            self.publish(template, self.version)

    def observation(self, frame, homography, k: float) -> "QueryObservation":
        return QueryObservation(self, frame, homography, k)

    def scale_grid(self, frame, k: float, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xy = check_hypotheses(xy, 2)
        rep = self.query(frame, ScoreQuery.GRID, xy, k, one_off=True)
        return reply_scores(rep, len(xy), N_ANGLES)


class QueryObservation:
    """One frame's :class:`common.tracking.observation.FrameObservation` at factor ``k``, with the
    template adaptation's ``refine_peak`` and ``pmatrix_at``."""

    def __init__(self, detector: QueryDetector, frame, homography, k: float):
        self.detector = detector
        self.frame = frame
        self.time = frame.time
        self.homography = homography
        self.image_size = tuple(frame.size)
        self.k = float(k)
        self._peak: tuple[tuple[float, float], float, float, np.ndarray | None] | None = None

    def score_at(self, hyps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        hyps = check_hypotheses(hyps, 3)
        return reply_scores(self.detector.query(self.frame, ScoreQuery.AT, hyps, self.k), len(hyps), None)

    def score_grid(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xy = check_hypotheses(xy, 2)
        rep = self.detector.query(self.frame, ScoreQuery.GRID, xy, self.k)
        return reply_scores(rep, len(xy), rep.angles)

    def _peak_at(self, x: float, y: float):
        point = (float(x), float(y))
        if self._peak is None or self._peak[0] != point:
            rep = self.detector.query(self.frame, ScoreQuery.PEAK, np.array([point]), self.k)
            theta, score = _unpack(rep.scores, np.float64, (2,))
            pm = None
            if rep.pmatrix:
                try:
                    pm = pmatrix_from_bytes(rep.pmatrix, N_ROWS, rep.pmatrix_columns)
                except ValueError as exc:
                    raise ObservationUnavailable(f"detector: malformed reply: {exc}") from None
            self._peak = (point, float(theta), float(score), pm)
        return self._peak

    def refine_peak(self, x: float, y: float) -> tuple[float, float]:
        """Best angle (degrees) and its score at one point; (0, 0) out of support."""
        _, theta, score, _ = self._peak_at(x, y)
        return theta, score

    def pmatrix_at(self, x: float, y: float) -> np.ndarray | None:
        """The P-matrix at one point (from the same PEAK reply as ``refine_peak`` there)."""
        return self._peak_at(x, y)[3]
