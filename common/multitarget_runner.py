"""Multi-target tracking the same way in-process, in the tracker service and on offline replay.

:class:`MultiRun` is what a multi-target run is (method, :class:`MultiTargetConfig`, first-frame
person boxes, seed); :class:`MultiTracker` is its filter, stepped with a
:class:`~common.multitarget.appearance.PartEvidence` per frame: :class:`HistogramEvidence`
in-process (``track_frames``), :class:`~common.part_evidence_queries.QueryPartEvidence` in the
tracker service (answered by the detector service) and on offline replay (answered by the
recorded replies). The filter only sees the evidence's answers, which are the same arrays
whichever way they come, so the estimates are bit-identical.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from typing import Iterable, Iterator

import numpy as np

from common.msgs import MultiEstimate, pack, unpack
from common.multitarget import (HistogramEvidence, MultiTargetConfig, MultiTrackState,
                                PartEvidence, body_model, make_filter, method_config)
from common.multitarget.placement import start_from_boxes

@dataclass(frozen=True)
class MultiRun:
    """A multi-target run: ``method`` (one of :data:`common.multitarget.METHODS`), its config, the first frame's
    person boxes (T, 4) x, y, w, h, and the seed of the filter's generators."""

    method: str
    config: MultiTargetConfig
    boxes: tuple[tuple[float, float, float, float], ...]
    seed: int = 0

    @classmethod
    def make(cls, method: str, boxes, seed: int = 0, n_parts: int = 10, particles: int | None = None) -> "MultiRun":
        cfg = method_config(method, n_parts=n_parts, **({"n_particles": particles} if particles else {}))
        return cls(method, cfg, tuple(tuple(float(v) for v in b) for b in np.asarray(boxes, float)), int(seed))

    def to_json(self) -> str:
        return json.dumps({"method": self.method, "config": self.config.model_dump(mode="json"),
                           "boxes": [list(b) for b in self.boxes], "seed": self.seed})

    @classmethod
    def from_json(cls, text: str) -> "MultiRun":
        d = json.loads(text)
        return cls(d["method"], MultiTargetConfig.model_validate(d["config"]),
                   tuple(tuple(float(v) for v in b) for b in d["boxes"]), int(d["seed"]))


class MultiTracker:
    """The run's filter, started on the first frame's evidence (its ``image_size`` bounds the boxes):
    ``step(time, evidence) -> MultiTrackState``. Each body is placed in its box and shifted to where its core stands out from the surroundings
    (:mod:`common.multitarget.placement`; ``placement_shifts``, px)."""

    def __init__(self, run: MultiRun, first_evidence: PartEvidence):
        self.run = run
        self.body = body_model(run.config.n_parts)
        init, self.placement_shifts = start_from_boxes(np.array(run.boxes, float), self.body, first_evidence,
                                                       run.config.placement)  # fmt: skip
        self.filter = make_filter(run.config, init, first_evidence, run.seed)

    def step(self, frame_time: float, evidence: PartEvidence) -> MultiTrackState:
        return self.filter.step(frame_time, evidence)

    def prediction_msg(self, frame_index: int, frame_time: float, capture_ns: int | None = None,
                       step_ms: float = 0.0) -> MultiEstimate:
        """``observed=False``: the estimate of the particles as a failed step left them (its evidence
        did not come: the filter predicted, and weighed nothing), so a run without a detector still
        reports every frame."""
        from common.tracking import resampling

        f = self.filter
        parts, vel = f.estimate()
        t_n = len(parts)
        state = MultiTrackState(time=float(frame_time), parts=parts, velocity=vel,
                                n_eff=np.array([resampling.ess(row) for row in f.weights()]),
                                moved=np.zeros(t_n, bool), gate_area=np.zeros((t_n, 0)),
                                n_measurements=np.zeros((t_n, 0), np.int64), acceptance={})
        msg = multi_estimate_msg(frame_index, state, self.run, capture_ns, step_ms)
        msg.observed = False
        return msg


def track_frames(frames: Iterable, run: MultiRun) -> Iterator[tuple[object, MultiTrackState]]:
    """In-process: each frame's :class:`HistogramEvidence`, the filter started on the first."""
    tracker = None
    for frame in frames:
        ev = HistogramEvidence(frame.image, run.config.histogram)
        if tracker is None:
            tracker = MultiTracker(run, ev)
        yield frame, tracker.step(frame.time, ev)


