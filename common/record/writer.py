"""Writing PolarTrack MCAP recordings: one schema per message class, one channel per topic,
chunks written around the page cache (:mod:`common.record.direct_file`) so that a writer killed
with SIGKILL leaves a file readable up to its last flush; a recording split into files by size
or duration (:class:`SplitSink`). The recorder service (``services/recorder.py``) is the bus
shell around it."""

from __future__ import annotations

import errno
import logging
import os
from pathlib import Path

from mcap.writer import CompressionType, Writer
from mcap_protobuf.schema import build_file_descriptor_set

from common.msgs import message_class
from common.record import split_path
from common.record.direct_file import DirectFile

log = logging.getLogger("polartrack.recorder")


class SmallDiskFile(DirectFile):
    """A :class:`DirectFile` on a simulated disk of ``limit`` bytes: ENOSPC beyond."""

    def __init__(self, path: str, limit: int):
        super().__init__(path)
        self.limit = limit

    def _pwrite(self, length: int) -> None:
        if self._base + length > self.limit:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), self.path)
        super()._pwrite(length)


class McapSink:
    """MCAP writing with one schema per message class and one channel per topic."""

    def __init__(self, path: str, compression: str = "lz4", chunk_size: int = 256 << 10,
                 disk_bytes: int | None = None):
        """``chunk_size``: small chunks are much cheaper for large frames. The writer collects a
        chunk in a growing buffer, so a 2.7 MB frame landing in a 4 MiB chunk behind other
        messages is copied again as the buffer grows: 11.9 ms of CPU a frame against 1.9 ms with
        256 KiB chunks (1280x720 RGB frames plus a frame's queries, replies and estimates)."""
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        # raw video around the page cache (see common.record.direct_file)
        self.fh = DirectFile(path) if disk_bytes is None else SmallDiskFile(path, disk_bytes)
        self.flushed = 0
        """Bytes of the file as of the last successful flush (it ends on a whole record there)."""
        self.flushed_messages = 0
        from collections import deque

        self.boundaries: deque[tuple[int, int]] = deque([(0, 0)], maxlen=4096)
        """(file length, messages) where the file ended on a whole record, the latest ones."""
        comp = {"lz4": CompressionType.LZ4, "zstd": CompressionType.ZSTD}.get(compression, CompressionType.NONE)
        self.writer = Writer(self.fh, chunk_size=chunk_size, compression=comp)
        self.writer.start(profile="protobuf", library="polartrack")
        self.schemas: dict[str, int] = {}
        self.channels: dict[str, int] = {}
        self.counts: dict[str, int] = {}
        self.sequence = 0
        self.metadata_written: set[str] = set()
        self.flush()  # the header on disk at once: even a file cut at once is an MCAP file's start

    def channel(self, topic: str, data: bytes = b"") -> int:
        """The topic's channel, registered with its first message: ``frame/image`` is a
        foxglove.CompressedImage channel when that message is one, else a RawImage one."""
        ch = self.channels.get(topic)
        if ch is not None:
            return ch
        cls = message_class(topic)
        if topic == "frame/image" and data:
            from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage

            from common.msgs.image_wire import is_compressed

            try:
                cls = CompressedImage if is_compressed(data) else cls
            except ValueError:
                pass
        if cls is None:
            ch = self.writer.register_channel(topic=topic, message_encoding="", schema_id=0)
        else:
            name = cls.DESCRIPTOR.full_name
            sid = self.schemas.get(name)
            if sid is None:
                sid = self.writer.register_schema(name=name, encoding="protobuf",
                                                  data=build_file_descriptor_set(cls).SerializeToString())
                self.schemas[name] = sid
            ch = self.writer.register_channel(topic=topic, message_encoding="protobuf", schema_id=sid)
        self.channels[topic] = ch
        return ch

    def write(self, topic: str, data: bytes, log_time: int, publish_time: int) -> None:
        self.sequence += 1
        self.writer.add_message(self.channel(topic, data), log_time=log_time, data=data, publish_time=publish_time,
                                sequence=self.sequence)
        self.counts[topic] = self.counts.get(topic, 0) + 1
        end = self.fh.tell()
        if end != self.boundaries[-1][0]:  # the writer emitted a chunk: the file ends on a whole record
            self.boundaries.append((end, self.sequence))

    def metadata(self, name: str, data: dict[str, str]) -> None:
        if name not in self.metadata_written:
            self.writer.add_metadata(name, {k: str(v) for k, v in data.items()})
            self.metadata_written.add(name)

    def flush(self) -> None:
        self.fh.flush()
        self.flushed = self.fh.tell()
        self.flushed_messages = self.sequence

    def close(self) -> None:
        self.writer.finish()
        self.fh.close()

    def abort(self) -> None:
        """After a failed write: cut the file back to the last whole record that reached the disk
        (a reader gets every message up to there) and close it without writing more."""
        fh = self.fh
        on_disk = fh._base  # every byte before the stage was written
        cut = max([(self.flushed, self.flushed_messages)] + [b for b in self.boundaries if b[0] <= on_disk])
        self.flushed, self.flushed_messages = cut
        try:
            os.ftruncate(fh._fd, self.flushed)
        except OSError:
            pass
        try:
            os.close(fh._fd)
        except OSError:
            pass
        fh.closed = True


class SplitSink:
    """An :class:`McapSink` that moves on to the next file (``NAME.splitK.mcap``) before a frame
    image once the current one holds ``max_bytes`` or spans ``max_duration_ns`` of log time:
    rosbag2's ``--max-bag-size``/``--max-bag-duration``. Every file is a whole MCAP file that
    replays alone: it carries the run's metadata and its own message counts."""

    def __init__(self, path: str, compression: str, chunk_size: int, disk_bytes: int | None = None,
                 max_bytes: int | None = None, max_duration_ns: int | None = None):
        self.path, self.args = path, (compression, chunk_size, disk_bytes)
        self.max_bytes, self.max_duration_ns = max_bytes, max_duration_ns
        self.part = 0
        self.paths = [path]
        self.sink = McapSink(path, *self.args)
        self.first_ns: int | None = None
        self.run_meta: dict[str, str] | None = None
        self.total: dict[str, int] = {}

    def _due(self, log_time: int) -> bool:
        if self.max_bytes is not None and self.sink.fh.tell() >= self.max_bytes:
            return True
        return (self.max_duration_ns is not None and self.first_ns is not None
                and log_time - self.first_ns >= self.max_duration_ns)

    def write(self, topic: str, data: bytes, log_time: int, publish_time: int) -> None:
        if topic == "frame/image" and self.sink.counts.get("frame/image") and self._due(log_time):
            self.close()
            self.part += 1
            self.paths.append(split_path(self.path, self.part))
            self.sink = McapSink(self.paths[-1], *self.args)
            self.first_ns = None
            if self.run_meta is not None:
                self.sink.metadata("run", self.run_meta)
            log.info("recording split: now %s", self.paths[-1])
        if self.first_ns is None:
            self.first_ns = log_time
        self.sink.write(topic, data, log_time, publish_time)
        self.total[topic] = self.total.get(topic, 0) + 1

    def metadata(self, name: str, data: dict[str, str]) -> None:
        if name == "run":
            self.run_meta = dict(data)
        self.sink.metadata(name, data)

    def close(self) -> None:
        """Close the current file with its own counts."""
        self.sink.metadata("recorder", {"messages": sum(self.sink.counts.values()),
                                        **{f"count:{k}": v for k, v in self.sink.counts.items()}})
        self.sink.close()

    def __getattr__(self, name):  # flush, abort, flushed, flushed_messages: the current file's
        return getattr(self.sink, name)
