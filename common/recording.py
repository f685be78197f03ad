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
import math
import struct
import zlib
from collections import defaultdict, deque
from dataclasses import dataclass, field
from io import BytesIO
from typing import Iterable, Iterator

import numpy as np

from common.msgs import Estimate, ScoreQuery, ScoreReply, TOPICS
from common.msgs.convert import estimate_msg, info_frame, info_homography


class RecordingError(ValueError):
    pass


MiB = 1 << 20
MCAP_MAGIC = b"\x89MCAP0\r\n"
MAX_RECORD_BYTES = 64 * MiB
"""A record (a chunk as stored, a message, a metadata record) larger than this is skipped unread
(the recorder's chunks are 256 KiB, or one frame of at most 32 MiB)."""
MAX_CHUNK_BYTES = 64 * MiB
"""A chunk decompressing to more than this is skipped: its stated size is checked before
decompressing, and the decompressor never writes more (a zstd bomb took replay to 1.3 GB)."""
MAX_CHANNELS = 1 << 16
MAX_METADATA = 64

_OP_HEADER, _OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK, _OP_METADATA = 1, 2, 3, 4, 5, 6, 0x0C


@dataclass
class ReadReport:
    """What a streamed read met: ``messages`` read, records ``skipped`` per reason (a chunk whose
    CRC fails, too large, not decompressible...), ``cut``: why it stopped before the footer (None:
    read to the end), ``malformed``: messages per topic that did not decode where decoded."""
    messages: int = 0
    skipped: dict[str, int] = field(default_factory=dict)
    cut: str | None = None
    malformed: dict[str, int] = field(default_factory=dict)

    def skip(self, reason: str) -> None:
        self.skipped[reason] = self.skipped.get(reason, 0) + 1

    def bad(self, topic: str, n: int = 1) -> None:
        self.malformed[topic] = self.malformed.get(topic, 0) + n

    def summary(self) -> dict:
        return {"messages_read": self.messages, "records_skipped": dict(self.skipped),
                "malformed": dict(self.malformed), "cut": self.cut}


def _stream(body: bytes):
    from mcap.data_stream import ReadDataStream

    return ReadDataStream(BytesIO(body))


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    """A chunk's records, never more than ``size`` + 1 bytes decompressed; ValueError."""
    if compression == "":
        return data
    data = bytes(data) if compression == "zstd" else data
    if compression == "zstd":
        import zstandard

        out = bytearray()
        with zstandard.ZstdDecompressor().stream_reader(BytesIO(data)) as r:
            while len(out) <= size:
                piece = r.read(min(1 << 20, size + 1 - len(out)))
                if not piece:
                    break
                out += piece
        return bytes(out)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=size + 1)
    raise ValueError(f"unknown compression {compression[:20]!r}")


def _chunk_records(body: bytes, report: ReadReport) -> Iterator[tuple[int, memoryview]]:
    """(opcode, record body) of the records in a chunk; a chunk that cannot be trusted is skipped
    and counted (stated size over :data:`MAX_CHUNK_BYTES`, decompressed size or CRC not as stated,
    a record running past its end). The records are views of the chunk (no copy)."""
    view = memoryview(body)
    try:
        _start, _end, usize, crc, clen = struct.unpack_from("<QQQII", view, 0)
        compression = bytes(view[32:32 + clen]).decode("utf-8")
        (dlen,) = struct.unpack_from("<Q", view, 32 + clen)
        if 40 + clen + dlen > len(view):
            raise ValueError("data past the record")
        packed = view[40 + clen:40 + clen + dlen]
    except (struct.error, ValueError):  # a garbled chunk header
        report.skip("bad_chunk")
        return
    if usize > MAX_CHUNK_BYTES:
        report.skip("chunk_too_large")
        return
    try:
        data = memoryview(_decompress(compression, packed, usize))
    except Exception:  # noqa: BLE001 - the decompressors raise their own types
        report.skip("chunk_not_decompressible")
        return
    if len(data) != usize:
        report.skip("chunk_size_mismatch")
        return
    if crc and zlib.crc32(data) != crc:
        report.skip("chunk_crc")
        return
    pos, n = 0, len(data)
    while pos < n:
        if n - pos < 9:
            report.skip("bad_chunk")
            return
        opcode, length = struct.unpack_from("<BQ", data, pos)
        if length > n - pos - 9:
            report.skip("bad_chunk")
            return
        yield opcode, data[pos + 9:pos + 9 + length]
        pos += 9 + length


