"""Starts the services as separate processes on a private loopback Zenoh network.

The launcher starts a Zenoh router (``services.router``) on a free loopback port and every
service joins it as a client (explicit endpoints, no scouting, nothing leaves 127.0.0.1): a star
that forms as soon as each process starts, whatever the start order. The frame images travel
through Zenoh shared memory (the router and the services; the launcher's own session reads only
small messages and stays out of it); when the run ends, the segment files the processes left in
/dev/shm are removed. It watches the estimates for progress, shuts everything down when the
source ends or on Ctrl-C, and leaves ``recordings/<time>-<source>.mcap`` (and ``.rrd`` with the
viewer).
"""

from __future__ import annotations

import json
import logging
import os
import secrets
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from common.evaluation import LiveErrors, LiveMultiErrors
from common.record.meta import run_config_json
from common.settings import TrackerSettings

SERVICES = ("recorder", "detector", "tracker", "viewer", "ingest")

RESTARTED = ("detector", "recorder", "viewer")
"""Services the launcher restarts when they die mid-run (a bounded number of times); a dead
router, tracker or ingest ends the run with a failure."""

END_GRACE_S = 2.0
"""How long the end of the stream may take to reach the launcher after a service that stops at the
end (the tracker, the viewer) has exited cleanly: within it, the exit is not yet a fault."""

MAX_RESTARTS = 3

EXIT_DISK_FULL = 3
"""The recorder's exit status on a full disk (services.recorder): not restarted, the run fails."""

log = logging.getLogger("polartrack.launcher")


class Interrupted(KeyboardInterrupt):
    """The launcher got SIGINT, SIGTERM or SIGHUP: every child is stopped on the way out."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def free_ports(n: int) -> list[int]:
    socks, ports = [], []
    for _ in range(n):
        s = socket.socket()
        s.bind(("127.0.0.1", 0))
        socks.append(s)
        ports.append(s.getsockname()[1])
    for s in socks:
        s.close()
    return ports


def stop_process(proc: subprocess.Popen, timeout: float = 10.0) -> int | None:
    """SIGTERM, then SIGKILL if it is still there after ``timeout`` s; its exit status."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
    return proc.returncode


def wait_for_port(port: int, proc: subprocess.Popen, timeout: float, log=lambda: "") -> None:
    """Wait until something listens on loopback ``port``; RuntimeError if ``proc`` exits first."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
            return
        except OSError:
            pass
        if proc.poll() is not None:
            raise RuntimeError(f"the router exited ({proc.returncode}): {log()[-2000:]}")
        if time.monotonic() > deadline:
            raise RuntimeError(f"nothing listens on 127.0.0.1:{port} after {timeout:.0f} s")
        time.sleep(0.05)


def client_args(hub_port: int) -> list[str]:
    """Flags joining a service to the loopback router as a client."""
    return ["--mode", "client", "--connect", f"tcp/127.0.0.1:{hub_port}"]


def router_config(hub_port: int, stream: str):
    from services.bus import BusConfig

    return BusConfig(stream=stream, mode="router", listen=[f"tcp/127.0.0.1:{hub_port}"])


@dataclass
class RunResult:
    mcap: str
    rrd: str | None
    frames: int
    estimates: int
    mean_err: float | None
    frames_lost: int | None
    fps: float
    wall_s: float
    returncodes: dict[str, int | None] = field(default_factory=dict)
    failure: str | None = None
    """Why the run failed (a service died for good, the router went away, the disk filled), or None."""
    restarts: list[dict] = field(default_factory=list)
    """Each restart: the service, its exit status, the frames seen when it died and when it was restarted."""
    rejected: dict[str, dict[str, dict[str, int]]] = field(default_factory=dict)
    rrd_images: int | None = None
    """Frame images the Rerun file holds (the viewer keeps at most ``max_image_hz`` a second)."""
    """Messages dropped, per receiving service (and ``launcher``), key and reason."""
    recordings: list[str] = field(default_factory=list)
    """The MCAP files of the run: ``mcap``, then one more per restart of the recorder."""

    @property
    def ok(self) -> bool:
        """No failure, no restart and every service's exit status 0 (or not run)."""
        return self.failure is None and not self.restarts and all(c in (0, None) for c in self.returncodes.values())

    def as_dict(self) -> dict:
        return {"mcap": self.mcap, "rrd": self.rrd, "frames": self.frames, "estimates": self.estimates,
                "mean_err": None if self.mean_err is None else round(self.mean_err, 3),
                "frames_lost": self.frames_lost, "fps": round(self.fps, 2), "wall_s": round(self.wall_s, 2),
                "returncodes": self.returncodes, "failure": self.failure, "restarts": self.restarts,
                "rejected": self.rejected, "recordings": self.recordings, "rrd_images": self.rrd_images}


