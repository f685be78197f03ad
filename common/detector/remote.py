"""The detector's clients over query/reply messages: every question a tracker asks is one
``ScoreQuery`` handed to ``ask`` (the tracker service sends it to the detector service; offline
replay looks up the recorded reply; tests ask :class:`common.detector.server.DetectorCore`
directly), and each ``ScoreReply`` comes back as numbers. The answering side is
:mod:`common.detector.server`, the in-process client :mod:`common.detector.client`.

:class:`QueryDetector` implements :class:`common.detector.client.DetectorClient` for the
single-target tracker:

- ``build_template`` -> TEMPLATE at the factor (the reply carries the template and its version);
- the frame observation's ``score_at`` / ``score_grid`` -> AT / GRID at the factor;
  ``refine_peak`` (and the ``pmatrix_at`` that follows it at the same point) -> one PEAK;
- ``scale_grid`` -> GRID with ``one_off`` (a resampled crop of its own, as the in-process search, over
  the ``crop`` box it names if any);
- ``use_template`` -> the next version, handed to ``publish`` (the tracker service puts it on the
  ``template`` key, where the detector installs it); every query carries the version it needs.

A missing or failed reply raises :class:`ObservationUnavailable`: no observation (the filter
predicts only), no scale correction, no template update.

:class:`QueryPartEvidence` is the multi-target filters' :class:`~common.multitarget.appearance.PartEvidence`.
The filters ask a frame two batched questions: the colour histograms of Q boxes (HISTOGRAMS:
``hypotheses`` = the boxes, float64 Q x 4), and the Bhattacharyya similarity of Q boxes to
reference histograms (SIMILARITY: the boxes, the references as float64 R x B, lossless for the
filters' float32 histograms, and ``ref_index``, int64 Q), both with the :class:`HistogramConfig`
as JSON. The detector answers with the very :class:`~common.multitarget.appearance.HistogramEvidence`
methods an in-process run calls on the same pixels; the reply carries the result's dtype and its
bytes, so the client returns the same array, bit for bit. A missing or failed reply raises
:class:`EvidenceUnavailable`.
"""



from __future__ import annotations

import itertools
from typing import Callable

import numpy as np

from common.detector.layout import N_ANGLES, N_ROWS
from common.detector.matcher import check_hypotheses
from common.detector.template import Template
from common.msgs import ScoreQuery, ScoreReply, pack, unpack
from common.msgs.convert import REPLY_DTYPES, msg_to_template, pmatrix_from_bytes, score_query
from common.msgs.convert import reply_scores as codec_reply_scores
from common.multitarget.appearance import HistogramConfig
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

    def query(self, frame, kind: int, hyps: np.ndarray, k: float, one_off: bool = False,
              crop: tuple[float, float, float, float] | None = None) -> ScoreReply:
        """The OK reply to one query about ``frame``; ObservationUnavailable otherwise."""
        q = score_query(next(self._ids), self.client, frame.index, kind, hyps, template_version=self.version,
                        factor=float(k), one_off=one_off, crop=[] if crop is None else [float(v) for v in crop])
        rep = self.ask(q)
        if rep is None:
            raise ObservationUnavailable(f"no reply for frame {frame.index}")
        if rep.status != ScoreReply.OK:
            raise ObservationUnavailable(f"detector: {ScoreReply.Status.Name(rep.status)}: {rep.error}")
        return rep

    def build_template(self, frame, centre, box, k: float) -> Template:
        row = np.array([[float(centre[0]), float(centre[1]), *(float(v) for v in box)]])
        try:
            rep = self.query(frame, ScoreQuery.TEMPLATE, row, k)
        except ObservationUnavailable:
            # the detector may have built and installed it as the next version all the same (a reply
            # lost or late): that number is skipped, so that the next template published does not
            # reuse it and get dropped as one the detector already holds
            self.version += 1
            raise
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

    def scale_grid(self, frame, k: float, xy: np.ndarray,
                   crop: tuple[float, float, float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
        xy = check_hypotheses(xy, 2)
        rep = self.query(frame, ScoreQuery.GRID, xy, k, one_off=True, crop=crop)
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


class EvidenceUnavailable(ObservationUnavailable):
    """No (usable) reply to a part-evidence query."""


class QueryPartEvidence:
    """:class:`PartEvidence` of one frame, every question one query answered by ``ask``."""

    def __init__(self, ask: Ask, client: str, frame_index: int, image_size: tuple[int, int],
                 cfg: HistogramConfig | None = None, ids=None):
        self.ask = ask
        self.client = client
        self.frame_index = int(frame_index)
        self.image_size = (int(image_size[0]), int(image_size[1]))
        self.cfg = cfg if cfg is not None else HistogramConfig()
        self._json = self.cfg.model_dump_json()
        self._ids = ids if ids is not None else itertools.count(1)

    def _query(self, kind: int, boxes: np.ndarray, **fields) -> np.ndarray:
        b = np.asarray(boxes, np.float64).reshape(-1, 4)
        q = score_query(next(self._ids), self.client, self.frame_index, kind, b, histogram_json=self._json, **fields)
        rep = self.ask(q)
        if rep is None:
            raise EvidenceUnavailable(f"no reply for frame {self.frame_index}")
        if rep.status != ScoreReply.OK:
            raise EvidenceUnavailable(f"detector: {ScoreReply.Status.Name(rep.status)}: {rep.error}")
        dtype = REPLY_DTYPES.get(rep.dtype)
        shape = (len(b), rep.bins) if kind == ScoreQuery.HISTOGRAMS else (len(b),)
        try:
            if dtype is None or rep.count != len(b):
                raise ValueError(f"dtype {rep.dtype!r}, count {rep.count} for {len(b)} boxes")
            return unpack(rep.scores, dtype, shape)
        except ValueError as exc:
            raise EvidenceUnavailable(f"detector: malformed reply: {exc}") from None

    def histograms(self, boxes: np.ndarray) -> np.ndarray:
        return self._query(ScoreQuery.HISTOGRAMS, boxes)

    def similarity(self, boxes: np.ndarray, references: np.ndarray, ref_index: np.ndarray) -> np.ndarray:
        refs = np.asarray(references, np.float64)
        idx = np.asarray(ref_index).astype(np.int64, copy=False).ravel()
        return self._query(ScoreQuery.SIMILARITY, boxes, reference_count=refs.shape[0], bins=refs.shape[1],
                           references=pack(refs), ref_index=pack(idx, np.int64))