def _top_records(fh, size: int, report: ReadReport) -> Iterator[tuple[int, bytes]]:
    """(opcode, record body) of the file's records in order, a chunk's records in its place;
    stops at the footer, or where the file is cut (``report.cut``)."""
    if fh.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
        raise RecordingError("not an MCAP file (no MCAP magic)")
    pos = len(MCAP_MAGIC)
    while True:
        head = fh.read(9)
        if len(head) < 9:
            report.cut = f"the file ends at byte {pos + len(head)} without a footer"
            return
        opcode, length = struct.unpack("<BQ", head)
        if length > size - pos - 9:
            report.cut = f"a record at byte {pos} runs {length} bytes, past the end of the file"
            return
        if length > MAX_RECORD_BYTES:
            fh.seek(length, 1)
            report.skip("record_too_large")
        else:
            body = fh.read(length)
            if opcode == _OP_CHUNK:
                yield from _chunk_records(body, report)
            elif opcode == _OP_FOOTER:
                return
            else:
                yield opcode, body
            del body  # not held while the next record is read
        pos += 9 + length


def stream_messages(path: str, topics: Iterable[str] | None = None, report: ReadReport | None = None,
                    metadata: dict | None = None, kinds: dict | None = None) -> Iterator[tuple[str, int, bytes]]:
    """(topic, log time, data) of every message (of ``topics``, when given) in file order, one
    chunk in memory at a time. A file cut short ends where it is cut (``report.cut``); records
    that cannot be trusted are skipped and counted in ``report.skipped``; the file's metadata
    records go into ``metadata`` (name -> dict), each topic's (message encoding, schema name or
None) into ``kinds``. RecordingError: no such file, not an MCAP file."""
    from mcap.records import Channel, Metadata, Schema

    report = report if report is not None else ReadReport()
    wanted = None if topics is None else set(topics)
    channels: dict[int, str] = {}
    schemas: dict[int, str] = {}
    try:
        fh = open(path, "rb")
    except FileNotFoundError:
        raise RecordingError(f"{path}: no such file") from None
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read ({exc.strerror or exc})") from None
    with fh:
        import os

        size = os.fstat(fh.fileno()).st_size
        try:
            for opcode, body in _top_records(fh, size, report):
                try:
                    if opcode == _OP_MESSAGE:
                        channel_id, _seq, log_time, _pub = struct.unpack_from("<HIQQ", body, 0)
                        topic = channels.get(channel_id)
                        if topic is None:
                            report.skip("unknown_channel")
                            continue
                        report.messages += 1
                        if wanted is None or topic in wanted:
                            data = bytes(body[22:])
                            del body
                            yield topic, int(log_time), data
                            del data
                        continue
                    body = bytes(body)  # a small record: parsed by mcap's classes
                    if opcode == _OP_CHANNEL:
                        ch = Channel.read(_stream(body))
                        if ch.id in channels or len(channels) < MAX_CHANNELS:
                            channels[ch.id] = _topic_suffix(ch.topic)
                            if kinds is not None:
                                kinds[channels[ch.id]] = (ch.message_encoding, schemas.get(ch.schema_id))
                    elif opcode == _OP_SCHEMA and kinds is not None:
                        sc = Schema.read(_stream(body))
                        if sc.id in schemas or len(schemas) < MAX_CHANNELS:
                            schemas[sc.id] = sc.name
                    elif opcode == _OP_METADATA and metadata is not None:
                        md = Metadata.read(_stream(body))
                        if md.name in metadata or len(metadata) < MAX_METADATA:
                            metadata[md.name] = dict(md.metadata)
                except (struct.error, ValueError, EOFError, UnicodeDecodeError, OverflowError):
                    report.skip("bad_record")
                except Exception as exc:  # noqa: BLE001 - mcap's EndOfFile and others on a garbled record
                    if type(exc).__module__.startswith("mcap"):
                        report.skip("bad_record")
                    else:
                        raise
        except RecordingError as exc:
            raise RecordingError(f"{path}: {exc}") from None
        except OSError as exc:
            raise RecordingError(f"{path}: cannot read ({exc.strerror or exc})") from None


def _topic_suffix(topic: str) -> str:
    t = topic.lstrip("/")
    if t.startswith("polartrack/"):
        parts = t.split("/", 2)
        return parts[2] if len(parts) == 3 else t
    return t


