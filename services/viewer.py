"""Viewer service: logs a run on the bus to a Rerun recording (.rrd), optionally to a live viewer.

Subscribes to the frame images and infos, estimates, particle clouds, template, run config and
service statuses of ``polartrack/<stream>/...`` (bounded channels: the Zenoh callbacks do no
work; images in a ring of the newest eight, so a viewer short of CPU logs fewer images and never
slows the pipeline), and logs them from its main thread with :class:`common.record.rerun.RunLogger`,
frame images at most ``max_image_hz`` per second of capture time (decoding and JPEG-encoding
every 1280x720 frame at 30 fps was most of the viewer's CPU; the rest is logged for every
frame, and ``polartrack view`` converts a recording with every image). Stops on SIGINT/SIGTERM, or once an end-of-stream frame info has arrived and the bus has been quiet for
``quiet_s``; then flushes the file and exits 0. Malformed messages are counted and skipped.
Run: ``python -m services.viewer --help``.
"""

from __future__ import annotations

import logging
import time

import zenoh
from pydantic import BaseModel, ConfigDict, Field, field_validator

from services import options
from common.msgs import FrameInfo
from common.record import split_path
from common.validation import FrameOrder, Invalid, check_frame_info, decode
from services.bus import (BusConfig, ServiceShell, Stopper, attachment_ns, attachment_sender, ns_attachment, payload_bytes)

log = logging.getLogger("polartrack.viewer")

# topic -> (FIFO capacity, messages taken per pass). Infos first: they carry the frame times.
SUBSCRIPTIONS = {
    "frame/info": (1024, 256),
    "frame/image": (8, 2),
    "track/estimate": (1024, 256),
    "track/multi_estimate": (1024, 256),
    "track/particles": (64, 16),
    "template": (16, 16),
    "run/config": (16, 16),
    "status/*": (256, 64),
}


RINGS = ("frame/image", "track/particles")
"""The bulky streams: kept in rings that drop the oldest rather than ever fill."""


def handler(topic: str, capacity: int):
    """A bounded channel for a subscription. Frame images and particle clouds go to rings that
    drop the oldest: a viewer short of CPU (it runs at a lower priority) logs the newest ones
    and never blocks the bus (a full FIFO channel blocks Zenoh's delivery, and with it, through
    the router, the publishers). The small messages (infos, estimates) keep FIFOs deep enough
    for half a minute of frames."""
    if topic in RINGS:
        return zenoh.handlers.RingChannel(capacity)
    return zenoh.handlers.FifoChannel(capacity)


