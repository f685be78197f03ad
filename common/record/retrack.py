"""Re-running a recording's tracker: ``replay --offline`` with no detector (the recorded replies
answer every query) and the comparison of the new estimates with the recorded ones, the same
for one target and for several articulated ones.

:func:`offline_retrack` rebuilds the tracker from the recorded run configuration and steps it
over the recorded frame infos (and images, when it stabilises); every query it makes is checked
against the recorded one and answered with the recorded reply (:class:`RecordedReplies`).
"""

from __future__ import annotations

import json
import math
from collections import defaultdict, deque

import numpy as np

from common.msgs import Estimate, MultiEstimate, ScoreQuery, ScoreReply
from common.msgs.convert import estimate_msg, info_frame, info_homography
from common.record.reader import Recording, RecordingError, read_recording

COMPARED = ("frame_index", "time_s", "observed", "filter", "x", "y", "theta_deg", "p_visible", "world_x", "world_y",
            "vx", "vy", "speed", "mmse_x", "mmse_y", "n_eff", "resampled", "w", "h", "reacquired",
            "box_dx", "box_dy")
"""Estimate fields that must be identical on replay (not timings or latencies)."""


def same_estimate(a: Estimate, b: Estimate) -> bool:
    return all(getattr(a, f) == getattr(b, f) for f in COMPARED)


def compare_estimates(recorded: list, new: list, same=same_estimate) -> dict:
    """Frame by frame, the ``new`` estimates against the ``recorded`` ones with ``same`` (Estimate or,
    with ``same_multi_estimate``, MultiEstimate messages)."""
    by_frame = {e.frame_index: e for e in recorded}
    mismatched = [e.frame_index for e in new if e.frame_index not in by_frame or not same(by_frame[e.frame_index], e)]
    missing = sorted(set(by_frame) - {e.frame_index for e in new})
    return {"identical": not mismatched and not missing and len(new) > 0, "compared": len(new),
            "recorded": len(recorded), "mismatched": mismatched[:20], "missing": missing[:20]}


class RecordedReplies:
    """``ask`` for a detector client (:class:`common.detector.remote.QueryDetector`, or the
    multi-target filters' :class:`common.detector.remote.QueryPartEvidence`) answered from
    a recording: each frame's recorded queries in order, each checked against the one asked
    (every field but the request id and the client, bit for bit; a mismatch counted in
    ``stats["query_mismatch"]``) and answered with its recorded reply (none left:
    ``stats["unanswered"]``)."""

    def __init__(self, rec: Recording, stats: dict, kinds: tuple[int, ...] | None = None):
        replies = {(r.client, r.request_id): r for r in rec.decoded("detector/reply")}
        self.per_frame: dict[int, deque] = defaultdict(deque)
        seen = set()
        for q in rec.decoded("detector/query"):
            key = (q.client, q.request_id)
            if key not in seen and (kinds is None or q.kind in kinds):  # a retried query counts once
                seen.add(key)
                self.per_frame[q.frame_index].append((q, replies.get(key)))
        self.stats = stats

    @staticmethod
    def _question(q: ScoreQuery) -> bytes:
        c = ScoreQuery()
        c.CopyFrom(q)
        c.ClearField("request_id")
        c.ClearField("client")
        return c.SerializeToString(deterministic=True)

    def ask(self, q: ScoreQuery) -> ScoreReply | None:
        queue = self.per_frame[q.frame_index]
        if not queue:
            self.stats["unanswered"] += 1
            return None
        r, rep = queue.popleft()
        if self._question(r) != self._question(q):
            self.stats["query_mismatch"] += 1
        return rep


def run_settings(rec: Recording):
    """(TrackerSettings, init box) of a single-target recording's run metadata; RecordingError
    in one line when either is missing or garbled."""
    from common.settings import TrackerSettings

    run = rec.run
    try:
        settings = TrackerSettings.model_validate_json(run.get("settings_json") or "")
    except ValueError as exc:
        first = str(exc).splitlines()
        raise RecordingError(f"{rec.path}: the run metadata's settings are not valid tracker settings "
                             f"({first[1].strip() if len(first) > 1 else first[0][:200]})") from None
    try:
        box = tuple(float(v) for v in json.loads(run.get("init_box") or ""))
        if len(box) != 4 or not all(map(math.isfinite, box)) or box[2] <= 0 or box[3] <= 0:
            raise ValueError(f"{len(box)} values")
    except (ValueError, TypeError) as exc:
        raise RecordingError(f"{rec.path}: the run metadata's init box is not x,y,w,h "
                             f"({type(exc).__name__}: {str(exc)[:100]})") from None
    return settings, box


def checked_infos(rec: Recording, infos: list) -> list:
    """The frame infos a tracker can step on, in order (as the live tracker, which drops the
    others); the others are counted in ``rec.report.malformed['frame/info']``."""
    from common.validation import FrameOrder, Invalid, check_frame_info

    order, out = FrameOrder(), []
    for info in infos:
        try:
            check_frame_info(info, order)
        except Invalid:
            rec.report.bad("frame/info")
            continue
        if not info.end_of_stream:
            out.append(info)
    return out


