"""The launcher's supervision, fault by fault, with the outcome stated: a dead detector is
restarted and the run recovers with N frames unobserved; a dead tracker or router ends the run
with a clear failure within seconds; the launcher on SIGTERM / SIGHUP stops every child; a full
disk stops the recorder cleanly with the file readable up to the cut and a one-line reason. Each
time: no orphan process, no shared-memory file left. Real processes on the run's private
loopback router (explicit endpoints, multicast scouting off)."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import psutil
import pytest

from common.msgs.image_wire import decode_frame

from common.record.reader import read_recording
from services.launcher import EXIT_DISK_FULL
from services.shm_files import segment_files, segments_mapped_by
from tests.outage import held_after, outage_report, wait_restarted

pytestmark = pytest.mark.slow  # services as separate processes on a loopback bus

SOURCE = "synthetic:3"
REPO = Path(__file__).resolve().parents[1]


class Watch:
    """The run's processes and shared-memory segments, seen while it goes on."""

    def __init__(self):
        self.pids: set[int] = set()
        self.segments: set[str] = set()

    def look(self, pipe) -> None:
        pids = [p.pid for p in pipe.procs.values() if p.poll() is None]
        self.pids.update(pids)
        self.segments.update(segments_mapped_by(pids))

    def assert_clean(self) -> None:
        alive = [pid for pid in self.pids if psutil.pid_exists(pid) and psutil.Process(pid).status() != "zombie"]
        assert alive == [], f"orphans: {alive}"
        assert self.segments, "no shared-memory segment seen mid-run"
        assert not (segment_files() & self.segments), "shared-memory files left"


def kill_at(watch: Watch, services, sig, at: int = 8, resume: bool = True):
    """``on_estimate`` sending ``sig`` to ``services`` at the first estimate of frame ``at`` or later
    the launcher hears of, and the list of (frame, time) it did. On a pipeline whose source stops
    before the next frame (:func:`tests.outage.held_after`), nothing later goes out before the kill, however late
    a busy launcher hears of frame ``at``. ``resume``: the source goes on right after the kill (else
    the pipeline's ``on_restart`` lets it go: :func:`resume_when_alive`)."""
    killed = []

    def inject(pipe, est):
        watch.look(pipe)
        if est.frame_index >= at and not killed:
            for s in services:
                pipe.procs[s].send_signal(sig)
            killed.append((est.frame_index, time.monotonic()))
            if resume:
                pipe.resume_source()

    return inject, killed


def resume_when_alive(pipe, service) -> None:
    """``on_restart``: the source goes on once the restarted service is up (seconds here)."""
    try:
        wait_restarted(pipe, service)
    finally:
        pipe.resume_source()


@pytest.fixture
def pipeline(synthetic_pipeline):
    """The run every supervision test starts: the synthetic scene, the profile at seed 3."""
    return lambda frames, **kw: synthetic_pipeline(SOURCE, frames, seed=3, **kw)


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_dead_detector_is_restarted_and_the_run_recovers(tmp_path, sig, pipeline):
    """Killed (or stopped) at frame 8, the source stopped before frame 9 until then: restarted by
    the launcher. Ingest holds the source while no detector is on the bus (its start takes seconds
    here; a live source would lose that many frames), so the outage is the frames sent before
    ingest saw the detector go: at most a few unobserved."""
    frames = 40
    watch = Watch()
    inject, _ = kill_at(watch, ["detector"], sig)
    with pipeline(frames, ingest_options=held_after(8)) as pipe:
        result = pipe.run(progress=False, timeout=300, on_estimate=inject)
    rec = read_recording(result.mcap)
    report = outage_report(rec, tmp_path)
    status = -sig if sig == signal.SIGKILL else 0
    assert [(r["service"], r["status"]) for r in result.restarts] == [("detector", status)], report
    gap = result.restarts[0]
    assert gap["died_after_frames"] >= 9 and gap["restarted_after_frames"] >= gap["died_after_frames"]
    assert result.failure is None and not result.ok  # recovered, but the run says a service died
    ests = sorted(rec.decoded("track/estimate"), key=lambda e: e.frame_index)
    assert [e.frame_index for e in ests] == list(range(frames)), report
    unobserved = [e.frame_index for e in ests if not e.observed]
    assert all(i >= 8 for i in unobserved) and len(unobserved) <= 5, report
    print(f"detector {sig.name}: restarted after frame {gap['died_after_frames']}, {len(unobserved)} unobserved")
    assert ests[-1].observed and ests[-1].p_visible > 0.9, report  # recovered
    info = {i.index: i for i in rec.decoded("frame/info") if not i.end_of_stream}[frames - 1]
    assert np.hypot(ests[-1].x - info.truth.centre_x, ests[-1].y - info.truth.centre_y) < 5
    assert len(rec.messages["frame/image"]) == frames
    watch.assert_clean()