def multi_estimate_msg(frame_index: int, state: MultiTrackState, run: MultiRun, capture_ns: int | None = None,
                       step_ms: float = 0.0) -> MultiEstimate:
    """The message of one frame's estimates (no loss: float64 arrays as bytes)."""
    body = body_model(run.config.n_parts)
    t_n, p_n = state.parts.shape[:2]
    gate = np.asarray(state.gate_area, np.float64)
    return MultiEstimate(
        frame_index=frame_index, time_s=state.time, filter=run.method, targets=t_n, parts=p_n,
        part_names=list(body.names), positions=pack(state.parts), velocities=pack(state.velocity),
        n_eff=pack(state.n_eff), moved=pack(state.moved, np.uint8), units=gate.shape[1] if gate.ndim == 2 else 0,
        gate_area=pack(gate), n_measurements=pack(state.n_measurements, np.int64),
        acceptance={k: float(v) for k, v in state.acceptance.items()}, parents=pack(body.parent, np.int32),
        observed=True, step_ms=step_ms,
        latency_ms=0.0 if capture_ns is None else (time.time_ns() - capture_ns) / 1e6)  # fmt: skip


def msg_positions(m: MultiEstimate) -> np.ndarray:
    """(T, P, 2) part centres of a MultiEstimate; ValueError if malformed."""
    return unpack(m.positions, np.float64, (m.targets, m.parts, 2))


MULTI_IGNORED = ("step_ms", "latency_ms", "frames_skipped")
"""MultiEstimate fields not compared on replay (timings)."""


def same_multi_estimate(a: MultiEstimate, b: MultiEstimate) -> bool:
    """Bit-for-bit equality of everything but the timings (arrays compared as bytes)."""
    x, y = MultiEstimate(), MultiEstimate()
    x.CopyFrom(a)
    y.CopyFrom(b)
    for f in MULTI_IGNORED:
        x.ClearField(f)
        y.ClearField(f)
    return x == y


def compare_multi(recorded: list[MultiEstimate], new: list[MultiEstimate]) -> dict:
    from common.recording import compare_estimates

    return compare_estimates(recorded, new, same=same_multi_estimate)


def people_truth_parts(info, n_parts: int) -> np.ndarray | None:
    """(people, P, 2) true part centres of the body model from a FrameInfo's 10-point truth, or None."""
    if not info.truth_people:
        return None
    try:
        ten = unpack(info.truth_parts, np.float64, (info.truth_people, 10, 2))
    except ValueError:
        return None
    return body_model(n_parts).from_ten(ten)


def offline_retrack_multi(rec, run: MultiRun) -> dict:
    """Re-run a multi-target recording from its recorded part-evidence replies (no detector, no
    pixels) and compare every estimate with the recorded one. Every query the filter makes must
    equal the recorded one (everything but the request id, bit for bit)."""
    from common.msgs import ScoreQuery
    from common.part_evidence_queries import EvidenceUnavailable, QueryPartEvidence
    from common.recording import RecordingError

    recorded = rec.decoded("track/multi_estimate")
    done = {e.frame_index for e in recorded}
    infos = [i for i in rec.decoded("frame/info") if not i.end_of_stream and i.index in done]
    if not infos:
        raise RecordingError(f"{rec.path}: no multi-target estimates recorded")
    replies = {(r.client, r.request_id): r for r in rec.decoded("detector/reply")}
    per_frame: dict[int, list] = {}
    seen = set()
    for q in rec.decoded("detector/query"):
        key = (q.client, q.request_id)
        if q.kind in (ScoreQuery.HISTOGRAMS, ScoreQuery.SIMILARITY) and key not in seen:
            seen.add(key)
            per_frame.setdefault(q.frame_index, []).append((q, replies.get(key)))
    stats = {"unanswered": 0, "query_mismatch": 0}

    def stripped(q: ScoreQuery) -> bytes:
        c = ScoreQuery()
        c.CopyFrom(q)
        c.ClearField("request_id")
        c.ClearField("client")
        return c.SerializeToString(deterministic=True)

    def ask(q: ScoreQuery):
        queue = per_frame.get(q.frame_index)
        if not queue:
            stats["unanswered"] += 1
            return None
        r, rep = queue.pop(0)
        if stripped(r) != stripped(q):
            stats["query_mismatch"] += 1
        return rep

    tracker = None
    new = []
    for info in infos:
        ev = QueryPartEvidence(ask, "offline", info.index, (info.width, info.height), run.config.histogram)
        try:
            if tracker is None:
                tracker = MultiTracker(run, ev)
            new.append(multi_estimate_msg(info.index, tracker.step(info.time_s, ev), run))
        except EvidenceUnavailable:
            stats["unanswered"] += 1
            if tracker is not None:
                new.append(tracker.prediction_msg(info.index, info.time_s))
    out = compare_multi(recorded, new)
    out.update(stats)
    out["identical"] = out["identical"] and stats["query_mismatch"] == 0
    return out