@dataclass
class Recording:
    path: str
    metadata: dict[str, dict[str, str]]
    messages: dict[str, list[tuple[int, bytes]]] = field(default_factory=dict)
    """topic -> [(log_time, data)] in file order (the topics read: see :func:`read_recording`)."""
    counts: dict[str, int] = field(default_factory=dict)
    """topic -> messages in the file, read or not."""
    report: ReadReport = field(default_factory=ReadReport)

    @property
    def run(self) -> dict:
        if "run" not in self.metadata:
            raise RecordingError(f"{self.path}: no run metadata (was it written by polartrack?)")
        return self.metadata["run"]

    def decoded(self, topic: str) -> list:
        """The topic's messages decoded; one that does not decode (or exceeds the key's size cap)
        is skipped and counted in ``report.malformed``."""
        from common.validation import Invalid, decode

        cls = TOPICS[topic]
        out = []
        for _, d in self.messages.get(topic, []):
            try:
                out.append(decode(cls, d, topic))
            except Invalid:
                self.report.bad(topic)
        return out

    def stream(self, topics: Iterable[str]) -> Iterator[tuple[str, int, bytes]]:
        """The file read again for ``topics``, streamed (see :func:`stream_messages`)."""
        return stream_messages(self.path, topics, ReadReport())


def run_metadata(raw: bytes) -> dict[str, str]:
    """The MCAP ``run`` metadata of a RunConfig message (what the recorder writes)."""
    from google.protobuf.json_format import MessageToDict

    from common.msgs import RunConfig

    cfg = RunConfig.FromString(raw)
    d = MessageToDict(cfg, preserving_proto_field_name=True, always_print_fields_with_no_presence=True)
    return {k: v if isinstance(v, str) else json.dumps(v) for k, v in d.items()}


def read_recording(path: str, warn=None, topics: Iterable[str] | None = None,
                   skip: Iterable[str] = ()) -> Recording:
    """The recording's messages of ``topics`` (default: all) but those of ``skip``, read in one
    streamed pass (replay passes ``skip=("frame/image",)`` and streams the frames later: memory
    for the small topics only), with every topic's count. A file cut short (no footer: a recorder
    killed or out of disk) is read up to its last complete record, records that cannot be trusted
    (bad CRC, a chunk too large or not decompressible) are skipped; either gives one warning line
    through ``warn`` (default: stderr). Without a ``run`` metadata record (cut before the end) the
    run metadata comes from the recorded ``run/config``. RecordingError: no such file, not an
    MCAP file, no message in it."""
    wanted = None if topics is None else set(topics)
    skipped = set(skip)
    meta: dict[str, dict[str, str]] = {}
    msgs: dict[str, list] = defaultdict(list)
    counts: dict[str, int] = defaultdict(int)
    report = ReadReport()
    for topic, t, data in stream_messages(path, None, report, meta):
        counts[topic] += 1
        if (wanted is None or topic in wanted) and topic not in skipped:
            msgs[topic].append((t, data))
    if report.messages == 0 and (report.cut or report.skipped):
        why = report.cut or ", ".join(f"{k} {v}" for k, v in report.skipped.items())
        raise RecordingError(f"{path}: not a readable MCAP file (no message could be read: {why})")
    if "run" not in meta and "run/config" in msgs:
        try:
            meta["run"] = run_metadata(msgs["run/config"][0][1])
        except Exception:  # noqa: BLE001 - a garbled config: no run metadata
            pass
    lines = []
    if report.cut:
        lines.append(f"warning: {path} is cut short ({report.cut}): read {report.messages} messages "
                     "up to the last complete record")
    if report.skipped:
        lines.append(f"warning: {path}: records skipped: "
                     + ", ".join(f"{k} {v}" for k, v in sorted(report.skipped.items())))
    for message in lines:
        if warn is None:
            import sys

            print(message, file=sys.stderr)
        else:
            warn(message)
    return Recording(path, meta, dict(msgs), dict(counts), report)


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
    from common.detector_queries import QueryDetector
    from common.runner import Tracker, stabilises
    from common.tracking.observation import ObservationUnavailable

    rec = read_recording(path, skip=("frame/image",))
    run = rec.run
    if run.get("multi_json"):
        from common.multitarget_runner import MultiRun, offline_retrack_multi

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
