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
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from common.settings import TrackerSettings

SERVICES = ("recorder", "detector", "tracker", "viewer", "ingest")


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

    def as_dict(self) -> dict:
        return {"mcap": self.mcap, "rrd": self.rrd, "frames": self.frames, "estimates": self.estimates,
                "mean_err": None if self.mean_err is None else round(self.mean_err, 3),
                "frames_lost": self.frames_lost, "fps": round(self.fps, 2), "wall_s": round(self.wall_s, 2),
                "returncodes": self.returncodes}


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


class Pipeline:
    """The processes of one run. Use as a context manager: everything is stopped on exit."""

    def __init__(self, source: str, init_box, settings: TrackerSettings, out_dir: str | Path = "recordings",
                 frames: int | None = None, pace: str = "consumer", viewer: bool = True, stream: str | None = None,
                 name: str | None = None, log_dir: str | Path | None = None, shared_memory: bool = True,
                 prerender: bool = False, multi=None):
        """``prerender``: the ingest service reads or renders every frame before publishing the
        first (see :class:`common.sources.PrerenderedSource`). ``multi``: a
        :class:`common.multitarget_runner.MultiRun` (multi-target filters; ``init_box`` is then None
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

    # -- processes ------------------------------------------------------------------------
    def command(self, service: str) -> list[str]:
        base = [sys.executable, "-m", f"services.{service}", "--stream", self.stream]
        base += ["--shared-memory"] if self.shared_memory else []
        if service == "router":
            return base + ["--mode", "router", "--listen", f"tcp/127.0.0.1:{self.hub_port}"]
        base += client_args(self.hub_port)
        if NICE.get(service):
            base += ["--nice", str(NICE[service])]
        if service == "recorder":
            return base + ["--out", self.mcap] + (["--compression", "none"] if self.incompressible() else [])
        if service == "viewer":
            return base + ["--out", self.rrd]
        if service == "tracker":
            cfg = Path(self.tmp.name) / "tracker.json"
            cfg.write_text(json.dumps({"init_box": None if self.init_box is None else list(self.init_box),
                                       "settings": self.settings.model_dump(mode="json"),
                                       "multi": None if self.multi is None else self.multi.to_json(),
                                       "skip_stale": self.pace != "consumer"}))
            return base + ["--config", str(cfg)]
        if service == "ingest":
            cfg = Path(self.tmp.name) / "ingest.json"
            run_config = {"run_id": self.name, "source": self.source,
                          "init_box": [] if self.init_box is None else list(self.init_box),
                          "settings_json": self.settings.model_dump_json(),
                          "seed": self.settings.seed if self.multi is None else self.multi.seed,
                          "versions_json": json.dumps(versions()), "pace": self.pace}
            if self.multi is not None:
                run_config["multi_json"] = self.multi.to_json()
            waits = [s for s in self.services if s != "ingest"]
            cfg.write_text(json.dumps({"source": self.source, "frames": self.frames, "pace": self.pace,
                                       "wait_for": waits, "run_config": json.dumps(run_config),
                                       "prerender": self.prerender}))
            return base + ["--config", str(cfg)]
        return base

    def incompressible(self) -> bool:
        """The synthetic scene's frames carry per-pixel sensor noise: LZ4 chunks of them are 0.0%
        smaller, and compressing them was a third of the recorder's CPU in bench --pipeline.
        (Frames of real video keep LZ4: about half the size for a UAV123 frame.)"""
        return self.source.split(":", 1)[0] == "synthetic"

    def start(self, service: str) -> subprocess.Popen:
        log = open(self.log_dir / f"{service}.log", "ab")
        self.logs[service] = log
        env = dict(os.environ, PYTHONUNBUFFERED="1") | {k: os.environ.get(k, v) for k, v in MALLOC_ENV.items()}
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
        if proc is None:
            return None
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(5)
        return proc.returncode

    def kill(self, service: str) -> None:
        proc = self.procs.get(service)
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait(5)

    def close_services(self) -> dict[str, int | None]:
        codes = {}
        for service in ("ingest", "tracker", "viewer", "detector", "recorder"):
            codes[service] = self.stop(service)
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

    # -- a run ----------------------------------------------------------------------------
    def run(self, progress: bool = True, timeout: float | None = None, on_estimate=None) -> RunResult:
        """Start everything, wait for the end of the source, stop everything.

        ``on_estimate(pipeline, estimate)`` is called for every estimate (fault-injection tests
        use it to kill and restart services mid-run)."""
        from tqdm import tqdm

        from common.msgs import Estimate, FrameInfo, MultiEstimate
        from common.multitarget_runner import msg_positions, people_truth_parts
        from services.bus import Inbox, payload_bytes

        self.open()
        bus = router_config(self.hub_port, self.stream)
        session = self.session
        inbox = Inbox()
        truths: dict[int, tuple[float, float, bool]] = {}
        people: dict[int, np.ndarray] = {}  # multi-target: true part centres of the body model per frame
        errors: dict[int, float] = {}
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
        try:
            subs = [session.declare_subscriber(bus.key("track/estimate"), inbox.callback("estimate")),
                    session.declare_subscriber(bus.key("track/multi_estimate"), inbox.callback("multi")),
                    session.declare_subscriber(bus.key("frame/info"), inbox.callback("info")),
                    session.declare_subscriber(bus.key("status/*"), inbox.callback("status"))]
            for s in [s for s in self.services if s != "ingest"]:
                self.start(s)
            self.start("ingest")
            bar = tqdm(total=None, unit="frame", disable=not progress, file=sys.stderr, desc=self.name)
            total = None
            done = False
            while not done:
                inbox.wait(0.2)
                while (s := inbox.pop("info")) is not None:
                    info = FrameInfo.FromString(payload_bytes(s))
                    infos_seen += not info.end_of_stream
                    if info.total_frames and total is None:
                        total = info.total_frames
                        bar.total = total
                        bar.refresh()
                    if info.HasField("truth") and not info.end_of_stream:
                        t = info.truth
                        truths[info.index] = (t.centre_x, t.centre_y, t.visible)
                    if self.multi is not None and not info.end_of_stream:
                        gt = people_truth_parts(info, self.multi.config.n_parts)
                        if gt is not None:
                            people[info.index] = gt
                while (s := inbox.pop("status")) is not None:
                    st = ServiceStatus.FromString(payload_bytes(s))
                    self.statuses[st.service] = st
                    self.status_log.append((time.monotonic(), infos_seen, st))
                while (s := inbox.pop("estimate")) is not None:
                    e = Estimate.FromString(payload_bytes(s))
                    self.latencies.append(e.latency_ms)
                    self.step_ms.append(e.step_ms)
                    self.skipped = max(self.skipped, e.frames_skipped)
                    now = time.monotonic()
                    first_t = first_t or now
                    last_t = now
                    if e.frame_index in truths:
                        cx, cy, vis = truths[e.frame_index]
                        if vis and np.isfinite(cx):
                            errors[e.frame_index] = float(np.hypot(e.x - cx, e.y - cy))
                    errors.setdefault(e.frame_index, float("nan"))
                    bar.update(1)
                    if on_estimate is not None:
                        on_estimate(self, e)
                while (s := inbox.pop("multi")) is not None:
                    e = MultiEstimate.FromString(payload_bytes(s))
                    self.skipped = max(self.skipped, e.frames_skipped)
                    self.latencies.append(e.latency_ms)
                    self.step_ms.append(e.step_ms)
                    now = time.monotonic()
                    first_t = first_t or now
                    last_t = now
                    gt = people.pop(e.frame_index, None)
                    for k in [k for k in people if k < e.frame_index]:  # skipped frames: bounded
                        del people[k]
                    err = float("nan")
                    if gt is not None and len(gt) == e.targets:  # targets in the scene's person order
                        err = float(np.mean(np.linalg.norm(msg_positions(e) - gt, axis=-1)))
                    errors[e.frame_index] = err
                    bar.update(1)
                    if on_estimate is not None:
                        on_estimate(self, e)
                tracker = self.procs["tracker"]
                ingest = self.procs["ingest"]
                if tracker.poll() is not None and ingest.poll() is not None:
                    done = True
                if ingest.poll() not in (None, 0) or tracker.poll() not in (None, 0):
                    done = True
                if timeout is not None and time.monotonic() - t0 > timeout:
                    done = True
            bar.close()
        finally:
            codes = self.close_services()
            while (s := inbox.pop("status")) is not None:
                st = ServiceStatus.FromString(payload_bytes(s))
                self.statuses[st.service] = st
                self.status_log.append((time.monotonic(), infos_seen, st))
            for s in subs:
                s.undeclare()
            self.close()
        n = len(errors)
        errs = np.array([e for e in errors.values() if np.isfinite(e)])
        fps = (n - 1) / (last_t - first_t) if n > 1 and last_t > first_t else 0.0
        return RunResult(mcap=self.mcap, rrd=self.rrd, frames=total or n, estimates=n,
                         mean_err=float(errs.mean()) if errs.size else None,
                         frames_lost=int(np.sum(errs > 20.0)) if errs.size else None, fps=fps,
                         wall_s=time.monotonic() - t0, returncodes=codes)


def versions() -> dict[str, str]:
    from importlib.metadata import PackageNotFoundError, version

    out = {"python": sys.version.split()[0]}
    for pkg in ("polartrack", "numpy", "dtcwt", "opencv-python-headless", "eclipse-zenoh", "mcap", "rerun-sdk", "numba"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            pass
    return out
