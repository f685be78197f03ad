"""Recorder service: writes every message on the bus to MCAP.

Subscribes to ``polartrack/<stream>/**`` and writes each message on a channel named by its topic
(``frame/image``, ``track/estimate``, ...), protobuf-encoded with its schema, log time = the
frame's capture time (from the message attachment), publish time = when it was received.
Messages of unknown topics are kept too (schemaless). The run configuration is written as MCAP
metadata. Chunks are LZ4-compressed (zstd is too slow for raw video here; the launcher asks for
none on the synthetic scene, whose noisy frames LZ4 cannot shrink) and written around the page cache (:mod:`services.direct_file`), flushed at least once a second, so a
recorder killed with SIGKILL leaves a file readable up to its last flush.
Run: ``python -m services.recorder --help``.
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path
from typing import Literal

from google.protobuf.json_format import MessageToDict
from mcap.writer import CompressionType, Writer
from mcap_protobuf.schema import build_file_descriptor_set
from pydantic import BaseModel, ConfigDict, Field

from common.msgs import RunConfig, message_class
from services import options
from services.direct_file import DirectFile
from services.bus import BusConfig, Counters, Inbox, StatusTicker, Stopper, attachment_ns, open_session, payload_bytes, publisher
from services.shm_populate import SegmentPopulator

log = logging.getLogger("polartrack.recorder")


class RecorderSettings(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    out: str = Field(description="MCAP file to write")
    compression: Literal["lz4", "none"] = Field("lz4", description="chunk compression")
    chunk_size: int = Field(256 << 10, ge=1 << 16, description="bytes per chunk (a chunk is the unit lost on SIGKILL); "
                            "a frame larger than this closes its chunk at once")


class McapSink:
    """MCAP writing with one schema per message class and one channel per topic."""

    def __init__(self, path: str, compression: str = "lz4", chunk_size: int = 256 << 10):
        """``chunk_size``: small chunks are much cheaper for large frames. The writer collects a
        chunk in a growing buffer, so a 2.7 MB frame landing in a 4 MiB chunk behind other
        messages is copied again as the buffer grows: 11.9 ms of CPU a frame against 1.9 ms with
        256 KiB chunks (1280x720 RGB frames plus a frame's queries, replies and estimates)."""
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        self.fh = DirectFile(path)  # raw video around the page cache (see services.direct_file)
        comp = CompressionType.LZ4 if compression == "lz4" else CompressionType.NONE
        self.writer = Writer(self.fh, chunk_size=chunk_size, compression=comp)
        self.writer.start(profile="protobuf", library="polartrack")
        self.schemas: dict[str, int] = {}
        self.channels: dict[str, int] = {}
        self.counts: dict[str, int] = {}
        self.sequence = 0
        self.metadata_written: set[str] = set()

    def channel(self, topic: str) -> int:
        ch = self.channels.get(topic)
        if ch is not None:
            return ch
        cls = message_class(topic)
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
        self.writer.add_message(self.channel(topic), log_time=log_time, data=data, publish_time=publish_time,
                                sequence=self.sequence)
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def metadata(self, name: str, data: dict[str, str]) -> None:
        if name not in self.metadata_written:
            self.writer.add_metadata(name, {k: str(v) for k, v in data.items()})
            self.metadata_written.add(name)

    def flush(self) -> None:
        self.fh.flush()

    def close(self) -> None:
        self.writer.finish()
        self.fh.close()


def run_metadata(raw: bytes) -> dict[str, str]:
    cfg = RunConfig.FromString(raw)
    d = MessageToDict(cfg, preserving_proto_field_name=True, always_print_fields_with_no_presence=True)
    return {k: v if isinstance(v, str) else json.dumps(v) for k, v in d.items()}


def serve(bus: BusConfig, cfg: RecorderSettings, stopper: Stopper) -> Counters:
    c = Counters("recorder")
    inbox = Inbox()
    sink = McapSink(cfg.out, cfg.compression, cfg.chunk_size)
    prefix = bus.key("")
    with open_session(bus) as session:
        sub = session.declare_subscriber(bus.key("**"), inbox.callback("all"))
        pub_status = publisher(session, bus.key("status/recorder"))
        token = session.liveliness().declare_token(bus.key("alive/recorder"))
        log.info("recording %s** to %s", prefix, cfg.out)
        status = StatusTicker(pub_status, c)

        def write_one(sample) -> str:
            key = str(sample.key_expr)
            topic = key[len(prefix):] if key.startswith(prefix) else key
            data = payload_bytes(sample)
            now = time.time_ns()
            log_time = attachment_ns(sample)
            sink.write(topic, data, log_time if log_time is not None else now, now)
            c.add("received")
            if topic == "run/config":
                try:
                    sink.metadata("run", run_metadata(data))
                except Exception as exc:  # noqa: BLE001
                    c.add("malformed")
                    log.warning("malformed run config: %s", exc)
            return topic

        segments = SegmentPopulator()
        while not stopper.stopped:
            if inbox.wait(0.2):
                images = False
                while (s := inbox.pop("all")) is not None:
                    images |= write_one(s) == "frame/image"
                if images:
                    segments.populate()  # the frames' shared memory, mapped with the first frame
            if status.tick():  # and the file flushed as often
                sink.flush()
        # a short grace period for messages in flight, then close the file properly
        deadline = time.monotonic() + 0.3
        while time.monotonic() < deadline:
            while (s := inbox.pop("all")) is not None:
                write_one(s)
            time.sleep(0.02)
        pub_status.put(c.status(final=True).SerializeToString())
        token.undeclare()
        sub.undeclare()
    sink.metadata("recorder", {"messages": sum(sink.counts.values()), **{f"count:{k}": v for k, v in sink.counts.items()}})
    sink.close()
    log.info("wrote %d messages to %s", sum(sink.counts.values()), cfg.out)
    return c


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m services.recorder", description=__doc__)
    options.add_bus_arguments(p)
    p.add_argument("--out", help="MCAP file to write")
    p.add_argument("--compression", choices=["lz4", "none"], help="chunk compression")
    args = p.parse_args(argv)
    bus, cfg = options.load("recorder", args, RecorderSettings, ["out", "compression"])
    from services.bus import setup_logging

    setup_logging("recorder", args.log_level)
    serve(bus, cfg, Stopper())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