NICE = {"viewer": 19}
"""Services run at a lower priority: the viewer's work is for inspection, and it drops images and
particle clouds rather than fall behind; the detector and tracker, whose work is the latency,
come first. Every frame wakes the detector, the recorder and the viewer at once; at nice 5 the
viewer (mostly Rerun's own threads) took the detector's CPU: bench --pipeline (frames rendered before the run) went
from 26.5 to 27.7-27.9 estimates/s and the latency p50 from 49-55 to 31-36 ms at nice 19."""


MALLOC_ENV = {"MALLOC_MMAP_THRESHOLD_": str(16 << 20), "MALLOC_TRIM_THRESHOLD_": str(64 << 20)}
"""glibc allocator settings for every service. By default a 2.7 MB frame buffer is a fresh mmap
that is paged in (faulted and zeroed) on first use and unmapped when freed, for every copy of
every frame: in bench --pipeline the recorder spent 40 % of a core in the kernel, the detector
and the viewer 7 % each. With buffers up to 16 MiB taken from the heap, and the heap kept, the
pages are reused: the recorder's kernel time fell to 23 %, the others' to 2-3 % (same run
otherwise). Memory stays bounded by the largest working set, as the heap is reused."""

VIEWER_ENV = {"MIMALLOC_PURGE_DELAY": "0"}
"""The viewer's Rerun (mimalloc, its own allocator) returns freed memory to the system at once
rather than after a delay: RunLogger over 4,000 synthetic frames grew 4.5 MB per 1,000 frames
with it, 9-10 without (docs/reliability.md)."""