class ViewerSettings(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", use_attribute_docstrings=True)

    out: str
    """Rerun recording (.rrd) to write"""
    spawn: bool = False
    """also open a live Rerun viewer (when a display is available)"""
    rerun_connect: str | None = None
    """also stream to a running Rerun viewer or server at this gRPC URL, e.g.
    rerun+http://127.0.0.1:9876/proxy"""
    rerun_serve_port: int | None = Field(None, ge=1, le=65535)
    """also host a Rerun gRPC server on loopback at this port; viewers connect with rerun --connect
    rerun+http://127.0.0.1:PORT/proxy"""
    jpeg_quality: int = Field(85, ge=1, le=100)
    """JPEG quality of the logged frames"""
    track_length: int = Field(300, ge=2, le=100_000)
    """estimates kept in the drawn track"""
    quiet_s: float = Field(1.0, gt=0, le=600)
    """after end of stream, stop after this long without messages"""
    rotate_frames: int = Field(3000, ge=0)
    """a file-only viewer goes on in a new .rrd part (NAME.split1.rrd, ...; one recording: open the
    parts together) every this many frames (0: never), which frees what Rerun holds for the run so
    far"""
    max_image_hz: float = Field(10.0, ge=0)
    """frame images logged per second of capture time at most (0: every image); the overlays and plots
    are logged for every frame"""

    @field_validator("out")
    @classmethod
    def _rrd(cls, v: str) -> str:
        if not v.endswith(".rrd"):
            raise ValueError("must be a .rrd file name")
        return v


def serve(bus: BusConfig, cfg: ViewerSettings, stopper: Stopper, nice: int = 0) -> dict:
    """``nice``: lower the priority of this thread and of Rerun's threads, but not of Zenoh's, which
    the session starts first. Zenoh's threads only move samples into the bounded channels; niced
    with the rest, they drained the socket late whenever the machine was busy, the router's queue
    to the viewer filled, and the router, blocking on it, held up every other service's
    messages behind it (the detector got frames 100-170 ms late at the start of a run, and the
    tracker then skipped 40 frames)."""
    from common.record.rerun import RunLogger, display_available

    shell = ServiceShell(bus, "viewer", log)
    c, guard = shell.counters, shell.guard
    info_order = FrameOrder()
    spawn = cfg.spawn and display_available()
    if cfg.spawn and not spawn:
        log.warning("--spawn: no display available; writing %s only", cfg.out)
    shell.open()  # before the file: a bus that cannot be joined leaves no empty .rrd
    options.lower_priority(nice)  # after Zenoh's threads started, before Rerun's
    logger = RunLogger.to_file(cfg.out, spawn=spawn, connect=cfg.rerun_connect, serve_port=cfg.rerun_serve_port,
                               jpeg_quality=cfg.jpeg_quality, track_length=cfg.track_length)
    if cfg.rerun_serve_port is not None:
        log.info("serving the run to Rerun viewers: rerun --connect rerun+http://127.0.0.1:%d/proxy",
                 cfg.rerun_serve_port)
    eos_at: float | None = None
    rotate = cfg.rotate_frames > 0 and not (spawn or cfg.rerun_connect or cfg.rerun_serve_port)
    try:
        with shell:
            subs = [(topic, burst, shell.subscribe(topic, handler(topic, cap)))
                    for topic, (cap, burst) in SUBSCRIPTIONS.items()]
            status = shell.alive()
            log.info("logging polartrack/%s/** to %s", bus.stream, cfg.out)
            last_msg = time.monotonic()
            last_ns = None
            last_image_ns = None
            image_interval_ns = int(1e9 / cfg.max_image_hz) if cfg.max_image_hz > 0 else 0
            while not stopper.stopped:
                got = 0
                for sub_topic, burst, sub in subs:
                    for _ in range(burst):
                        sample = sub.try_recv()
                        if sample is None:
                            break
                        got += sub_topic != "status/*"  # the services' periodic statuses are not activity
                        c.add("received")
                        topic = bus.suffix(str(sample.key_expr))
                        data = payload_bytes(sample)
                        if not guard.accept(topic, attachment_sender(sample), len(data)):
                            continue  # another sender than the run's service on this key, or too large
                        if topic == "frame/info":
                            try:  # a forged end of stream or a replayed frame would end or confuse the run
                                check_frame_info(decode(FrameInfo, data, topic), info_order)
                            except Invalid as exc:
                                guard.reject(topic, exc)
                                continue
                        ns = attachment_ns(sample)
                        last_ns = ns if ns is not None else last_ns
                        if topic == "frame/image" and ns is not None:
                            if last_image_ns is not None and 0 <= ns - last_image_ns < image_interval_ns:
                                c.add("dropped")  # not decoded, not encoded
                                continue
                            last_image_ns = ns
                        if (rotate and topic == "frame/info" and logger.stats["infos"]
                                and logger.stats["infos"] % cfg.rotate_frames == 0):
                            part = logger.stats["infos"] // cfg.rotate_frames
                            logger.rotate(split_path(cfg.out, part))
                            log.info("Rerun recording continues in %s", split_path(cfg.out, part))
                        eos_before = logger.stats["end_of_stream"]
                        malformed_before = logger.stats["malformed"]
                        try:
                            logger.log_message(topic, data, ns)
                        except Exception as exc:  # noqa: BLE001 - nothing a message holds stops the viewer
                            guard.reject(topic, "not_logged", f"{type(exc).__name__}: {exc}")
                            continue
                        if logger.stats["malformed"] != malformed_before:
                            guard.reject(topic, "malformed")
                        elif topic == "frame/image":
                            c.add("published")  # images in the .rrd (the run's summary says how many)
                        if logger.stats["end_of_stream"] != eos_before and eos_at is None:
                            eos_at = time.monotonic()
                            log.info("end of stream; stopping after %.1f s of quiet", cfg.quiet_s)
                now = time.monotonic()
                status.tick()
                if got:
                    last_msg = now
                elif eos_at is not None and now - last_msg >= cfg.quiet_s:
                    break
                else:
                    stopper.wait(0.005)
            status.final(**({"attachment": ns_attachment(last_ns)} if last_ns is not None else {}))
    finally:
        logger.close()
    stats = dict(logger.stats)
    log.info("wrote %s: %s", cfg.out, ", ".join(f"{k} {v}" for k, v in stats.items() if v))
    return stats


def main(argv: list[str] | None = None) -> int:
    bus, cfg, args = options.start("viewer", __doc__, ViewerSettings, argv, nice_later=True)
    try:
        bus.zenoh_config()
    except zenoh.ZError as exc:
        options.fail("viewer", f"bus: {str(exc).split(' at /')[0]}")
    try:
        serve(bus, cfg, Stopper(), nice=args.nice)
        # done and written: a stop request now (the launcher's, as the viewer exits by itself
        # after the end of stream) must not turn a clean exit into death by signal
        import signal

        for sig in (signal.SIGTERM, signal.SIGHUP, signal.SIGINT):
            signal.signal(sig, signal.SIG_IGN)
    except zenoh.ZError as exc:
        log.error("cannot join the bus: %s", str(exc).split(" at /")[0])
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
