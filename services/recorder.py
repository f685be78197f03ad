"""Recorder service: the bus shell around the MCAP writer (:mod:`common.record.writer`).

Subscribes to ``polartrack/<stream>/**`` and keeps the keys the pipeline's graph marks recorded
(:mod:`common.msgs.topics`), from the run's own senders, each validated first: a channel per
topic, protobuf-encoded with its schema, log time = the frame's capture time (from the message
attachment), publish time = when it was received, written in log-time order
(:mod:`common.record.order`). It draws the track for Foxglove (``track/annotations``). The run
configuration is written as MCAP metadata. Chunks are LZ4-compressed by default (the launcher
asks for none on the synthetic scene, whose noisy frames LZ4 cannot shrink), flushed at least
once a second, so a recorder killed with SIGKILL leaves a file readable up to its last flush.
Run: ``python -m services.recorder --help``.
"""

from __future__ import annotations

import errno
import logging
import sys
import time
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from common.record.meta import run_metadata
from services import options
from common.record.writer import SplitSink
from common.msgs import TOPICS, Estimate, FrameInfo, MultiEstimate, ParticleCloud, ServiceStatus
from common.msgs.annotations import TrackDrawing
from common.record.order import LogTimeOrder
from common.validation import FrameOrder, Invalid, check_estimate, check_frame_info, check_image_size, check_status, decode, max_bytes
from services.bus import (BusConfig, Counters, Inbox, ServiceShell, Stopper, attachment_ns, attachment_sender, ns_attachment, payload_bytes)
from services.shm_populate import SegmentPopulator

log = logging.getLogger("polartrack.recorder")


