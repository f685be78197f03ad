"""The multi-target filters' :class:`~common.multitarget.appearance.PartEvidence` over query/reply messages.

The filters ask a frame two batched questions (:mod:`common.multitarget.appearance`): the colour
histograms of Q boxes, and the Bhattacharyya similarity of Q boxes to reference histograms. Here
they travel as :class:`ScoreQuery` messages answered by the detector service (or, on offline
replay, by the recorded replies):

- ``histograms(boxes)`` -> HISTOGRAMS: ``hypotheses`` = the boxes (float64 Q x 4);
- ``similarity(boxes, references, ref_index)`` -> SIMILARITY: the boxes, the references (float64
  R x B, lossless for the filters' float32 histograms) and ``ref_index`` (int64 Q);

both with the :class:`HistogramConfig` as JSON. The detector answers them with
:func:`answer_part_query`, which calls the very :class:`HistogramEvidence` methods an in-process
run calls on the same pixels; the reply carries the result's dtype and its bytes, so the client
returns the same array, bit for bit. A missing or failed reply raises
:class:`EvidenceUnavailable`.
"""

from __future__ import annotations

import itertools
from collections import OrderedDict
from typing import Callable

import numpy as np

from common.msgs import ScoreQuery, ScoreReply, pack, unpack
from common.msgs.convert import score_query
from common.multitarget.appearance import HistogramConfig, HistogramEvidence
from common.tracking.observation import ObservationUnavailable

Ask = Callable[[ScoreQuery], "ScoreReply | None"]
PART_KINDS = (ScoreQuery.HISTOGRAMS, ScoreQuery.SIMILARITY)
DTYPES = {"float32": np.float32, "float64": np.float64}
MAX_BOXES = 5_000_000
"""Boxes one query may ask about (a malformed query could otherwise ask for gigabytes)."""


class EvidenceUnavailable(ObservationUnavailable):
    """No (usable) reply to a part-evidence query."""


def _boxes(data: bytes, count: int) -> np.ndarray:
    if count > MAX_BOXES:
        raise ValueError(f"{count} boxes in one query (at most {MAX_BOXES})")
    b = unpack(data, np.float64, (count, 4))
    if not np.all(np.isfinite(b)):
        raise ValueError("boxes contain NaN or infinite coordinates")
    return b


def histogram_config(text: str) -> HistogramConfig:
    """The query's HistogramConfig (empty: the default); ValueError if malformed."""
    if not text:
        return HistogramConfig()
    try:
        return HistogramConfig.model_validate_json(text)
    except Exception as exc:  # noqa: BLE001 - pydantic's ValidationError and JSON errors
        raise ValueError(f"bad histogram_json: {exc}") from None


class EvidenceCache:
    """One :class:`HistogramEvidence` (integral histogram) per (frame, histogram config), the last few."""

    def __init__(self, max_items: int = 8):
        self.items: OrderedDict[tuple[int, str], HistogramEvidence] = OrderedDict()
        self.max_items = max_items

    def get(self, frame_index: int, image: np.ndarray, cfg: HistogramConfig) -> HistogramEvidence:
        key = (int(frame_index), cfg.model_dump_json())
        ev = self.items.get(key)
        if ev is None:
            ev = self.items[key] = HistogramEvidence(image, cfg)
            while len(self.items) > self.max_items:
                self.items.popitem(last=False)
        return ev


def answer_part_query(q: ScoreQuery, image: np.ndarray, cache: EvidenceCache, rep: ScoreReply) -> None:
    """Fill ``rep`` with the answer to a HISTOGRAMS or SIMILARITY query about ``image``; ValueError
    for a malformed query (the caller turns it into BAD_REQUEST)."""
    if q.kind not in PART_KINDS:
        raise ValueError(f"not a part-evidence query: kind {q.kind}")
    cfg = histogram_config(q.histogram_json)
    boxes = _boxes(q.hypotheses, q.count)
    ev = cache.get(q.frame_index, image, cfg)
    if q.kind == ScoreQuery.HISTOGRAMS:
        out = ev.histograms(boxes)
        rep.bins = out.shape[1] if out.ndim == 2 else 0
    else:
        r, b = int(q.reference_count), int(q.bins)
        if r == 0 or b != cfg.n_bins:
            raise ValueError(f"SIMILARITY needs reference histograms of {cfg.n_bins} bins, got {r} x {b}")
        refs = unpack(q.references, np.float64, (r, b))
        if not np.all(np.isfinite(refs)):
            raise ValueError("reference histograms contain NaN or infinite values")
        idx = unpack(q.ref_index, np.int64, (q.count,))
        if idx.size and (idx.min() < 0 or idx.max() >= r):
            raise ValueError(f"ref_index outside [0, {r})")
        out = ev.similarity(boxes, refs, idx)
    name = np.dtype(out.dtype).name
    if name not in DTYPES:
        raise RuntimeError(f"evidence returned {name}, not float32/float64")
    rep.dtype = name
    rep.count = q.count
    rep.scores = pack(out, out.dtype)


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
        dtype = DTYPES.get(rep.dtype)
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
