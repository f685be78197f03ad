"""Reading PolarTrack MCAP recordings: one streaming reader (:func:`stream_messages`) that
reads a file cut short up to its last whole record, and :func:`read_recording` on top of it
(the run metadata, the messages by topic, decoded on demand). Re-running a recording's tracker
is :mod:`common.record.retrack`.
"""

from __future__ import annotations

import struct
import zlib
from collections import defaultdict
from dataclasses import dataclass, field
from io import BytesIO
from typing import Iterable, Iterator

from common.msgs import TOPICS
from common.msgs.topics import topic_suffix
from common.record.meta import run_metadata


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
    stops at the footer (followed by the closing magic), or where the file is cut (``report.cut``)."""
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
                tail = fh.read(len(MCAP_MAGIC))
                if tail != MCAP_MAGIC:  # cut inside the closing magic: every record is whole
                    report.cut = f"the file ends at byte {pos + 9 + length + len(tail)} without its closing magic"
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
                            channels[ch.id] = topic_suffix(ch.topic)
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
    warn_read(path, report, warn)
    return Recording(path, meta, dict(msgs), dict(counts), report)


def warn_read(path: str, report: ReadReport, warn=None) -> None:
    """One line (to ``warn``, default standard error) for a file read up to a cut, and one for
    records skipped."""
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
