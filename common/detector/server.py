"""The detector without the bus: frames and templates in, queries in, replies out.

:class:`DetectorCore` answers the ``detector/score`` queries (AT, GRID, TEMPLATE, PEAK, and the
multi-target filters' HISTOGRAMS and SIMILARITY, :func:`answer_part_query`) with the
same functions an in-process run calls (:mod:`common.detector.client`), on the same kept
per-frame observation (regions prepared once per client and frame), so the numbers are
bit-identical. The detector service (``services/detector.py``) is the bus shell around it;
tests and offline tools drive it directly.
"""

from __future__ import annotations

import logging
import math
import time
from collections import OrderedDict

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from common.detector import FrameCache, PolarMatcher, Template
from common.detector.client import OneOffRegions, frame_observation, make_template, one_off_grid
from common.detector.layout import N_ANGLES
from common.detector.observation import DetectorObservation
from common.detector.resample import check_crop
from common.msgs import ScoreQuery, ScoreReply, pack, unpack
from common.msgs import Template as TemplateMsg
from common.msgs.convert import PART_KINDS, REPLY_DTYPES, query_hypotheses, template_to_msg
from common.multitarget.appearance import HistogramConfig, HistogramEvidence
from common.validation import MAX_CLIENT_CHARS, Counters, Invalid, Rejects, check_query

log = logging.getLogger("polartrack.detector")


# -- the multi-target filters' part evidence (HISTOGRAMS, SIMILARITY) ----------------------

MAX_BOXES = 5_000_000
"""Boxes one query may ask about (a malformed query could otherwise ask for gigabytes)."""


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
    if name not in REPLY_DTYPES:
        raise RuntimeError(f"evidence returned {name}, not float32/float64")
    rep.dtype = name
    rep.count = q.count
    rep.scores = pack(out, out.dtype)



# -- the detector ----------------------------------------------------------------------------