class RecorderSettings(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", use_attribute_docstrings=True)

    out: str
    """MCAP file to write"""
    compression: Literal["lz4", "zstd", "none"] = "lz4"
    """chunk compression: lz4 (fast), zstd (smaller, more CPU) or none"""
    chunk_size: int = Field(256 << 10, ge=1 << 16)
    """bytes per chunk (a chunk is the unit lost on SIGKILL); a frame larger than this closes its chunk
    at once"""
    image_every_s: float = Field(0.0, ge=0)
    """keep at most one frame image per this many seconds of capture time (0: every image; the others
    counted as dropped): a long soak's recording of every 1280x720 frame would be 8 GB a minute"""
    simulate_disk_bytes: int | None = Field(None, ge=0)
    """testing: the disk holds this many bytes of the file, and writes beyond raise ENOSPC as a full
    disk would"""
    reorder_s: float = Field(0.25, ge=0)
    """messages are held this long in log (capture) time and written sorted by it (a frame's estimate
    arrives after the next frame's image)"""
    max_size_mb: float | None = Field(None, gt=0)
    """split the recording into files of about this many MB (NAME.split1.mcap, NAME.split2.mcap, ...
    after NAME.mcap), each closed and readable alone; a split falls before a frame image"""
    max_duration_s: float | None = Field(None, gt=0)
    """split the recording every this many seconds of log (capture) time, before a frame image"""


class DiskFull(Exception):
    """The recording's disk is full (ENOSPC): the recorder stops, keeping the file as of its last flush."""


EXIT_DISK_FULL = 3
"""The recorder's exit status on a full disk (the launcher ends the run: a restart would not help)."""


def on_disk(operation, what: str, path: str, full: list[str]) -> None:
    """Run a file ``operation``; a full disk (ENOSPC) is noted in ``full``, any other error raised."""
    try:
        operation()
    except OSError as exc:
        if exc.errno != errno.ENOSPC:
            raise
        full.append(f"disk full (ENOSPC) {what} {path}")


def image_index(data: bytes) -> int:
    """The frame index of a ``frame/image`` payload, its geometry checked (the pixels not copied); Invalid."""
    from common.msgs.image_wire import decode_frame

    try:
        index, msg, image = decode_frame(data, pixels=False)  # a compressed one is not decoded here
    except Exception as exc:  # noqa: BLE001 - protobuf and the wire reader raise several types
        raise Invalid("undecodable", f"not a frame image: {type(exc).__name__}") from None
    if image is not None:
        check_image_size(image.shape[1], image.shape[0])
    return index


def declared(topic: str, services) -> bool:
    """A topic of the run: the message topics, and ``status/<service>`` of the run's services
    (any service when the run's ids are not known)."""
    if topic in TOPICS:
        return True
    if topic.startswith("status/"):
        name = topic[len("status/"):]
        return (name in services) if services else ("/" not in name and 0 < len(name) <= 32)
    return False


def serve(bus: BusConfig, cfg: RecorderSettings, stopper: Stopper) -> Counters:
    """Records the run's declared topics from the run's own senders (others are counted per key
    and reason and dropped); every message but the frame images is decoded and checked first.
    On a full disk (ENOSPC) it stops: the file is cut back to its last flush and
    :class:`DiskFull` is raised."""
    shell = ServiceShell(bus, "recorder", log)
    c, guard = shell.counters, shell.guard
    inbox = Inbox()
    sink = SplitSink(cfg.out, cfg.compression, cfg.chunk_size, cfg.simulate_disk_bytes,
                     None if cfg.max_size_mb is None else int(cfg.max_size_mb * 1e6),
                     None if cfg.max_duration_s is None else int(cfg.max_duration_s * 1e9))
    prefix = bus.key("")
    services = set(bus.ids)
    info_order, image_order = FrameOrder(), FrameOrder()
    order = LogTimeOrder(int(cfg.reorder_s * 1e9))
    full: list[str] = []
    with shell:
        shell.subscribe("**", inbox.callback("all"))
        pub_drawing = shell.publisher("track/annotations", remote_only=True)
        status = shell.alive()
        log.info("recording %s** to %s", prefix, cfg.out)

        def valid(topic: str, data: bytes, sender: str) -> bool:
            if topic.startswith("health/"):
                return False  # the services' reports to the launcher, not part of the run
            if not declared(topic, services):
                guard.reject("(undeclared)" if len(topic) > 64 else topic, "undeclared_topic")
                return False
            try:
                guard.senders.check(topic, sender)
                if topic == "frame/image":
                    if len(data) > max_bytes(topic):
                        raise Invalid("too_large", f"{len(data)} bytes")
                    index = image_index(data)  # no copy of the pixels
                    image_order.check(index)
                    image_order.accept(index)
                elif topic == "frame/info":
                    check_frame_info(decode(FrameInfo, data, topic), info_order)
                elif topic == "track/estimate":  # finite, about a frame recorded (or just about to be:
                    # an estimate may overtake its frame's info on the way here)
                    check_estimate(decode(Estimate, data, topic), (info_order.index or 0) + 64)
                elif topic.startswith("status/"):
                    check_status(decode(ServiceStatus, data, topic), topic)
                else:
                    decode(TOPICS[topic], data, topic)
            except Invalid as exc:
                guard.reject(topic, exc)
                return False
            return True

        drawing = TrackDrawing()

        def draw(topic: str, data: bytes, log_time: int) -> list[tuple[int, bytes]]:
            """The Foxglove annotations this (valid) message completes (common.msgs.annotations)."""
            try:
                if topic == "frame/info":
                    return drawing.info(FrameInfo.FromString(data))
                if topic == "track/estimate":
                    return drawing.estimate(Estimate.FromString(data), log_time)
                if topic == "track/particles":
                    return drawing.cloud(ParticleCloud.FromString(data))
                if topic == "track/multi_estimate":
                    return drawing.multi(MultiEstimate.FromString(data), log_time)
            except Exception as exc:  # noqa: BLE001 - a drawing never stops the recording
                guard.log.warning("drawing", f"cannot draw {topic}: {type(exc).__name__}: {exc}")
            return []

        def write_sorted(items) -> None:
            """Into the file, in log-time order (:class:`common.record.order.LogTimeOrder`)."""
            def write_all() -> None:
                for topic, data, log_time, now in items:
                    if not full:
                        sink.write(topic, data, log_time, now)

            on_disk(write_all, "writing", cfg.out, full)

        def write_one(sample) -> str:
            topic = bus.suffix(str(sample.key_expr))
            data = payload_bytes(sample)
            c.add("received")
            if full or not valid(topic, data, attachment_sender(sample)):
                return ""
            now = time.time_ns()
            log_time = attachment_ns(sample)
            log_time = log_time if log_time is not None else now
            if topic.startswith("status/") and order.newest is not None:
                # a service's periodic report, stamped by its own clock: recorded at the run's
                # time base (the newest capture time seen), where it belongs among the frames
                log_time = order.newest
            write_sorted(order.push(log_time, (topic, data, log_time, now)))
            for t, ann in draw(topic, data, log_time):
                pub_drawing.put(ann, attachment=ns_attachment(t))
                write_sorted(order.push(t, ("track/annotations", ann, t, now)))
            if full:
                return ""
            if topic == "run/config":
                try:
                    sink.metadata("run", run_metadata(data))
                except Exception as exc:  # noqa: BLE001
                    guard.reject(topic, "bad_run_config", str(exc)[:200])
            return topic

        if cfg.image_every_s > 0:
            every_ns, last_image = int(cfg.image_every_s * 1e9), [None]
            record = write_one

            def write_one(sample) -> str:  # noqa: F811 - the same, frame images thinned
                if str(sample.key_expr).endswith("/frame/image"):
                    ns = attachment_ns(sample)
                    if ns is not None and last_image[0] is not None and 0 <= ns - last_image[0] < every_ns:
                        c.add("dropped")  # thinned, not lost: counted with the drops
                        return ""
                    last_image[0] = ns
                return record(sample)

        segments = SegmentPopulator()
        while not stopper.stopped and not full:
            if inbox.wait(0.2):
                images = False
                while (s := inbox.pop("all")) is not None and not full:
                    images |= write_one(s) == "frame/image"
                if images:
                    segments.populate()  # the frames' shared memory, mapped with the first frame
            if status.tick():  # and the file flushed as often
                on_disk(sink.flush, "flushing", cfg.out, full)
        if not full:
            # a short grace period for messages in flight, then close the file properly
            deadline = time.monotonic() + 0.3
            while time.monotonic() < deadline and not full:
                while (s := inbox.pop("all")) is not None and not full:
                    write_one(s)
                time.sleep(0.02)
        for t, ann in drawing.flush():
            write_sorted(order.push(t, ("track/annotations", ann, t, time.time_ns())))
        write_sorted(order.drain())
        if order.late:
            log.info("%d messages arrived more than %.2f s of log time late (written out of order)",
                     order.late, cfg.reorder_s)
        if full:
            c.add("errors")
        status.final()
    if not full:
        on_disk(sink.close, "closing", cfg.out, full)
    if full:
        sink.abort()
        raise DiskFull(f"{full[0]}: stopped; the file keeps its first {sink.flushed_messages} messages "
                       f"({sink.flushed} bytes, every whole record that reached the disk)")
    log.info("wrote %d messages to %s", sum(sink.total.values()), ", ".join(sink.paths))
    return c


def main(argv: list[str] | None = None) -> int:
    bus, cfg, _ = options.start("recorder", __doc__, RecorderSettings, argv)
    try:
        serve(bus, cfg, Stopper())
    except DiskFull as exc:
        log.error("%s", exc)
        print(f"recorder: error: {exc}", file=sys.stderr, flush=True)
        return EXIT_DISK_FULL
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
