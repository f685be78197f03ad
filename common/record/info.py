"""What an MCAP recording holds, as ``ros2 bag info`` says it: ``polartrack info FILE.mcap``.

From the file's summary section (no message is read): the time span, the message count and rate
of every topic with its schema, the chunks' compression and sizes, and the run's metadata (the
source, the first box, the seed and the settings the recorder stored). A file without a summary
(a recorder killed, a full disk: the summary is written last) is read record by record up to
where it was cut, and the result says so.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, field

NS = 1e-9
MAX_CHUNK_BYTES = 1 << 30
"""A cut file's chunk is expanded only if it says it holds at most this much (a zstd bomb is not)."""


def _read_errors() -> tuple[type[BaseException], ...]:
    """What the mcap library raises on a damaged or cut file (its own errors, and struct's and
    zstd's from inside records)."""
    import struct

    from mcap.exceptions import McapError

    errors: tuple[type[BaseException], ...] = (McapError, ValueError, EOFError, OSError, KeyError, IndexError,
                                               struct.error, RuntimeError)  # lz4 raises RuntimeError
    try:
        import zstandard

        errors += (zstandard.ZstdError,)
    except ImportError:
        pass
    return errors


class InfoError(ValueError):
    """The file is not a readable MCAP recording; the message says why."""


@dataclass
class TopicInfo:
    topic: str
    schema: str
    encoding: str
    messages: int
    rate_hz: float | None
    """Messages per second over the recording's duration (None for a single instant)."""


@dataclass
class RecordingInfo:
    path: str
    size_bytes: int
    profile: str
    library: str
    start_ns: int | None
    end_ns: int | None
    messages: int
    topics: list[TopicInfo]
    chunks: int
    compression: list[str]
    """The chunks' compression schemes ('' is none)."""
    compressed_bytes: int
    uncompressed_bytes: int
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    complete: bool = True
    """False: no summary section (the file was cut); counted by reading it up to the cut."""

    @property
    def duration_s(self) -> float:
        if self.start_ns is None or self.end_ns is None:
            return 0.0
        return (self.end_ns - self.start_ns) * NS

    @property
    def run(self) -> dict:
        """The run's source, first box, seed and settings from the ``run`` metadata ({} if none)."""
        meta = self.metadata.get("run", {})
        out = {k: meta[k] for k in ("run_id", "source", "init_box") if k in meta}
        try:
            settings = json.loads(meta.get("settings_json", "") or "{}")
        except json.JSONDecodeError:
            settings = {}
        if isinstance(settings, dict):
            if "seed" in settings:
                out["seed"] = settings["seed"]
            if "filter" in settings:
                out["filter"] = settings["filter"]
        return out

    def as_dict(self) -> dict:
        d = asdict(self)
        d["duration_s"] = round(self.duration_s, 6)
        d["run"] = self.run
        return d


def _topics(counts: dict[int, int], channels: dict, schemas: dict, duration_s: float) -> list[TopicInfo]:
    out = []
    for cid, ch in sorted(channels.items(), key=lambda kv: kv[1].topic):
        n = int(counts.get(cid, 0))
        schema = schemas.get(ch.schema_id)
        rate = n / duration_s if duration_s > 0 else None
        out.append(TopicInfo(ch.topic, schema.name if schema is not None else "", ch.message_encoding, n, rate))
    return out


def recording_info(path: str) -> RecordingInfo:
    """The summary of the MCAP file at ``path``; :class:`InfoError` if it is not one."""
    from mcap.reader import make_reader

    try:
        size = os.path.getsize(path)
        fh = open(path, "rb")
    except OSError as exc:
        raise InfoError(f"{path}: {exc.strerror or exc}") from None
    with fh:
        try:
            reader = make_reader(fh)
            header = reader.get_header()
        except _read_errors() as exc:
            raise InfoError(f"{path}: not a readable MCAP file ({type(exc).__name__}: {exc})") from None
        try:
            summary = reader.get_summary()
        except _read_errors():
            summary = None  # no footer or a garbled one: the file was cut
        if summary is None or summary.statistics is None:
            return _scan(path, size, header)
        st = summary.statistics
        start, end = (st.message_start_time, st.message_end_time) if st.message_count else (None, None)
        duration = (end - start) * NS if start is not None else 0.0
        chunks = summary.chunk_indexes
        try:
            metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        except _read_errors():
            metadata = {}
        return RecordingInfo(
            path=path, size_bytes=size, profile=header.profile, library=header.library,
            start_ns=start, end_ns=end, messages=int(st.message_count),
            topics=_topics(st.channel_message_counts, summary.channels, summary.schemas, duration),
            chunks=len(chunks), compression=sorted({c.compression for c in chunks}),
            compressed_bytes=sum(c.compressed_size for c in chunks),
            uncompressed_bytes=sum(c.uncompressed_size for c in chunks), metadata=metadata)