class DetectorSettings(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", use_attribute_docstrings=True)

    max_frames: int = Field(24, ge=1)
    """Frames held (oldest dropped): bounds memory. Ten more than the tracker's max_lag_frames: frames
    reach the detector before the tracker learns of them"""
    wait_frame_s: float = Field(1.0, ge=0)
    """How long a query waits for its frame's image, or for the adapted template it names, to arrive
    (meanwhile the detector answers the other queries)"""
    max_clients: int = Field(8, ge=1, le=1024)
    """Queriers whose prepared regions are kept (least recently used dropped): each holds up to a
    frame's pyramid (~10 MB at 1280x720)"""
    max_pending: int = Field(64, ge=1, le=10_000)
    """Queries waiting for their frame or template at most (beyond: answered UNKNOWN_FRAME at once)"""


MIN_FACTOR, MAX_FACTOR = 1.0 / 64.0, 64.0
"""Resampling factors a query may ask for (beyond them a malformed query could ask for a huge crop)."""

def query_factor(q: ScoreQuery) -> float:
    """The query's resampling factor (0, unset: 1); ValueError outside [MIN_FACTOR, MAX_FACTOR]."""
    k = 1.0 if q.factor == 0 else float(q.factor)
    if not (math.isfinite(k) and MIN_FACTOR <= k <= MAX_FACTOR):
        raise ValueError(f"resampling factor {q.factor} is outside [{MIN_FACTOR:g}, {MAX_FACTOR:g}]")
    return k


OBSERVATIONS_KEPT = 4
"""Prepared observations kept (per client, frame, factor and template): the scale search and the
template adaptation ask about the frame the filter's query just prepared, so a few are enough,
and each can hold a full frame's pyramid (about 11 MB at 1280x720), fewer than the frames held."""


class DetectorCore:
    """The detector without the bus: frames in, queries in, replies out."""

    def __init__(self, settings: DetectorSettings | None = None):
        self.settings = settings or DetectorSettings()
        self.frames: OrderedDict[int, tuple[np.ndarray, float]] = OrderedDict()
        self.templates: OrderedDict[int, PolarMatcher] = OrderedDict()
        self.caches: OrderedDict[str, FrameCache] = OrderedDict()
        """Per querier (its sender id and client name), least recently used first, at most ``max_clients``."""
        self.rejects = Rejects()
        """Malformed queries per reason (also counted in ``malformed``)."""
        self.observations: OrderedDict[tuple, object] = OrderedDict()
        """(client, frame, factor, template version) -> the frame's observation, kept so the
        template adaptation's PEAK reuses the region the filter's query prepared (as in-process)."""
        self.one_off = OneOffRegions(self.settings.max_clients)
        """Per querier, the crops its one-off queries of its latest frame named by box."""
        self.counters = Counters("detector")
        self.evidence = EvidenceCache(min(4, self.settings.max_frames))
        """The latest frames' integral histograms (multi-target part evidence; tens of MB each, so
        fewer than the frames held: an older frame's is computed again if asked for)."""

    def add_frame(self, index: int, image: np.ndarray, time_s: float) -> None:
        self.frames[index] = (image, time_s)
        while len(self.frames) > self.settings.max_frames:
            self.frames.popitem(last=False)

    def install_template(self, version: int, template: Template) -> None:
        self.templates[version] = PolarMatcher(template)
        while len(self.templates) > 4:
            self.templates.popitem(last=False)

    def _bad(self, reason: str) -> None:
        self.counters.add("malformed")
        self.rejects.add("detector/score", reason)

    def cache_for(self, client: str) -> FrameCache:
        """The querier's region cache (least recently used ones dropped beyond ``max_clients``,
        with their kept observations)."""
        cache = self.caches.get(client)
        if cache is None:
            cache = self.caches[client] = FrameCache()
            while len(self.caches) > self.settings.max_clients:
                gone, _ = self.caches.popitem(last=False)
                for key in [key for key in self.observations if key[0] == gone]:
                    del self.observations[key]
        self.caches.move_to_end(client)
        return cache

    def observation(self, q: ScoreQuery, k: float, matcher: PolarMatcher, image: np.ndarray, time_s: float,
                    querier: str = ""):
        """The frame's observation for the query's client, factor and template (kept for later queries)."""
        client = f"{querier}/{q.client}"
        key = (client, q.frame_index, k, q.template_version)
        obs = self.observations.get(key)
        if obs is None:
            cache = self.cache_for(client)
            obs = self.observations[key] = frame_observation(q.frame_index, time_s, image, matcher, cache, k)
            while len(self.observations) > min(OBSERVATIONS_KEPT, self.settings.max_frames):
                self.observations.popitem(last=False)
        return obs

    @staticmethod
    def parse(q: ScoreQuery) -> tuple[np.ndarray, float]:
        """(hypotheses, factor) of an AT / GRID / TEMPLATE / PEAK query; ValueError when malformed."""
        hyps = query_hypotheses(q)
        if not np.all(np.isfinite(hyps)):
            raise ValueError("hypotheses contain NaN or infinite coordinates")
        k = query_factor(q)
        if q.kind in (ScoreQuery.TEMPLATE, ScoreQuery.PEAK) and q.count != 1:
            raise ValueError(f"a {ScoreQuery.Kind.Name(q.kind)} query has exactly one row")
        return hyps, k

    def precheck(self, q: ScoreQuery) -> ScoreReply | None:
        """The error reply to a query no frame can make answerable (caps, sizes, NaNs, kind,
        factor), counted; None when it may wait for its frame."""
        try:
            check_query(q, PART_KINDS)
            if q.kind not in PART_KINDS:
                self.parse(q)
            elif not np.all(np.isfinite(query_hypotheses(q))):
                raise ValueError("boxes contain NaN or infinite values")
        except ValueError as exc:
            self._bad(exc.reason if isinstance(exc, Invalid) else "bad_request")
            return ScoreReply(request_id=q.request_id, client=q.client[:MAX_CLIENT_CHARS], frame_index=q.frame_index,
                              status=ScoreReply.BAD_REQUEST, error=str(exc)[:300])
        return None

    def handle(self, q: ScoreQuery, querier: str = "") -> tuple[ScoreReply, TemplateMsg | None]:
        """Answer one query (from sender ``querier``: each querier's regions are its own). Never
        raises: problems become an error status."""
        rep = ScoreReply(request_id=q.request_id, client=q.client[:MAX_CLIENT_CHARS], frame_index=q.frame_index)
        try:
            check_query(q, PART_KINDS)
        except Invalid as exc:
            self._bad(exc.reason)
            rep.status, rep.error = ScoreReply.BAD_REQUEST, str(exc)
            return rep, None
        frame = self.frames.get(q.frame_index)
        if frame is None:
            if q.kind in PART_KINDS:
                self._bad("unknown_frame")
            rep.status, rep.error = ScoreReply.UNKNOWN_FRAME, f"frame {q.frame_index} is not held"
            return rep, None
        image, time_s = frame
        if q.kind in PART_KINDS:
            return self.handle_part(q, image, rep), None
        try:
            hyps, k = self.parse(q)
        except ValueError as exc:
            self._bad("bad_request")
            rep.status, rep.error = ScoreReply.BAD_REQUEST, str(exc)
            return rep, None
        t0 = time.perf_counter()
        try:
            if q.kind == ScoreQuery.TEMPLATE:
                cx, cy, bx, by, bw, bh = (float(v) for v in hyps[0])
                template = make_template(image, (cx, cy), (bx, by, bw, bh), k)
                version = (max(self.templates) if self.templates else 0) + 1
                self.install_template(version, template)
                tm = template_to_msg(template, version, q.frame_index)
                rep.template.CopyFrom(tm)
                rep.count, rep.angles = 0, 0
                return rep, tm
            matcher = self.templates.get(q.template_version)
            if matcher is None:
                rep.status, rep.error = ScoreReply.NO_TEMPLATE, f"no template version {q.template_version}"
                return rep, None
            if len(q.crop) and not q.one_off:
                raise ValueError("crop is for one_off GRID queries only")
            if q.one_off:
                if q.kind != ScoreQuery.GRID:
                    raise ValueError("one_off is for GRID queries only")
                crop = check_crop(q.crop)
                regions = None if crop is None else self.one_off.of(f"{querier}/{q.client}", q.frame_index)
                scores, valid = one_off_grid(time_s, image, matcher, k, hyps, crop, regions)
                rep.angles = N_ANGLES
            else:
                obs = self.observation(q, k, matcher, image, time_s, querier)
                if q.kind == ScoreQuery.AT:
                    scores, valid = obs.score_at(hyps)
                    rep.angles = 1
                elif q.kind == ScoreQuery.GRID:
                    scores, valid = obs.score_grid(hyps)
                    rep.angles = N_ANGLES
                else:  # PEAK: the refined angle and score, then the P-matrix, as Tracker._adapt asks them
                    x, y = float(hyps[0, 0]), float(hyps[0, 1])
                    theta, score = obs.refine_peak(x, y)
                    pm = obs.pmatrix_at(x, y)
                    scores, valid = np.array([theta, score], np.float64), np.array([pm is not None])
                    rep.angles = 2
                    if pm is not None:
                        rep.pmatrix = np.ascontiguousarray(pm, np.complex64).tobytes()
                        rep.pmatrix_columns = pm.shape[1]
        except ValueError as exc:
            self._bad("bad_request")
            rep.status, rep.error = ScoreReply.BAD_REQUEST, str(exc)
            return rep, None
        except Exception as exc:  # noqa: BLE001 - a service never stops on one bad query
            log.exception("query %s failed", q.request_id)
            self.counters.add("errors")
            rep.status, rep.error = ScoreReply.INTERNAL_ERROR, f"{type(exc).__name__}: {exc}"
            return rep, None
        rep.count = q.count
        rep.scores = pack(scores)
        rep.valid = pack(valid, np.uint8)
        rep.score_ms = 1e3 * (time.perf_counter() - t0)
        return rep, None


    def handle_part(self, q: ScoreQuery, image: np.ndarray, rep: ScoreReply) -> ScoreReply:
        """A HISTOGRAMS or SIMILARITY query (never raises: problems become an error status)."""
        t0 = time.perf_counter()
        try:
            answer_part_query(q, image, self.evidence, rep)
        except ValueError as exc:
            self._bad("bad_request")
            rep.status, rep.error = ScoreReply.BAD_REQUEST, str(exc)
            return rep
        except Exception as exc:  # noqa: BLE001 - a service never stops on one bad query
            log.exception("query %s failed", q.request_id)
            self.counters.add("errors")
            rep.status, rep.error = ScoreReply.INTERNAL_ERROR, f"{type(exc).__name__}: {exc}"
            return rep
        rep.score_ms = 1e3 * (time.perf_counter() - t0)
        return rep


def warm_up() -> None:
    """Compile the numba sampler and start the sampling threads before joining the bus (first
    compilation takes seconds)."""
    rng = np.random.default_rng(0)
    img = (rng.random((160, 160, 3)) * 255).astype(np.float32)
    matcher = PolarMatcher(Template.from_image(img, (80.0, 80.0)))
    obs = DetectorObservation(0, 0.0, img, matcher, FrameCache())
    obs.score_at(np.array([[80.0, 80.0, 0.0]]))
    obs.score_grid(np.array([[80.0, 80.0]]))
    # a batch large enough for the sampling threads (the pool starts here, not on the first frame)
    obs.score_at(np.c_[rng.uniform(70.0, 90.0, (256, 2)), np.zeros(256)])