class _Images:
    """The recording's frame images streamed in file order, looked up by frame index as the
    frames are stepped: those ahead are held (at most ``ahead``), those behind dropped."""

    def __init__(self, rec: Recording, ahead: int = 64):
        self._it = rec.stream(["frame/image"])
        self._held: dict[int, np.ndarray] = {}
        self._ahead = ahead

    def get(self, index: int) -> np.ndarray | None:
        """Frame ``index``'s pixels (a read-only view into the recorded bytes); None when not
        recorded. ValueError: the recorded image is garbled (its geometry or pixels)."""
        from common.msgs.image_wire import decode_frame
        from common.validation import max_bytes

        for k in [k for k in self._held if k < index]:
            del self._held[k]
        while index not in self._held:
            try:
                _topic, _t, data = next(self._it)
            except StopIteration:
                return None
            if len(data) > max_bytes("frame/image"):
                continue
            try:
                fid, _msg, image = decode_frame(data)
            except Exception:  # noqa: BLE001 - protobuf and the wire reader raise several types
                continue
            if fid >= index and len(self._held) < self._ahead:
                self._held[fid] = image
        return self._held.pop(index)


def offline_retrack(path: str) -> dict:
    """Re-run the tracker over a recording's frames with the recorded detector replies and compare
    its estimates with the recorded ones. The frames' pixels are read only when stabilising, and
    then streamed (the other topics are read into memory: a few kB a frame)."""
    from common.detector.remote import QueryDetector
    from common.single_target.runner import Tracker, stabilises
    from common.tracking.observation import ObservationUnavailable

    rec = read_recording(path, skip=("frame/image",))
    run = rec.run
    if run.get("multi_json"):
        from common.multitarget.runner import MultiRun

        try:
            multi = MultiRun.from_json(run["multi_json"])
        except (ValueError, KeyError, TypeError) as exc:
            raise RecordingError(f"{path}: the run metadata's multi-target settings are not valid "
                                 f"({type(exc).__name__}: {str(exc).splitlines()[0][:200]})") from None
        out = offline_retrack_multi(rec, multi)
        out["malformed"] = dict(rec.report.malformed)
        return out
    settings, init_box = run_settings(rec)
    stats = {"unanswered": 0, "query_mismatch": 0}
    replies = RecordedReplies(rec, stats)
    recorded = rec.decoded("track/estimate")
    done = {e.frame_index for e in recorded}
    infos = [i for i in checked_infos(rec, rec.decoded("frame/info")) if i.index in done]  # as the live run
    if not infos:
        raise RecordingError(f"{path}: no frames recorded")
    pixels = stabilises(settings, info_homography(infos[0]))
    images = _Images(rec) if pixels else None
    tracker = None
    new = []
    for info in infos:
        image = None
        if pixels:
            image = images.get(info.index)
            if image is None:
                raise RecordingError(f"{path}: frame {info.index}'s image is not recorded or unreadable "
                                     "(needed to stabilise)")
        frame = info_frame(info, image)
        if tracker is None:
            try:
                tracker = Tracker.start(frame, init_box, settings, QueryDetector(replies.ask, "offline"))
            except ObservationUnavailable as exc:
                raise RecordingError(f"{path}: no usable template for frame {info.index}: {exc}") from None
        state = tracker.step(frame)
        new.append(estimate_msg(info.index, info.capture_ns, state, settings.filter))
    out = compare_estimates(recorded, new)
    out.update(stats)
    out["identical"] = out["identical"] and stats["query_mismatch"] == 0
    out["malformed"] = dict(rec.report.malformed)
    return out


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
    return compare_estimates(recorded, new, same=same_multi_estimate)


def offline_retrack_multi(rec: Recording, run) -> dict:
    """Re-run a multi-target recording (``run``: its :class:`common.multitarget.runner.MultiRun`)
    from its recorded part-evidence replies (no detector, no pixels) and compare every estimate
    with the recorded one."""
    from common.msgs.convert import multi_estimate_msg
    from common.multitarget.runner import MultiTracker
    from common.detector.remote import EvidenceUnavailable, QueryPartEvidence

    recorded = rec.decoded("track/multi_estimate")
    done = {e.frame_index for e in recorded}
    infos = [i for i in rec.decoded("frame/info") if not i.end_of_stream and i.index in done]
    if not infos:
        raise RecordingError(f"{rec.path}: no multi-target estimates recorded")
    stats = {"unanswered": 0, "query_mismatch": 0}
    replies = RecordedReplies(rec, stats, kinds=(ScoreQuery.HISTOGRAMS, ScoreQuery.SIMILARITY))
    tracker = None
    new = []
    for info in infos:
        ev = QueryPartEvidence(replies.ask, "offline", info.index, (info.width, info.height), run.config.histogram)
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
