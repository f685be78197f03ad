"""Ingest service: publishes the frames of a source on the bus.

Each frame goes out as a foxglove.RawImage (``frame/image``) and a FrameInfo (``frame/info``:
index, capture time, homography when known, ground truth when known), both carrying the
capture time as their attachment. Pacing: ``consumer`` (a file source paced by the tracker:
at most ``window`` frames ahead of the last estimate, so nothing is dropped), ``realtime`` (the
source rate; a slow tracker skips stale frames) or ``max`` (as fast as possible).
Run: ``python -m services.ingest --help``.
"""

from __future__ import annotations

import logging
import signal
import threading
import time
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from common.msgs import Estimate, FrameInfo, MultiEstimate
from common.msgs.convert import frame_info_msg
from common.msgs.image_wire import encode_compressed, encode_image
from common.sources import PrerenderedSource, SourceError, open_source
from common.sources.published import parse_image_format, published_image
from services import options
from common.validation import check_estimate, check_multi_estimate
from services.bus import (BusConfig, Counters, Inbox, Presence, ServiceShell, Stopper, attachment_sender,
                          ns_attachment, payload_bytes, wait_for_alive)
from services.shm_populate import SegmentPopulator

log = logging.getLogger("polartrack.ingest")


class IngestSettings(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", use_attribute_docstrings=True)

    source: str
    """video file, UAV123 folder, camera:N or synthetic[:SEED]"""
    frames: int | None = Field(None, ge=1)
    """only the first N frames"""
    pace: Literal["consumer", "realtime", "max"] = "consumer"
    """how fast frames go out"""
    window: int = Field(2, ge=1)
    """consumer pacing: frames in flight ahead of the last estimate"""
    max_late_frames: int = Field(2, ge=0)
    """real time (file sources): a frame up to this many frame periods late still goes out, stamped with
    the time it was due, as a camera's buffered frame would; later ones are skipped and counted as
    dropped"""
    consumer_timeout_s: float = Field(10.0, gt=0)
    """consumer pacing: give up waiting after this"""
    detector_wait_s: float = Field(60.0, ge=0)
    """consumer pacing: while a detector that was on the bus is gone (killed, being restarted), hold
    the next frame up to this long for one to be back (seconds): a file loses nothing by waiting,
    and a frame sent meanwhile could only be predicted. 0: never hold"""
    wait_for: list[str] = Field(default_factory=list)
    """services to wait for (liveliness) first"""
    wait_timeout_s: float = Field(60.0, gt=0)
    """how long to wait for the wait_for services (seconds); past it an error is logged and counted and
    the frames go out anyway"""
    start_ns: int | None = None
    """time base: capture_ns of frame 0 (default: now)"""
    run_config: str | None = None
    """RunConfig (JSON) to publish before the first frame"""
    image_format: str = "auto"
    """frames on the bus and in the recording: auto (a JPEG or PNG file's own bytes, else raw for
    rendered scenes and jpeg:90 for video and cameras), raw, png (lossless), jpeg or jpeg:QUALITY
    (lossy: every consumer decodes the published bytes); see common.sources.published"""
    pause_before: int | None = Field(None, ge=0)
    """hold the source before this frame (index) as SIGUSR1 does, until SIGUSR2 lets it go on: a
    breakpoint at a known frame, to look at the run there or to inject a fault at a frame the source
    stops at, not at one a busy launcher hears of late"""
    prerender: bool = False
    """read or render every frame before the first is published (seekable sources; memory: all frames),
    so that the source costs no more than reading a recorded video while the run goes on"""

    @field_validator("image_format")
    @classmethod
    def _image_format(cls, v: str) -> str:
        parse_image_format(v)
        return v


class Pause:
    """SIGUSR1 holds the source before its next frame, SIGUSR2 lets it go on (as a player's
    pause and resume; :meth:`services.launcher.Pipeline.pause_source` sends them). A held source
    keeps its Zenoh session running: SIGSTOP would also stop the threads that keep its
    shared-memory frames valid, and a frame still on its way to a slow subscriber could then be
    lost (seen once in a hundred runs of the fuzz test: one frame missing from the recording).

    The breakpoint (``pause_before``) holds until a SIGUSR2 has come at all: one sent before the
    source reached it counts (a launcher that heard of the frame before it can resume the source
    before ingest has stopped there)."""

    def __init__(self) -> None:
        self.held = threading.Event()
        self.resumes = 0
        """SIGUSR2s so far."""
        for sig, handler in ((signal.SIGUSR1, lambda *_: self.held.set()), (signal.SIGUSR2, self._resume)):
            try:
                signal.signal(sig, handler)
            except ValueError:  # not the main thread (tests)
                pass

    def _resume(self, *_) -> None:
        self.resumes += 1
        self.held.clear()

    def breakpoint(self, stopper: "Stopper") -> float:
        """Until a SIGUSR2 has come (at any time so far) or the run is stopped. Returns the seconds waited."""
        return _wait_while(lambda: self.resumes == 0, stopper)

    def wait(self, stopper: "Stopper") -> float:
        """While held (and not stopped): wait. Returns the seconds waited."""
        return _wait_while(self.held.is_set, stopper)


def _wait_while(busy, stopper: "Stopper") -> float:
    """While ``busy()`` and the run is not stopped: wait. Returns the seconds waited (0.0 when not busy)."""
    if not busy():
        return 0.0
    t0 = time.monotonic()
    while busy() and not stopper.stopped:
        stopper.wait(0.01)
    return time.monotonic() - t0


class Clock:
    """The real-time clock of a file source: ``wall0`` is the monotonic time of source time 0."""

    def __init__(self) -> None:
        self.wall0: float | None = None

    def start(self, frame_time: float) -> None:
        """Frame time ``frame_time`` is due now."""
        self.wall0 = time.monotonic() - frame_time

    def reset(self) -> None:
        """Not started: the next frame read is due when it is read."""
        self.wall0 = None

    def lateness_s(self, frame_time: float) -> float:
        """How long ago frame time ``frame_time`` was due (0 when not yet, or not started)."""
        return 0.0 if self.wall0 is None else max(0.0, time.monotonic() - (self.wall0 + frame_time))


def frames_to_publish(source, pace: str, counters: Counters, clock: Clock | None = None, max_late: int = 0):
    """Frames in source order; in real time, a source that can be read at any frame skips
    straight to the frame due now when it falls more than ``max_late`` frames behind (counted
    as dropped), as a camera would once its buffer is full, instead of reading frames it will
    not publish. The clock starts at the first frame (or when the caller restarts ``clock``;
    after ``clock.reset()``, at the next frame)."""
    if pace != "realtime" or source.live or not hasattr(source, "frame"):
        yield from source
        return
    n = len(source)
    i = 0
    clock = clock if clock is not None else Clock()
    while i < n:
        wall0 = clock.wall0
        if wall0 is not None:
            due = int((time.monotonic() - wall0) * source.fps)
            if due > i + max_late:
                counters.add("dropped", min(due, n) - i)
                i = due
                if i >= n:
                    break
        frame = source.frame(i)
        if clock.wall0 is None:
            clock.start(frame.time)
        yield frame
        i += 1


def serve(bus: BusConfig, cfg: IngestSettings, stopper: Stopper) -> Counters:
    from google.protobuf.json_format import Parse

    from common.msgs import RunConfig

    pause = Pause()  # before anything: a pause signal never finds the default action (exit)
    shell = ServiceShell(bus, "ingest", log)
    c = shell.counters
    source = open_source(cfg.source, n_frames=cfg.frames)
    if cfg.prerender:
        t0 = time.monotonic()
        source = PrerenderedSource(source)
        log.info("prerendered %d frames in %.1f s", len(source), time.monotonic() - t0)
    total = 0 if source.live else len(source)
    inbox = Inbox()
    with shell:
        session, guard = shell.session, shell.guard
        pub_image = shell.publisher("frame/image")
        pub_info = shell.publisher("frame/info")
        sub = shell.subscribe("track/estimate", inbox.callback("estimate", maxlen=4096))
        sub_multi = shell.subscribe("track/multi_estimate", inbox.callback("multi", maxlen=4096))
        status = shell.alive()
        if cfg.wait_for and not wait_for_alive(session, bus, cfg.wait_for, cfg.wait_timeout_s, stopper):
            log.error("services %s not up after %.0f s", cfg.wait_for, cfg.wait_timeout_s)
            c.add("errors")
        start_ns = cfg.start_ns if cfg.start_ns is not None else time.time_ns()
        if cfg.run_config:
            rc = Parse(cfg.run_config, RunConfig())
            rc.start_ns = start_ns
            shell.publisher("run/config").put(rc.SerializeToString(), attachment=ns_attachment(start_ns))
        done = -1  # highest frame index estimated
        clock = Clock()  # the real-time clock starts at the first frame
        last_ns = start_ns
        index = -1
        last_published = -1  # the newest frame out: no estimate can be about a later one
        first = True
        segments = SegmentPopulator(write=True)
        listening = True

        def stop_listening() -> None:
            """Real-time and max pacing read no estimate after the first frame: the subscriptions
            go (their boxes held the last 4,096 estimates, never read: ingest grew ~30 MB in a
            soak), and what they held with them."""
            nonlocal listening
            if listening:
                shell.undeclare(sub)
                shell.undeclare(sub_multi)
                for name in list(inbox.boxes):
                    inbox.close(name)  # a sample already on Zenoh's threads is not kept either
                listening = False

        presence = Presence(session, bus) if cfg.pace == "consumer" and cfg.detector_wait_s > 0 else None
        detector_seen = False

        def wait_for_detector(index: int) -> None:
            """Hold frame ``index`` while a detector that was on the bus is gone (consumer pacing),
            up to ``detector_wait_s``: with none, the tracker could only predict it, and a source
            that went on would send every remaining frame in milliseconds, each a prediction."""
            nonlocal detector_seen
            if presence is None:
                return
            if "detector" in presence:
                detector_seen = True
                return
            if not detector_seen:
                return  # none yet (a run without one, or not up): pacing by the estimates alone
            log.warning("frame %d: the detector has left the bus: held until one is back (at most %.0f s)",
                        index, cfg.detector_wait_s)
            t0 = time.monotonic()
            if presence.wait("detector", cfg.detector_wait_s, stopper):
                log.info("frame %d: a detector is back after %.1f s", index, time.monotonic() - t0)
            else:
                log.error("no detector after %.0f s: the frames go on without one", cfg.detector_wait_s)
                c.add("errors")
                detector_seen = False  # not held again until one has been back

        def wait_for_estimate(upto: int) -> None:
            """Until frame ``upto`` or a later one is estimated (consumer pacing, and the first
            frame of a real-time run), or ``consumer_timeout_s``."""
            nonlocal done
            deadline = time.monotonic() + cfg.consumer_timeout_s
            while done < upto and not stopper.stopped:
                inbox.wait(0.05)
                for box, key, cls, check in (("estimate", "track/estimate", Estimate, check_estimate),
                                             ("multi", "track/multi_estimate", MultiEstimate, check_multi_estimate)):
                    while (s := inbox.pop(box)) is not None:
                        # pacing only from the run's tracker, about a frame already published (an
                        # estimate of frame 1e9 had let every frame out unobserved)
                        e = guard.decode(key, cls, payload_bytes(s), attachment_sender(s), check, last_published)
                        if e is not None:
                            done = max(done, int(e.frame_index))
                if time.monotonic() > deadline:
                    log.warning("no estimate for frame %d after %.0f s: going on", done + 1, cfg.consumer_timeout_s)
                    done = upto
                    c.add("errors")

        for frame in frames_to_publish(source, cfg.pace, c, clock, cfg.max_late_frames):
            if stopper.stopped:
                break
            held = 0.0
            if frame.index == cfg.pause_before:
                log.info("frame %d: paused before it (pause_before) until resumed", frame.index)
                held = pause.breakpoint(stopper)
            held += pause.wait(stopper)
            if held and clock.wall0 is not None:
                clock.wall0 += held  # real time resumes where it was held
            if stopper.stopped:
                break
            index = frame.index
            if cfg.pace == "consumer":
                wait_for_estimate(frame.index - cfg.window)
                wait_for_detector(frame.index)
            elif cfg.pace == "realtime":
                if clock.wall0 is None:
                    clock.start(frame.time)
                delay = clock.wall0 + frame.time - time.monotonic()
                if delay > 0:
                    stopper.wait(delay)
            if source.live:
                capture_ns = time.time_ns()
            elif cfg.pace == "realtime":
                # a late frame (within max_late_frames) is stamped with the time it was due: its
                # latency counts from then
                capture_ns = time.time_ns() - int(clock.lateness_s(frame.time) * 1e9)
            else:
                capture_ns = start_ns + int(round(frame.time * 1e9))
            last_ns = capture_ns
            att = ns_attachment(capture_ns)
            true_centre = source.true_centre(frame.index) if hasattr(source, "true_centre") else None
            packed = published_image(frame, cfg.image_format, source.image_format)
            pub_image.put(encode_image(frame.image, capture_ns, frame.index) if packed is None else
                          encode_compressed(packed[1], packed[0], capture_ns, frame.index), attachment=att)
            segments.populate()  # the pool, once the first frame has created it
            pub_info.put(frame_info_msg(frame, capture_ns, source.name, total, true_centre).SerializeToString(),
                         attachment=att)
            last_published = frame.index
            c.add("published")
            status.tick(attachment=att)
            if first and cfg.pace == "realtime" and not source.live:
                # A file source in real time starts its clock once the tracker has set up on the
                # first frame (the template, the services' first calls), as an operator marks the
                # target and then tracks: else the set-up's second would skip the first 30 frames
                # and lose a fast target. The next frame read is due when it is read (the clock
                # restarted here, not at the next frame, so that frame 1 is never counted late).
                wait_for_estimate(0)
                clock.reset()
            if cfg.pace != "consumer":
                stop_listening()
            first = False
        eos = FrameInfo(index=index + 1, end_of_stream=True, source=source.name, total_frames=total,
                        capture_ns=last_ns)
        pub_info.put(eos.SerializeToString(), attachment=ns_attachment(last_ns))
        status.final(attachment=ns_attachment(last_ns))
        log.info("published %d frames", c["published"])
        if presence is not None:
            presence.close()
        time.sleep(0.1)
    return c


def run_keys(spec, settings, path: str) -> dict:
    """Ingest's keys from the run file (``--run``): the source and how to send it, and the run
    config to publish, named after the file (deploy/run.toml: run id "run")."""
    from pathlib import Path

    from common.record.meta import run_config_json

    return {"source": spec.source, "frames": spec.frames, "pace": spec.pace, "image_format": spec.image_format,
            "run_config": run_config_json(Path(path).stem, spec.source, spec.init_box, settings, spec.pace)}


def main(argv: list[str] | None = None) -> int:
    bus, cfg, _ = options.start("ingest", __doc__, IngestSettings, argv, run=run_keys)
    try:
        serve(bus, cfg, Stopper())
    except SourceError as exc:
        options.fail("ingest", str(exc))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