@pytest.mark.parametrize("victim,sig", [("tracker", signal.SIGKILL), ("tracker", signal.SIGTERM),
                                        ("router", signal.SIGKILL), ("ingest", signal.SIGKILL),
                                        ("ingest", signal.SIGTERM)])
def test_dead_tracker_or_router_ends_the_run_within_seconds(tmp_path, victim, sig, pipeline):
    frames = 200
    watch = Watch()
    inject, killed = kill_at(watch, [victim], sig)
    with pipeline(frames) as pipe:
        result = pipe.run(progress=False, timeout=300, on_estimate=inject)
        ended = time.monotonic()
    assert killed
    took = ended - killed[0][1]
    assert result.failure is not None and (victim in result.failure or "source ended" in result.failure), result.failure
    assert not result.ok and result.estimates < frames
    assert took < 20, f"{took:.1f} s from the kill to the end of the run"
    watch.assert_clean()
    if victim != "router":  # the recorder was stopped cleanly: the file is whole up to the fault
        rec = read_recording(result.mcap)
        assert 9 <= len(rec.messages["track/estimate"]) < frames
    print(f"{victim} {sig.name}: failure {result.failure!r} after {took:.1f} s")


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_launcher_signal_stops_every_child(tmp_path, sig):
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-c", "import sys; from services.cli import main; sys.exit(main())",
                             "run", "--source", SOURCE, "--frames", "300", "--no-progress", "--out-dir", str(tmp_path)],
                            cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    watch = Watch()
    try:
        parent = psutil.Process(proc.pid)
        deadline = time.monotonic() + 120
        mcap = None
        while time.monotonic() < deadline:  # every service up and frames recorded
            kids = parent.children()
            files = list(tmp_path.glob("*.mcap"))
            if len(kids) >= 6 and files and files[0].stat().st_size > (8 << 20):
                mcap = files[0]
                break
            time.sleep(0.2)
        assert mcap is not None, "the run never got going"
        watch.pids = {k.pid for k in parent.children()}
        watch.segments = segments_mapped_by(watch.pids)
        proc.send_signal(sig)
        out, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 128 + sig, out[-2000:]
    assert "interrupted" in out and "services stopped" in out
    watch.assert_clean()


def test_full_disk_stops_the_recorder_cleanly(tmp_path, pipeline):
    """A disk of 12 MiB (simulated: ENOSPC beyond): the recorder stops, exit 3 with one line, the
    file readable up to its last flush, and the run ends with that reason."""
    from mcap.reader import NonSeekingReader

    frames = 60
    watch = Watch()
    with pipeline(frames, recorder_options={"simulate_disk_bytes": 12 << 20}) as pipe:
        result = pipe.run(progress=False, timeout=300, on_estimate=lambda p, e: watch.look(p))
        log = pipe.log_text("recorder")
    assert result.failure is not None and result.failure.startswith("recorder: disk full (ENOSPC)"), result.failure
    assert "\n" not in result.failure
    assert result.returncodes["recorder"] == EXIT_DISK_FULL and not result.ok
    assert "Traceback" not in log
    size = Path(result.mcap).stat().st_size
    assert 0 < size <= 12 << 20
    n, images = 0, 0
    with open(result.mcap, "rb") as fh:
        try:
            for _schema, channel, _msg in NonSeekingReader(fh).iter_messages(log_time_order=False):
                n += 1
                images += channel.topic == "frame/image"
        except Exception as exc:  # noqa: BLE001 - the file ends where the disk filled: no footer
            assert "end" in type(exc).__name__.lower() or "EOF" in str(exc) or "end" in str(exc).lower(), exc
    assert images >= 2 and n > images
    # and a replay reads it up to the cut, with one line saying so (it has no footer)
    warnings = []
    rec = read_recording(result.mcap, warn=warnings.append)
    assert len(rec.messages["frame/image"]) == images and sum(map(len, rec.messages.values())) == n
    assert len(warnings) == 1 and "cut short" in warnings[0] and "\n" not in warnings[0]
    assert rec.run["source"] == SOURCE  # the run's metadata from its recorded config
    print(f"disk full: {result.failure}; {n} messages readable, {images} frames")
    watch.assert_clean()