def _scan(path: str, size: int, header) -> RecordingInfo:
    """A file without a summary: every record up to the cut, read in order."""
    from mcap.records import Channel, Chunk, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader, breakup_chunk

    channels, schemas, counts, metadata = {}, {}, {}, {}
    start = end = None
    n = 0
    compression, nchunks, comp, uncomp = set(), 0, 0, 0

    def records(stream):
        for rec in stream:
            if isinstance(rec, Chunk):
                nonlocal nchunks, comp, uncomp
                nchunks += 1
                compression.add(rec.compression)
                comp += len(rec.data)
                uncomp += rec.uncompressed_size
                if rec.uncompressed_size > MAX_CHUNK_BYTES:
                    continue  # a chunk claiming gigabytes is not expanded (a zstd bomb)
                yield from breakup_chunk(rec, validate_crc=True)
            else:
                yield rec

    with open(path, "rb") as fh:
        try:
            for rec in records(StreamReader(fh, skip_magic=False, emit_chunks=True).records):
                if isinstance(rec, Schema):
                    schemas[rec.id] = rec
                elif isinstance(rec, Channel):
                    channels[rec.id] = rec
                elif isinstance(rec, Metadata):
                    metadata[rec.name] = dict(rec.metadata)
                elif isinstance(rec, Message):
                    n += 1
                    counts[rec.channel_id] = counts.get(rec.channel_id, 0) + 1
                    start = rec.log_time if start is None else min(start, rec.log_time)
                    end = rec.log_time if end is None else max(end, rec.log_time)
        except _read_errors():
            pass  # the cut: everything before it is counted
    duration = (end - start) * NS if start is not None else 0.0
    return RecordingInfo(path=path, size_bytes=size, profile=header.profile, library=header.library,
                         start_ns=start, end_ns=end, messages=n,
                         topics=_topics(counts, channels, schemas, duration), chunks=nchunks,
                         compression=sorted(compression), compressed_bytes=comp, uncompressed_bytes=uncomp,
                         metadata=metadata, complete=False)


def _stamp(ns: int | None) -> str:
    if ns is None:
        return "-"
    from datetime import datetime, timezone

    t = datetime.fromtimestamp(ns * NS, tz=timezone.utc)
    return f"{t.isoformat(timespec='milliseconds').replace('+00:00', 'Z')} ({ns * NS:.3f})"


def _mib(n: int) -> str:
    return f"{n / 2**20:.1f} MiB"


def format_info(info: RecordingInfo) -> str:
    """The ``ros2 bag info``-style text of :func:`recording_info`'s result."""
    lines = [
        f"Files:             {info.path}",
        f"Bag size:          {_mib(info.size_bytes)}",
        f"Storage:           mcap ({info.profile or 'no profile'}, written by {info.library or 'unknown'})"
        + ("" if info.complete else "; no summary: cut short, counted up to the cut"),
        f"Duration:          {info.duration_s:.3f} s",
        f"Start:             {_stamp(info.start_ns)}",
        f"End:               {_stamp(info.end_ns)}",
        f"Messages:          {info.messages}",
    ]
    if info.chunks:
        comp = ", ".join(c or "none" for c in info.compression)
        ratio = info.uncompressed_bytes / info.compressed_bytes if info.compressed_bytes else float("nan")
        lines.append(f"Chunks:            {info.chunks}, {comp}: {_mib(info.compressed_bytes)} from "
                     f"{_mib(info.uncompressed_bytes)} ({ratio:.2f}x)")
    run = info.run
    if run:
        lines.append("Run:               " + ", ".join(f"{k} {v}" for k, v in run.items()))
    lines.append("Topic information:")
    width = max((len(t.topic) for t in info.topics), default=0)
    for t in info.topics:
        rate = "-" if t.rate_hz is None else f"{t.rate_hz:.2f} Hz"
        lines.append(f"  {t.topic:<{width}}  {t.messages:>8} msgs  {rate:>10}  {t.schema} ({t.encoding})")
    return "\n".join(lines)
