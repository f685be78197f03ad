"""Reading PolarTrack MCAP recordings, and re-running the tracker offline from recorded replies.

Multi-target recordings (``multi_json`` in the run metadata) are re-run by
:func:`common.multitarget_runner.offline_retrack_multi` from their recorded part-evidence replies.

``offline_retrack`` rebuilds the tracker from the recorded run configuration and steps it over
the recorded frame infos (and images, when it stabilises); every query it makes is checked
against the recorded query (same kind, frame, factor, template version and hypotheses, bit for
bit) and answered with the recorded reply, so no detector is needed. The new estimates are
compared with the recorded ones.
"""

from __future__ import annotations

import json
from collections import defaultdict, deque
from dataclasses import dataclass, field

from mcap.reader import make_reader

from common.msgs import Estimate, ScoreQuery, ScoreReply, TOPICS, msg_to_image
from common.msgs.convert import estimate_msg, info_frame, info_homography


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


def run_metadata(raw: bytes) -> dict[str, str]:
    """The MCAP ``run`` metadata of a RunConfig message (what the recorder writes)."""
    from google.protobuf.json_format import MessageToDict

    from common.msgs import RunConfig

    cfg = RunConfig.FromString(raw)
    d = MessageToDict(cfg, preserving_proto_field_name=True, always_print_fields_with_no_presence=True)
    return {k: v if isinstance(v, str) else json.dumps(v) for k, v in d.items()}


def _read_cut(path: str) -> tuple[dict, dict, int]:
    """(metadata, messages, records read) of a file cut short (a recorder killed, a full disk):
    every record up to the last complete one, read in file order."""
    from mcap.reader import NonSeekingReader

    meta: dict[str, dict[str, str]] = {}
    msgs: dict[str, list] = defaultdict(list)
    n = 0
    with open(path, "rb") as fh:
        reader = NonSeekingReader(fh, validate_crcs=True)
        try:
            for _schema, channel, message in reader.iter_messages(log_time_order=False):
                msgs[channel.topic].append((message.log_time, message.data))
                n += 1
        except Exception:  # noqa: BLE001 - the cut: a partial record or chunk, or no footer
            pass
    return meta, dict(msgs), n


def read_recording(path: str, warn=None) -> Recording:
    """The whole recording; a file cut short (no footer: a recorder killed or out of disk) is
    read up to its last complete record, with one warning line through ``warn`` (default:
    stderr), and no run metadata when it was cut before the end."""
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
        try:
            meta, msgs, n = _read_cut(path)
        except Exception:  # noqa: BLE001
            n = 0
        if n == 0:
            raise RecordingError(f"{path}: not a readable MCAP file ({type(exc).__name__}: {exc})") from None
        if meta == {} and "run/config" in msgs:
            try:
                meta["run"] = run_metadata(msgs["run/config"][0][1])
            except Exception:  # noqa: BLE001 - a garbled config: no run metadata
                pass
        message = f"warning: {path} is cut short ({type(exc).__name__}): read {n} messages up to the last complete record"
        if warn is None:
            import sys

            print(message, file=sys.stderr)
        else:
            warn(message)
    return Recording(path, meta, dict(msgs))


COMPARED = ("frame_index", "time_s", "observed", "filter", "x", "y", "theta_deg", "p_visible", "world_x", "world_y",
            "vx", "vy", "speed", "mmse_x", "mmse_y", "n_eff", "resampled", "w", "h", "reacquired")
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
    """``ask`` for a :class:`common.detector_queries.QueryDetector` answered from a recording: each
    frame's recorded queries in order, each checked against the one asked (same kind, frame,
    factor, template version and hypotheses, bit for bit) and answered with its recorded reply."""

    def __init__(self, rec: Recording, stats: dict):
        replies = {(r.client, r.request_id): r for r in rec.decoded("detector/reply")}
        self.per_frame: dict[int, deque] = defaultdict(deque)
        seen = set()
        for q in rec.decoded("detector/query"):
            key = (q.client, q.request_id)
            if key not in seen:  # a query retried (the detector had lost the template) counts once
                seen.add(key)
                self.per_frame[q.frame_index].append((q, replies.get(key)))
        self.stats = stats

    def ask(self, q: ScoreQuery) -> ScoreReply | None:
        queue = self.per_frame[q.frame_index]
        if not queue:
            self.stats["unanswered"] += 1
            return None
        r, rep = queue.popleft()
        same = (r.kind == q.kind and r.frame_index == q.frame_index and r.count == q.count
                and r.hypotheses == q.hypotheses and (r.factor or 1.0) == (q.factor or 1.0)
                and r.one_off == q.one_off and r.template_version == q.template_version)
        if not same:
            self.stats["query_mismatch"] += 1
        return rep


def offline_retrack(path: str) -> dict:
    """Re-run the tracker over a recording's frames with the recorded detector replies and compare
    its estimates with the recorded ones (the frames' pixels are read only when stabilising)."""
    from common.detector_queries import QueryDetector
    from common.runner import Tracker, stabilises
    from common.settings import TrackerSettings
    from common.tracking.observation import ObservationUnavailable

    rec = read_recording(path)
    run = rec.run
    if run.get("multi_json"):
        from common.multitarget_runner import MultiRun, offline_retrack_multi

        return offline_retrack_multi(rec, MultiRun.from_json(run["multi_json"]))
    settings = TrackerSettings.model_validate_json(run["settings_json"])
    init_box = tuple(json.loads(run["init_box"]))
    stats = {"unanswered": 0, "query_mismatch": 0}
    replies = RecordedReplies(rec, stats)
    recorded = rec.decoded("track/estimate")
    done = {e.frame_index for e in recorded}
    infos = [i for i in rec.decoded("frame/info") if not i.end_of_stream and i.index in done]  # as the live run
    if not infos:
        raise RecordingError(f"{path}: no frames recorded")
    pixels = stabilises(settings, info_homography(infos[0]))
    images = {int(m.frame_id): m for m in rec.decoded("frame/image")} if pixels else {}
    tracker = None
    new = []
    for info in infos:
        image = None
        if pixels:
            if info.index not in images:
                raise RecordingError(f"{path}: frame {info.index}'s image is not recorded (needed to stabilise)")
            image = msg_to_image(images[info.index])
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
    return out