def test_dead_recorder_and_viewer_are_restarted_into_new_files(tmp_path, pipeline):
    """SIGKILL of the recorder and the viewer at frame 20: both restarted, each into a file of
    its own (``.part1``); the first recording is readable up to the kill, the second holds the
    frames after the restart, the gap between them is in the run's restarts."""
    frames = 40
    watch = Watch()
    # at frame 20: the recorder holds the last 0.25 s of log time to write it in order (7.5
    # frames here), so a kill much earlier can find nothing whole on disk yet
    inject, _ = kill_at(watch, ["recorder", "viewer"], signal.SIGKILL, at=20, resume=False)

    def restarted(pipe, service):  # the source waits for each new process
        pipe.pause_source()
        resume_when_alive(pipe, service)

    with pipeline(frames, viewer=True, on_restart=restarted, ingest_options=held_after(20)) as pipe:
        result = pipe.run(progress=False, timeout=300, on_estimate=inject)
    assert sorted((r["service"], r["status"]) for r in result.restarts) == [("recorder", -9), ("viewer", -9)]
    assert result.failure is None and not result.ok and result.estimates == frames
    assert len(result.recordings) == 2 and result.recordings[1].endswith(".part1.mcap")
    assert Path(result.rrd).with_name(Path(result.rrd).stem + ".part1.rrd").exists()
    warnings = []
    first = read_recording(result.recordings[0], warn=warnings.append)
    second = read_recording(result.recordings[1], warn=warnings.append)
    ids = lambda rec: [decode_frame(data)[0] for _, data in rec.messages["frame/image"]]  # noqa: E731
    a, b = ids(first), ids(second)
    assert a and b and max(a) < min(b) and max(b) == frames - 1  # the gap between them, nothing twice
    assert len(warnings) == 1  # the killed one is cut short; the restarted one closed cleanly
    watch.assert_clean()


class _Proc:
    """A process as the launcher's supervision sees it: ``poll()`` -> its exit status (None: running)."""

    def __init__(self, returncode, pid):
        self.returncode, self.pid = returncode, pid

    def poll(self):
        return self.returncode


def test_a_viewer_that_stopped_at_the_end_before_the_launcher_heard_of_it_is_not_restarted(tmp_path):
    """The viewer exits 0 a second after the stream's end; a starved launcher can see that exit
    before the end itself (seen under four busy loops at nice -15: the viewer restarted after the
    run's last frame). A clean exit is a death only if no end comes within ``END_GRACE_S``, or
    ingest has not ended; negative control: a viewer stopped cleanly mid-run is restarted."""
    from common.settings import TrackerSettings
    from services.launcher import END_GRACE_S, Pipeline

    pipe = Pipeline(SOURCE, (10.0, 10.0, 20.0, 20.0), TrackerSettings(), out_dir=tmp_path, frames=40, log_dir=tmp_path)
    started = []
    pipe.start = started.append
    pipe.restart_log = []  # as run() sets it up
    running = _Proc(None, 1)
    try:
        pipe.procs = {s: running for s in ("router", "tracker", "ingest", "detector", "recorder")}
        pipe.procs["viewer"] = _Proc(0, 2)
        state, t = {"eos": False, "frames": 40}, 100.0
        assert pipe._check_services(state, now=t) is None and started == []  # the end not heard of yet
        state["eos"] = True  # ... and then heard of, within the grace
        assert pipe._check_services(state, now=t + END_GRACE_S + 5) is None and started == []

        pipe.procs["ingest"] = _Proc(0, 3)  # the source over: ingest exited cleanly
        pipe.procs["viewer"] = _Proc(0, 4)
        state = {"eos": False, "frames": 40}
        assert pipe._check_services(state, now=t) is None
        assert pipe._check_services(state, now=t + END_GRACE_S + 5) is None and started == []

        pipe.procs["ingest"] = running  # negative control: mid-run, no end comes
        pipe.procs["viewer"] = _Proc(0, 5)
        state = {"eos": False, "frames": 20}
        assert pipe._check_services(state, now=t) is None and started == []
        assert pipe._check_services(state, now=t + END_GRACE_S + 0.1) is None and started == ["viewer"]
        assert pipe.restart_log == [{"service": "viewer", "status": 0, "died_after_frames": 20,
                                     "restarted_after_frames": 20}]
    finally:
        pipe.tmp.cleanup()
