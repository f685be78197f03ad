"""Reading PolarTrack MCAP recordings, and re-running the tracker offline from recorded replies.

``offline_retrack`` rebuilds the filter from the recorded run configuration and steps it over
the recorded frame infos; every query the filter makes is checked against the recorded query
(same frame, same hypotheses, bit for bit) and answered with the recorded reply, so no detector
is needed. The new estimates are compared with the recorded ones.
"""

from __future__ import annotations

import json
from collections import defaultdict, deque
from dataclasses import dataclass, field

import numpy as np
from mcap.reader import make_reader

from common.msgs import Estimate, FrameInfo, ScoreQuery, ScoreReply, TOPICS, pack, unpack
from common.msgs.convert import estimate_msg


class RecordingError(ValueError):
    pass


@dataclass
class Recording:
    path: str
    metadata: dict[str, dict[str, str]]
    messages: dict[str, list[tuple[int, bytes]]] = field(default_factory=dict)
    """topic -> [(log_time, data)] in file order."""

    @property
    def run(self) -> dict:
        if "run" not in self.metadata:
            raise RecordingError(f"{self.path}: no run metadata (was it written by polartrack?)")
        return self.metadata["run"]

    def decoded(self, topic: str) -> list:
        cls = TOPICS[topic]
        return [cls.FromString(d) for _, d in self.messages.get(topic, [])]


def read_recording(path: str) -> Recording:
    try:
        with open(path, "rb") as fh:
            reader = make_reader(fh)
            meta = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
            msgs: dict[str, list] = defaultdict(list)
            for _schema, channel, message in reader.iter_messages(log_time_order=False):
                msgs[channel.topic].append((message.log_time, message.data))
    except FileNotFoundError:
        raise RecordingError(f"{path}: no such file") from None
    except Exception as exc:  # noqa: BLE001 - the mcap reader raises many types on bad files
        raise RecordingError(f"{path}: not a readable MCAP file ({type(exc).__name__}: {exc})") from None
    return Recording(path, meta, dict(msgs))


COMPARED = ("frame_index", "time_s", "observed", "filter", "x", "y", "theta_deg", "p_visible", "world_x", "world_y",
            "vx", "vy", "speed", "mmse_x", "mmse_y", "n_eff", "resampled")
"""Estimate fields that must be identical on replay (not timings or latencies)."""


def same_estimate(a: Estimate, b: Estimate) -> bool:
    return all(getattr(a, f) == getattr(b, f) for f in COMPARED)


def compare_estimates(recorded: list[Estimate], new: list[Estimate]) -> dict:
    by_frame = {e.frame_index: e for e in recorded}
    mismatched = [e.frame_index for e in new if e.frame_index not in by_frame or not same_estimate(by_frame[e.frame_index], e)]
    missing = sorted(set(by_frame) - {e.frame_index for e in new})
    return {"identical": not mismatched and not missing and len(new) > 0, "compared": len(new),
            "recorded": len(recorded), "mismatched": mismatched[:20], "missing": missing[:20]}


class RecordedObservation:
    """Answers the filter's queries from the recording, checking each is the recorded one."""

    def __init__(self, info: FrameInfo, queue: deque, stats: dict):
        self.info = info
        self.time = info.time_s
        self.homography = np.asarray(info.homography, float).reshape(3, 3) if len(info.homography) == 9 else None
        self.image_size = (int(info.width), int(info.height))
        self.queue = queue
        self.stats = stats

    def _answer(self, kind: int, hyps: np.ndarray) -> ScoreReply:
        from common.tracking.observation import ObservationUnavailable

        if not self.queue:
            self.stats["unanswered"] += 1
            raise ObservationUnavailable(f"no recorded query for frame {self.info.index}")
        q, rep = self.queue.popleft()
        if q.kind != kind or q.frame_index != self.info.index or q.hypotheses != pack(hyps):
            self.stats["query_mismatch"] += 1
        if rep is None or rep.status != ScoreReply.OK:
            raise ObservationUnavailable("recorded reply missing or not OK")
        return rep

    def score_at(self, hyps):
        hyps = np.asarray(hyps, np.float64)
        rep = self._answer(ScoreQuery.AT, hyps)
        n = len(hyps)
        return unpack(rep.scores, np.float64, (n,)), unpack(rep.valid, np.uint8, (n,)).astype(bool)

    def score_grid(self, xy):
        xy = np.asarray(xy, np.float64)
        rep = self._answer(ScoreQuery.GRID, xy)
        n = len(xy)
        return unpack(rep.scores, np.float64, (n, rep.angles)), unpack(rep.valid, np.uint8, (n,)).astype(bool)


def offline_retrack(path: str) -> dict:
    from common.runner import make_filter
    from common.settings import TrackerSettings

    rec = read_recording(path)
    run = rec.run
    settings = TrackerSettings.model_validate_json(run["settings_json"])
    init_box = tuple(json.loads(run["init_box"]))
    replies = {}
    for r in rec.decoded("detector/reply"):
        replies[(r.client, r.request_id)] = r
    per_frame: dict[int, deque] = defaultdict(deque)
    for q in rec.decoded("detector/query"):
        if q.kind != ScoreQuery.TEMPLATE:
            per_frame[q.frame_index].append((q, replies.get((q.client, q.request_id))))
    infos = [i for i in rec.decoded("frame/info") if not i.end_of_stream]
    recorded = rec.decoded("track/estimate")
    done = {e.frame_index for e in recorded}
    stats = {"unanswered": 0, "query_mismatch": 0}
    if not infos:
        raise RecordingError(f"{path}: no frames recorded")
    first = infos[0]
    h0 = np.asarray(first.homography, float).reshape(3, 3) if len(first.homography) == 9 else None
    filt = make_filter(settings, init_box, h0, first.time_s)
    new = []
    for info in infos:
        if info.index not in done:
            continue  # a live run skipped this frame
        state = filt.step(info.time_s, RecordedObservation(info, per_frame[info.index], stats))
        new.append(estimate_msg(info.index, info.capture_ns, state, settings.filter))
    out = compare_estimates(recorded, new)
    out.update(stats)
    out["identical"] = out["identical"] and stats["query_mismatch"] == 0
    return out