class Pipeline:
    """The processes of one run. Use as a context manager: everything is stopped on exit."""

    def __init__(self, source: str, init_box, settings: TrackerSettings, out_dir: str | Path = "recordings",
                 frames: int | None = None, pace: str = "consumer", viewer: bool = True, stream: str | None = None,
                 name: str | None = None, log_dir: str | Path | None = None, shared_memory: bool = True,
                 prerender: bool = False, multi=None, supervise: bool = True, on_restart=None,
                 recorder_options: dict | None = None, viewer_options: dict | None = None,
                 image_format: str = "auto", ingest_options: dict | None = None):
        """``supervise``: restart a dead detector, recorder or viewer (at most ``MAX_RESTARTS``
        times each), end the run on a dead router, tracker or ingest. ``on_restart(pipeline,
        service)`` is called after each restart (fault-injection tests). ``recorder_options``:
        more keys of the recorder's settings (``services.recorder.RecorderSettings``); ``ingest_options``
        of ingest's (``services.ingest.IngestSettings``, e.g. ``pause_before``). ``prerender``: the ingest service reads or renders every frame before publishing the
        first (see :class:`common.sources.PrerenderedSource`). ``multi``: a
        :class:`common.multitarget.runner.MultiRun` (multi-target filters; ``init_box`` is then None
        and ``settings`` only the single-target defaults)."""
        self.multi = multi
        self.prerender = prerender
        self.source, self.settings = source, settings
        self.init_box = None if init_box is None else tuple(float(v) for v in init_box)
        self.frames, self.pace, self.viewer = frames, pace, viewer
        stamp = time.strftime("%Y%m%d-%H%M%S")
        safe = "".join(ch if ch.isalnum() or ch in "-_" else "-" for ch in source.strip("/").split("/")[-1])
        self.name = name or f"{stamp}-{safe}"
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.mcap = str(self.out_dir / f"{self.name}.mcap")
        self.rrd = str(self.out_dir / f"{self.name}.rrd") if viewer else None
        self.stream = stream or f"run{os.getpid()}x{int(time.time() * 1000) % 100000}"
        self.services = [s for s in SERVICES if viewer or s != "viewer"]
        self.hub_port = free_ports(1)[0]
        self.shared_memory = shared_memory
        self.session = None
        self.tmp = tempfile.TemporaryDirectory(prefix="polartrack-")
        self.log_dir = Path(log_dir) if log_dir else Path(self.tmp.name)
        self.procs: dict[str, subprocess.Popen] = {}
        self.logs: dict[str, object] = {}
        self.supervise, self.on_restart = supervise, on_restart
        self.recorder_options = dict(recorder_options or {})
        self.ingest_options = dict(ingest_options or {})
        self.image_format = image_format
        """How frames go on the bus (common.sources.published): auto, raw, png, jpeg[:Q]."""
        self.viewer_options = dict(viewer_options or {})
        if self.viewer_options.get("out"):  # the .rrd where the caller wants it
            self.rrd = str(self.viewer_options.pop("out")) if viewer else None
        self.ids = {s: secrets.token_hex(8) for s in (*SERVICES, "router")}
        """The run's sender ids: every service speaks with its own and accepts each key only from
        the run's services that speak on it (common.validation)."""
        self.ids_file = Path(self.tmp.name) / "ids.json"
        self.ids_file.write_text(json.dumps(self.ids))
        os.chmod(self.ids_file, 0o600)
        self.parts: dict[str, int] = {}
        """Restarts so far of each service (a restarted recorder or viewer writes a new file)."""
        self.recordings = [self.mcap]

    # -- processes ------------------------------------------------------------------------
    def command(self, service: str) -> list[str]:
        base = [sys.executable, "-m", f"services.{service}", "--stream", self.stream, "--ids", str(self.ids_file)]
        base += ["--shared-memory"] if self.shared_memory else []
        if service == "router":
            return base + ["--mode", "router", "--listen", f"tcp/127.0.0.1:{self.hub_port}"]
        base += client_args(self.hub_port)
        if NICE.get(service):
            base += ["--nice", str(NICE[service])]
        if service == "recorder":
            out = self.part_path(self.mcap, self.parts.get("recorder", 0))
            if self.recorder_options:
                cfg = Path(self.tmp.name) / "recorder.json"
                cfg.write_text(json.dumps(self.recorder_options))
                base += ["--config", str(cfg)]
            if "compression" not in self.recorder_options and self.incompressible():
                base += ["--compression", "none"]
            return base + ["--out", out]
        if service == "viewer":
            if self.viewer_options:
                cfg = Path(self.tmp.name) / "viewer.json"
                cfg.write_text(json.dumps(self.viewer_options))
                base += ["--config", str(cfg)]
            return base + ["--out", self.part_path(self.rrd, self.parts.get("viewer", 0))]
        if service == "tracker":
            cfg = Path(self.tmp.name) / "tracker.json"
            cfg.write_text(json.dumps({"init_box": None if self.init_box is None else list(self.init_box),
                                       "settings": self.settings.model_dump(mode="json"),
                                       "multi": None if self.multi is None else self.multi.to_json(),
                                       "skip_stale": self.pace != "consumer"}))
            return base + ["--config", str(cfg)]
        if service == "ingest":
            cfg = Path(self.tmp.name) / "ingest.json"
            run_config = run_config_json(self.name, self.source, self.init_box, self.settings, self.pace, self.multi)
            waits = [s for s in self.services if s != "ingest"]
            cfg.write_text(json.dumps({"source": self.source, "frames": self.frames, "pace": self.pace,
                                       "wait_for": waits, "run_config": run_config,
                                       "prerender": self.prerender, "image_format": self.image_format,
                                       **self.ingest_options}))
            return base + ["--config", str(cfg)]
        return base

    @staticmethod
    def part_path(path: str, part: int) -> str:
        """The file of a service's ``part``-th restart: ``NAME.partK.EXT`` (part 0: ``path``)."""
        if not part:
            return path
        p = Path(path)
        return str(p.with_name(f"{p.stem}.part{part}{p.suffix}"))

    def incompressible(self) -> bool:
        """The synthetic scene's frames carry per-pixel sensor noise: LZ4 chunks of them are 0.0%
        smaller, and compressing them was a third of the recorder's CPU in bench --pipeline.
        (Frames of real video keep LZ4: about half the size for a UAV123 frame.)"""
        return self.source.split(":", 1)[0] == "synthetic"

    def start(self, service: str) -> subprocess.Popen:
        """Start ``service`` (a previous process of it still running is stopped first: never two)."""
        if service in self.procs and self.procs[service].poll() is None:
            self.stop(service)
        log = open(self.log_dir / f"{service}.log", "ab")
        self.logs[service] = log
        env = dict(os.environ, PYTHONUNBUFFERED="1") | {k: os.environ.get(k, v) for k, v in MALLOC_ENV.items()}
        env["POLARTRACK_PARENT_PID"] = str(os.getpid())  # a service dies with the launcher (services.options)
        if service == "viewer":
            env |= {k: os.environ.get(k, v) for k, v in VIEWER_ENV.items()}
        cmd = self.command(service)
        profile_dir = os.environ.get("POLARTRACK_PROFILE_DIR")
        if profile_dir:  # developers: a cProfile of every service, written when it exits
            Path(profile_dir).mkdir(parents=True, exist_ok=True)
            out = str(Path(profile_dir) / f"{service}.prof")
            code = (f"import cProfile, sys; import services.{service} as m; "
                    f"cProfile.run('m.main(sys.argv[1:])', {out!r})")
            cmd = [cmd[0], "-c", code, *cmd[3:]]
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env,
                                start_new_session=True)
        self.procs[service] = proc
        return proc

    def stop(self, service: str, timeout: float = 10.0) -> int | None:
        proc = self.procs.get(service)
        return None if proc is None else stop_process(proc, timeout)

    def pause_source(self) -> None:
        """Hold ingest before its next frame (SIGUSR1; :class:`services.ingest.Pause`), its bus
        session still running, until :meth:`resume_source`."""
        self._signal_ingest(signal.SIGUSR1)

    def resume_source(self) -> None:
        self._signal_ingest(signal.SIGUSR2)

    def _signal_ingest(self, sig: int) -> None:
        proc = self.procs.get("ingest")
        if proc is not None and proc.poll() is None:
            proc.send_signal(sig)

    def kill(self, service: str) -> None:
        proc = self.procs.get(service)
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait(5)

    def close_services(self, timeout: float = 10.0, at_once: bool = False) -> dict[str, int | None]:
        """Stop the services in order (the recorder last, to record the others' last messages),
        or with ``at_once`` SIGTERM them all first (a failed run: quicker); SIGKILL after
        ``timeout`` s."""
        for service in ("ingest", "tracker", "viewer", "detector", "recorder") if at_once else ():
            proc = self.procs.get(service)
            if proc is not None and proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        codes = {}
        for service in ("ingest", "tracker", "viewer", "detector", "recorder"):
            codes[service] = self.stop(service, timeout)
        return codes

    def close(self) -> dict[str, int | None]:
        """Stop the services, this process's session and the router; then remove the shared-memory
        segments they left (all of them have exited: nobody holds them any more)."""
        codes = self.close_services()
        if self.session is not None:
            self.session.close()
            self.session = None
        self.stop("router")
        for log in self.logs.values():
            log.close()
        self.logs = {}
        if self.shared_memory:
            from services.shm_files import remove_orphaned_segments

            remove_orphaned_segments()
        return codes

    def open(self) -> None:
        """Start the router the services join, and join it (without shared memory: this process
        reads only small messages, and must not hold the services' segments)."""
        from services.bus import BusConfig, open_session

        if self.session is None:
            router = self.procs.get("router")
            if router is None or router.poll() is not None:
                self.start("router")
            wait_for_port(self.hub_port, self.procs["router"], timeout=60.0, log=lambda: self.log_text("router"))
            self.session = open_session(BusConfig(stream=self.stream, mode="client",
                                                  connect=[f"tcp/127.0.0.1:{self.hub_port}"]))

    def __enter__(self) -> "Pipeline":
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()
        self.tmp.cleanup()

    def log_text(self, service: str) -> str:
        p = self.log_dir / f"{service}.log"
        return p.read_text(errors="replace") if p.exists() else ""

    # -- supervision ---------------------------------------------------------------------
    def _last_line(self, service: str) -> str:
        lines = [ln for ln in self.log_text(service).splitlines() if ln.strip()]
        return lines[-1][-300:] if lines else ""

    def _check_services(self, state: dict, now: float | None = None) -> str | None:
        """One look at the processes (at monotonic time ``now``): restart a dead detector, recorder
        or viewer; a failure (why the run must end now), or None."""
        now = time.monotonic() if now is None else now
        router = self.procs.get("router")
        if router is not None and router.poll() is not None:
            return f"the router exited with status {router.returncode}"
        tracker, ingest = self.procs["tracker"], self.procs["ingest"]
        if ingest.poll() not in (None, 0):
            return f"ingest exited with status {ingest.returncode}: {self._last_line('ingest')}"
        if tracker.poll() is not None:
            if tracker.returncode != 0:
                return f"the tracker exited with status {tracker.returncode}: {self._last_line('tracker')}"
            if not state["eos"]:
                state.setdefault("tracker_gone", now)
                if now - state["tracker_gone"] > END_GRACE_S:  # its last messages may still be on the way
                    return "the tracker exited before the end of the source"
        for service in RESTARTED:
            proc = self.procs.get(service)
            if proc is None or proc.poll() is None or state.get("closing"):
                continue
            if service == "viewer" and proc.returncode == 0:
                # the viewer stops by itself once the stream has ended, and may have seen the end
                # before a busy launcher does: a clean exit is a death only if no end comes soon
                quiet = state.setdefault(("exited", proc.pid), now)
                if state["eos"] or ingest.poll() == 0 or now - quiet <= END_GRACE_S:
                    continue
            if service == "recorder" and proc.returncode == EXIT_DISK_FULL:
                return f"recorder: {self._last_line('recorder').split('error: ', 1)[-1]}"
            if not self.supervise:
                continue
            n = self.parts.get(service, 0)
            if n >= MAX_RESTARTS:
                return f"the {service} died {n + 1} times (last status {proc.returncode})"
            event = {"service": service, "status": proc.returncode, "died_after_frames": state["frames"]}
            self.parts[service] = n + 1
            self.start(service)
            if service == "recorder":
                self.recordings.append(self.part_path(self.mcap, n + 1))
            event["restarted_after_frames"] = state["frames"]
            self.restart_log.append(event)
            log.warning("%s exited with status %s after %d frames: restarted (%d of %d)", service, proc.returncode,
                        state["frames"], n + 1, MAX_RESTARTS)
            if self.on_restart is not None:
                self.on_restart(self, service)
        return None

    # -- a run ----------------------------------------------------------------------------
    def run(self, progress: bool = True, timeout: float | None = None, on_estimate=None) -> RunResult:
        """Start everything, wait for the end of the source, stop everything.

        ``on_estimate(pipeline, estimate)`` is called for every estimate (fault-injection tests
        use it to kill and restart services mid-run). Every message is checked before use
        (:mod:`common.validation`): from the run's own services, decodable, within its caps,
        finite; the bad ones are counted in ``rejected``. On SIGINT, SIGTERM or SIGHUP every
        child is stopped and the shared memory removed, then :class:`Interrupted` is raised."""
        import threading

        previous = {}
        if threading.current_thread() is threading.main_thread():
            def on_signal(signum, frame):
                for sig in previous:  # once: the clean-up is not interrupted again
                    signal.signal(sig, signal.SIG_IGN)
                raise Interrupted(signum)

            for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
                previous[sig] = signal.signal(sig, on_signal)
        try:
            return self._run(progress, timeout, on_estimate)
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)

    def _run(self, progress: bool, timeout: float | None, on_estimate) -> RunResult:
        from tqdm import tqdm

        from common.msgs import Estimate, FrameInfo, MultiEstimate
        from common.msgs.convert import msg_positions
        from common.multitarget.runner import people_truth_parts
        from common.validation import (FrameOrder, Guard, Invalid, Senders, check_estimate, check_frame_info,
                                       check_multi_estimate, check_status, parse_rejects)
        from services.bus import Inbox, attachment_sender, payload_bytes

        self.open()
        bus = router_config(self.hub_port, self.stream)
        session = self.session
        inbox = Inbox()
        guard = Guard("launcher", Senders(self.ids), log)
        order = FrameOrder()
        # the estimates' errors, whatever their order with the frames' truths: single target (centre)
        # or multi-target (the mean over the body model's parts)
        live = LiveErrors() if self.multi is None else LiveMultiErrors()
        t0 = time.monotonic()
        first_t = last_t = None
        infos_seen = 0
        from common.msgs import ServiceStatus

        self.statuses: dict[str, ServiceStatus] = {}
        self.status_log: list[tuple[float, int, ServiceStatus]] = []
        """(arrival time, frames seen so far, status) of every service status, for steady-state figures"""
        self.latencies: list[float] = []
        self.step_ms: list[float] = []
        self.skipped = 0
        self.restart_log: list[dict] = []
        self.health: dict[str, dict[str, dict[str, int]]] = {}
        state = {"eos": False, "frames": 0}
        failure = None

        def take_statuses() -> None:
            while (s := inbox.pop("status")) is not None:
                key = bus.suffix(str(s.key_expr))
                st = guard.decode(key, ServiceStatus, payload_bytes(s), attachment_sender(s), check_status, key)
                if st is not None:
                    self.statuses[st.service] = st
                    self.status_log.append((time.monotonic(), infos_seen, st))
            while (s := inbox.pop("health")) is not None:
                key = bus.suffix(str(s.key_expr))
                if not guard.accept(key, attachment_sender(s)):
                    continue
                try:
                    self.health[key.split("/", 1)[1]] = parse_rejects(payload_bytes(s))
                except Invalid as exc:
                    guard.reject(key, exc)

        early: dict[str, list] = {"estimate": [], "multi": []}
        """Estimates that came before their frame's info (another path through the router): they
        wait up to 5 s for it (at most 1,000), then are dropped as about an unknown frame."""

        def take_estimates(box: str, key: str, cls, check, final: bool = False):
            held, early[box] = early[box], []
            while (s := inbox.pop(box)) is not None:
                e = guard.decode(key, cls, payload_bytes(s), attachment_sender(s), check)
                if e is not None:
                    held.append((time.monotonic(), e))
            newest = -1 if order.index is None else order.index
            for t, e in held:
                if e.frame_index <= newest:
                    yield e
                elif final or time.monotonic() - t > 5.0 or len(early[box]) >= 1000:
                    guard.reject(key, Invalid("unknown_frame", f"frame {e.frame_index} (newest {newest})"))
                else:
                    early[box].append((t, e))

        try:
            subs = [session.declare_subscriber(bus.key("track/estimate"), inbox.callback("estimate", maxlen=100_000)),
                    session.declare_subscriber(bus.key("track/multi_estimate"), inbox.callback("multi", maxlen=100_000)),
                    session.declare_subscriber(bus.key("frame/info"), inbox.callback("info", maxlen=100_000)),
                    session.declare_subscriber(bus.key("status/*"), inbox.callback("status", maxlen=10_000)),
                    session.declare_subscriber(bus.key("health/*"), inbox.callback("health", maxlen=10_000))]
            for s in [s for s in self.services if s != "ingest"]:
                self.start(s)
            self.start("ingest")
            bar = tqdm(total=None, unit="frame", disable=not progress, file=sys.stderr, desc=self.name)
            total = None
            done = final = False
            while True:  # until done, then once more (final) for the messages still on the way
                inbox.wait(0.2 if not final else 0.05)
                while (s := inbox.pop("info")) is not None:
                    info = guard.decode("frame/info", FrameInfo, payload_bytes(s), attachment_sender(s),
                                        check_frame_info, order)
                    if info is None:
                        continue
                    infos_seen += not info.end_of_stream
                    state["frames"] = infos_seen
                    state["eos"] = state["eos"] or info.end_of_stream
                    if info.end_of_stream:
                        state["eos_index"] = int(info.index)
                    if info.total_frames and total is None:
                        total = info.total_frames
                        bar.total = total
                        bar.refresh()
                    if info.end_of_stream:
                        continue
                    if self.multi is not None:
                        gt = people_truth_parts(info, self.multi.config.n_parts)
                        if gt is not None:
                            live.truth(info.index, gt)
                        else:
                            live.frame(info.index)
                    elif info.HasField("truth"):
                        t = info.truth
                        live.truth(info.index, t.centre_x, t.centre_y, t.visible)
                    else:
                        live.frame(info.index)
                take_statuses()
                for e in take_estimates("estimate", "track/estimate", Estimate, check_estimate, final):
                    self.latencies.append(e.latency_ms)
                    self.step_ms.append(e.step_ms)
                    self.skipped = max(self.skipped, e.frames_skipped)
                    now = time.monotonic()
                    first_t = first_t or now
                    last_t = now
                    live.estimate(e.frame_index, e.x + e.box_dx, e.y + e.box_dy)  # the box's centre
                    bar.update(1)
                    if on_estimate is not None:
                        on_estimate(self, e)
                for e in take_estimates("multi", "track/multi_estimate", MultiEstimate, check_multi_estimate, final):
                    self.skipped = max(self.skipped, e.frames_skipped)
                    self.latencies.append(e.latency_ms)
                    self.step_ms.append(e.step_ms)
                    now = time.monotonic()
                    first_t = first_t or now
                    last_t = now
                    try:
                        live.estimate(e.frame_index, msg_positions(e))  # targets in the scene's person order
                    except ValueError:
                        guard.reject("track/multi_estimate", "bad_positions")
                    bar.update(1)
                    if on_estimate is not None:
                        on_estimate(self, e)
                if final:
                    break
                tracker = self.procs["tracker"]
                ingest = self.procs["ingest"]
                if tracker.poll() is not None and ingest.poll() is not None:
                    done = True
                failure = self._check_services(state)
                if failure is not None:
                    log.error("%s: ending the run", failure)
                    done = True
                if timeout is not None and time.monotonic() - t0 > timeout:
                    failure = failure or f"timed out after {timeout:.0f} s"
                    done = True
                final = done
            if failure is None and total and state.get("eos_index", total) < total:
                failure = f"the source ended after {state['eos_index']} of {total} frames (ingest stopped early)"
            bar.close()
        finally:
            state["closing"] = True
            codes = self.close_services(timeout=3.0 if failure else 10.0, at_once=failure is not None)
            time.sleep(0.2)  # the last statuses and health reports still on the way
            take_statuses()
            for s in subs if "subs" in locals() else []:
                s.undeclare()
            self.close()
        errors = live.errors
        n = len(errors)
        errs = np.array([e for e in errors.values() if np.isfinite(e)])
        fps = (n - 1) / (last_t - first_t) if n > 1 and last_t > first_t else 0.0
        rejected = {k: v for k, v in self.health.items() if v}
        if guard.rejects.snapshot():
            rejected["launcher"] = guard.rejects.snapshot()
        return RunResult(mcap=self.mcap, rrd=self.rrd, frames=total or n, estimates=n,
                         mean_err=float(errs.mean()) if errs.size else None,
                         frames_lost=int(np.sum(errs > 20.0)) if errs.size else None, fps=fps,
                         wall_s=time.monotonic() - t0, returncodes=codes, failure=failure,
                         restarts=list(self.restart_log), rejected=rejected, recordings=self.recording_files(),
                         rrd_images=(int(self.statuses["viewer"].published) if self.viewer and "viewer" in self.statuses
                                     else None))

    def recording_files(self) -> list[str]:
        """Every file the run recorded in order: each recorder's file and its splits
        (``NAME.splitK.mcap``, :class:`common.record.writer.SplitSink`) after it."""
        from common.record import split_path

        out = []
        for path in self.recordings:
            out.append(path)
            k = 1
            while Path(part := split_path(path, k)).exists():
                out.append(part)
                k += 1
        return out


