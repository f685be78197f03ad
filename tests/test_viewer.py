"""Rerun logging: MCAP -> .rrd conversion (counts, entity paths, rows on the frame timeline),
malformed messages skipped, ``polartrack view`` errors, and the viewer service end to end on a
private loopback Zenoh port. No display, no network beyond 127.0.0.1."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import uuid
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from mcap.writer import Writer
from mcap_protobuf.schema import build_file_descriptor_set

from common.msgs import TOPICS, Estimate, FrameInfo, ParticleCloud, Truth, pack
from common.msgs.convert import image_to_msg
from common.record.rerun import RunLogger, mcap_to_rrd

REPO = Path(__file__).resolve().parents[1]
W, H, N = 64, 48, 20
T0 = 1_700_000_000_000_000_000
DT = 40_000_000


def _messages(n_frames: int = 3) -> list[tuple[str, bytes, int]]:
    """(topic, payload, capture_ns) of a short run, in publication order."""
    rng = np.random.default_rng(0)
    out = []
    for i in range(n_frames):
        ns = T0 + i * DT
        img = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
        out.append(("frame/image", image_to_msg(img, ns, str(i)).SerializeToString(), ns))
        truth = Truth(visible=True, box_x=20 + i, box_y=15, box_w=12, box_h=8, centre_x=26 + i, centre_y=19,
                      angle_deg=10.0, visible_fraction=1.0)
        info = FrameInfo(index=i, time_s=i * 0.04, capture_ns=ns, width=W, height=H,
                         homography=[1, 0, 0, 0, 1, 0, 0, 0, 1], truth=truth, source="test", total_frames=n_frames)
        out.append(("frame/info", info.SerializeToString(), ns))
        est = Estimate(frame_index=i, time_s=i * 0.04, observed=True, filter="sir", x=27 + i, y=20, theta_deg=9.0 + i,
                       p_visible=0.9, world_x=27 + i, world_y=20, speed=25.0, mmse_x=26.5 + i, mmse_y=19.5,
                       n_eff=15.0)
        out.append(("track/estimate", est.SerializeToString(), ns))
        parts = np.column_stack([rng.normal(27 + i, 2, N), np.zeros(N), rng.normal(20, 2, N), np.zeros(N),
                                 rng.normal(9, 3, N)])
        w = rng.random(N)
        cloud = ParticleCloud(frame_index=i, time_s=i * 0.04, count=N, particles=pack(parts),
                              image_xy=pack(parts[:, [0, 2]]), weights=pack(w / w.sum()), p_visible=pack(np.full(N, 0.9)))
        out.append(("track/particles", cloud.SerializeToString(), ns))
    return out


def _write_mcap(path: Path, messages) -> None:
    with open(path, "wb") as fh:
        writer = Writer(fh)
        writer.start(profile="protobuf", library="polartrack-test")
        schemas, channels = {}, {}
        for seq, (topic, data, ns) in enumerate(messages):
            if topic not in channels:
                cls = TOPICS[topic]
                name = cls.DESCRIPTOR.full_name
                if name not in schemas:
                    schemas[name] = writer.register_schema(
                        name=name, encoding="protobuf", data=build_file_descriptor_set(cls).SerializeToString())
                channels[topic] = writer.register_channel(topic=topic, message_encoding="protobuf",
                                                          schema_id=schemas[name])
            writer.add_message(channels[topic], log_time=ns, data=data, publish_time=ns, sequence=seq)
        writer.finish()


def _rows_by_entity(rrd: Path) -> tuple[Counter, set[str]]:
    """Rows per entity path on the ``frame`` timeline, and all timelines, read back from the file."""
    from rerun.chunk import RrdReader

    rows: Counter = Counter()
    timelines: set[str] = set()
    for chunk in RrdReader(rrd).stream().to_chunks():
        timelines.update(chunk.timeline_names)
        if not chunk.is_static and "frame" in chunk.timeline_names:
            rows[chunk.entity_path] += chunk.num_rows
    return rows, timelines


def test_mcap_to_rrd(tmp_path):
    src, rrd = tmp_path / "run.mcap", tmp_path / "run.rrd"
    _write_mcap(src, _messages(3))
    stats = mcap_to_rrd(src, rrd)
    assert (stats["images"], stats["infos"], stats["estimates"], stats["clouds"]) == (3, 3, 3, 3)
    assert stats["malformed"] == 0 and stats["skipped"] == 0 and not stats["truncated"]
    assert rrd.exists() and rrd.stat().st_size > 3 * 500  # three JPEGs at least
    rows, timelines = _rows_by_entity(rrd)
    assert {"frame", "capture_time"} <= timelines
    for path in ("/camera/image", "/camera/particles", "/camera/estimate", "/camera/truth", "/camera/truth_box",
                 "/ground/particles", "/ground/estimate", "/plots/visibility/p_visible", "/plots/n_eff",
                 "/plots/speed", "/plots/theta/estimate", "/plots/error/map_px"):
        assert rows[path] == 3, (path, rows)
    assert rows["/camera/track"] == 2  # drawn from the second estimate on
    # the time series go out in columns: each point at its own frame, with its value
    from rerun.chunk import RrdReader

    series = [c.to_record_batch() for c in RrdReader(rrd).stream().to_chunks()
              if c.entity_path == "/plots/theta/estimate" and not c.is_static]
    points = sorted((f, v[0]) for b in series for f, v in zip(b.column("frame").to_pylist(),
                                                              b.column("Scalars:scalars").to_pylist()))
    assert points == [(0, 9.0), (1, 10.0), (2, 11.0)]
    # the blueprint travels in the file
    from rerun.chunk import RrdReader

    assert RrdReader(rrd).blueprints()


def test_malformed_messages_are_counted_and_skipped(tmp_path):
    msgs = _messages(3)
    bad_cloud = ParticleCloud(frame_index=1, count=5, particles=pack(np.zeros((3, 5))),
                              image_xy=pack(np.zeros((3, 2))), weights=pack(np.ones(3)))
    msgs.insert(5, ("track/estimate", b"\xff" * 11, T0 + DT))  # not protobuf at all
    msgs.insert(6, ("track/particles", bad_cloud.SerializeToString(), T0 + DT))  # sizes disagree with count
    src, rrd = tmp_path / "bad.mcap", tmp_path / "bad.rrd"
    _write_mcap(src, msgs)
    stats = mcap_to_rrd(src, rrd)
    assert stats["malformed"] == 2
    assert (stats["images"], stats["estimates"], stats["clouds"]) == (3, 3, 3)
    assert _rows_by_entity(rrd)[0]["/camera/estimate"] == 3


def test_truncated_recording_converts_what_is_there(tmp_path):
    src = tmp_path / "full.mcap"
    _write_mcap(src, _messages(3))
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(src.read_bytes()[: src.stat().st_size // 2])
    stats = mcap_to_rrd(cut, tmp_path / "cut.rrd")
    assert stats["truncated"]
    assert (tmp_path / "cut.rrd").exists()


def test_recording_cut_anywhere_converts(tmp_path):
    """Wherever a killed recorder's file ends (mid-header, mid-record, mid-chunk), the conversion
    stops there instead of raising (the reader raises McapError, EOFError, struct.error, ...)."""
    src = tmp_path / "full.mcap"
    _write_mcap(src, _messages(3))
    data = src.read_bytes()
    for i, end in enumerate(range(9, len(data), max(1, len(data) // 23))):
        cut = tmp_path / f"cut{i}.mcap"
        cut.write_bytes(data[:end])
        stats = mcap_to_rrd(cut, tmp_path / f"cut{i}.rrd")
        assert stats["truncated"], end
    # cut inside the closing magic, after the footer: every record whole, the file still cut
    for end in (len(data) - 8, len(data) - 3):
        cut = tmp_path / f"magic{end}.mcap"
        cut.write_bytes(data[:end])
        assert mcap_to_rrd(cut, tmp_path / f"magic{end}.rrd")["truncated"], end
    assert not mcap_to_rrd(src, tmp_path / "full.rrd")["truncated"]  # the whole file is not


def test_two_loggers_in_one_process(tmp_path):
    import rerun as rr

    a = RunLogger(rr.RecordingStream("polartrack-a"))
    b = RunLogger(rr.RecordingStream("polartrack-b"))
    a.rec.save(str(tmp_path / "a.rrd"))
    b.rec.save(str(tmp_path / "b.rrd"))
    for topic, data, ns in _messages(2):
        assert a.log_message(topic, data, ns)
    assert b.log_message(*_messages(1)[0])
    a.close()
    b.close()
    assert a.stats["images"] == 2 and b.stats["images"] == 1
    assert _rows_by_entity(tmp_path / "a.rrd")[0]["/camera/image"] == 2
    assert _rows_by_entity(tmp_path / "b.rrd")[0]["/camera/image"] == 1


def test_rotate_goes_on_in_a_new_file_of_the_same_recording(tmp_path):
    """The viewer's long-run bound: the logger closes its stream and goes on in a new .rrd of
    the same recording id; the two files hold the frames before and after, none lost, none twice."""
    from rerun.chunk import RrdReader

    msgs = _messages(4)
    logger = RunLogger.to_file(tmp_path / "run.rrd")
    for m in msgs[:8]:  # frames 0 and 1
        assert logger.log_message(*m)
    logger.rotate(tmp_path / "run.split1.rrd")
    for m in msgs[8:]:  # frames 2 and 3
        assert logger.log_message(*m)
    logger.close()
    first, _ = _rows_by_entity(tmp_path / "run.rrd")
    second, _ = _rows_by_entity(tmp_path / "run.split1.rrd")
    assert first["/camera/image"] == 2 and second["/camera/image"] == 2
    ids = [[r.recording_id for r in RrdReader(f).recordings()] for f in (tmp_path / "run.rrd", tmp_path / "run.split1.rrd")]
    assert len(ids[0]) == 1 and ids[0] == ids[1]


def test_track_is_bounded():
    import rerun as rr

    lg = RunLogger(rr.RecordingStream("polartrack-bounded", default_enabled=False), track_length=5)
    for i in range(20):
        lg.estimate(Estimate(frame_index=i, x=float(i), y=1.0, world_x=float(i), world_y=2.0), T0 + i * DT)
    assert len(lg.track_image) == 5 and len(lg.track_world) == 5
    assert lg.track_image[0] == (15.0, 1.0)


def test_view_command(tmp_path, capsys):
    from services.commands import view

    src = tmp_path / "run.mcap"
    _write_mcap(src, _messages(2))
    import argparse

    p = argparse.ArgumentParser()
    view.add_arguments(p)
    assert view.run(p.parse_args([str(src)])) == 0
    assert capsys.readouterr().out.strip() == str(tmp_path / "run.rrd")
    assert (tmp_path / "run.rrd").exists()

    from services.commands.errors import UsageError

    notmcap = tmp_path / "notes.mcap"
    notmcap.write_text("hello")
    for argv, message in (([str(tmp_path / "missing.mcap")], "no such file"),
                          ([str(notmcap)], "not an MCAP file"),
                          ([str(src), "--out", str(tmp_path / "x.txt")], "must be a .rrd")):
        with pytest.raises(UsageError, match=message) as info:
            view.run(p.parse_args(argv))
        assert "\n" not in str(info.value)
    assert not (tmp_path / "notes.rrd").exists()  # a bad input leaves no output behind


# ---------------------------------------------------------------------- viewer service
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _env() -> dict:
    env = dict(os.environ)
    env.pop("DISPLAY", None)
    env.pop("WAYLAND_DISPLAY", None)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def test_viewer_flags_are_validated(tmp_path):
    cfg = tmp_path / "viewer.toml"
    cfg.write_text('out = "x.rrd"\njpeg_quality = 500\n')
    r = subprocess.run([sys.executable, "-m", "services.viewer", "--config", str(cfg)], cwd=REPO, env=_env(),
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert "jpeg_quality" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    r = subprocess.run([sys.executable, "-m", "services.viewer", "--out", str(tmp_path / "x.mcap")], cwd=REPO,
                       env=_env(), capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and ".rrd" in r.stderr


@pytest.mark.parametrize("max_image_hz, images", [(0, 3), (10, 1)])  # frames 40 ms apart: 10 Hz logs the first
def test_viewer_service_end_to_end(tmp_path, max_image_hz, images):
    from services.bus import BusConfig, ns_attachment, open_session, wait_for_alive

    port = _free_port()
    stream = "t" + uuid.uuid4().hex[:8]
    endpoint = f"tcp/127.0.0.1:{port}"
    out = tmp_path / "live.rrd"
    cfg = tmp_path / "viewer.toml"
    cfg.write_text(f'out = "{out}"\nquiet_s = 0.5\nmax_image_hz = {max_image_hz}\n\n[bus]\nstream = "{stream}"\nlisten = ["{endpoint}"]\n'
                   "multicast_scouting = false\n")
    proc = subprocess.Popen([sys.executable, "-m", "services.viewer", "--config", str(cfg)], cwd=REPO, env=_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        bus = BusConfig(stream=stream, connect=[endpoint], multicast_scouting=False)
        with open_session(bus) as session:
            assert wait_for_alive(session, bus, ["viewer"], timeout=30), "viewer never came up"
            pubs = {t: session.declare_publisher(bus.key(t)) for t in TOPICS}
            time.sleep(0.2)  # let the subscriptions propagate both ways
            for topic, data, ns in _messages(3):
                pubs[topic].put(data, attachment=ns_attachment(ns))
            pubs["track/estimate"].put(b"\xff" * 11, attachment=ns_attachment(T0))  # malformed: skipped
            eos = FrameInfo(index=3, end_of_stream=True, capture_ns=T0 + 2 * DT)
            pubs["frame/info"].put(eos.SerializeToString(), attachment=ns_attachment(T0 + 2 * DT))
            rc = proc.wait(timeout=30)
        output = proc.stdout.read()
        assert rc == 0, output
        assert "malformed" in output
        assert out.exists() and out.stat().st_size > 1000
        rows, _ = _rows_by_entity(out)
        assert rows["/camera/image"] == images and rows["/camera/particles"] == 3 and rows["/camera/estimate"] == 3
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=10)


def _thread_nice(pid: int) -> dict[str, set[int]]:
    """Thread name -> the nice values of the threads of that name, from /proc."""
    out: dict[str, set[int]] = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        stat = (task / "stat").read_text()
        name = stat[stat.index("(") + 1: stat.rindex(")")]
        nice = int(stat[stat.rindex(")") + 2:].split()[16])  # field 19 of stat
        out.setdefault(name, set()).add(nice)
    return out


def _check_viewer_priorities(pid: int) -> None:
    """A viewer run with ``--nice 19``: its own work (the main thread, Rerun's threads) at 19, but
    Zenoh's threads, which move samples from the socket into the bounded channels, at the normal
    priority: niced, they drained the socket late on a busy machine, and the router, blocked on
    the viewer's full queue, held up every other service's messages."""
    threads = _thread_nice(pid)
    main = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[16])
    zenoh = {n: v for n, v in threads.items() if n.split("-")[0] in ("rx", "tx", "net", "app", "acc")}
    rerun = {n: v for n, v in threads.items() if n in ("RecordingStream", "file_writer") or n.startswith("ChunkBatcher")}
    assert main == 19, threads
    assert zenoh and all(v == {0} for v in zenoh.values()), threads
    assert rerun and all(v == {19} for v in rerun.values()), threads


def test_viewer_stops_cleanly_on_sigterm(tmp_path):
    from services.bus import BusConfig, ns_attachment, open_session, wait_for_alive

    port = _free_port()
    stream = "t" + uuid.uuid4().hex[:8]
    endpoint = f"tcp/127.0.0.1:{port}"
    out = tmp_path / "stopped.rrd"
    proc = subprocess.Popen([sys.executable, "-m", "services.viewer", "--stream", stream, "--listen", endpoint,
                             "--out", str(out), "--nice", "19"], cwd=REPO, env=_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        bus = BusConfig(stream=stream, connect=[endpoint])
        with open_session(bus) as session:
            assert wait_for_alive(session, bus, ["viewer"], timeout=30), "viewer never came up"
            if sys.platform.startswith("linux"):
                _check_viewer_priorities(proc.pid)
            pub = session.declare_publisher(bus.key("frame/image"))
            time.sleep(0.2)
            topic, data, ns = _messages(1)[0]
            pub.put(data, attachment=ns_attachment(ns))
            time.sleep(0.5)
            proc.send_signal(signal.SIGTERM)
            rc = proc.wait(timeout=30)
        assert rc == 0, proc.stdout.read()
        assert _rows_by_entity(out)[0]["/camera/image"] == 1
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=10)


def test_estimate_box_is_the_estimates_own_size(monkeypatch):
    """Rerun draws the estimate's oriented box from its w, h (the apparent scale), falling back to
    the first box only when the estimate carries no size, about the box's centre (box_dx, box_dy
    from the MAP)."""
    import rerun as rr

    lg = RunLogger(rr.RecordingStream("polartrack-box", default_enabled=False))
    drawn = []
    real = RunLogger._rotated_box
    monkeypatch.setattr(RunLogger, "_rotated_box", staticmethod(lambda *a: drawn.append(a) or real(*a)))
    lg._box_size = (40.0, 20.0)
    lg.estimate(Estimate(frame_index=0, x=100.0, y=50.0, theta_deg=30.0, w=120.0, h=60.0), T0)
    lg.estimate(Estimate(frame_index=1, x=100.0, y=50.0, theta_deg=30.0), T0 + DT)
    lg.estimate(Estimate(frame_index=2, x=100.0, y=50.0, theta_deg=30.0, w=120.0, h=60.0, box_dx=4.0, box_dy=-3.0),
                T0 + 2 * DT)
    assert drawn == [(100.0, 50.0, 120.0, 60.0, 30.0), (100.0, 50.0, 40.0, 20.0, 30.0),
                     (104.0, 47.0, 120.0, 60.0, 30.0)]  # the last about the box's own centre
    pts = np.array(real(0.0, 0.0, 120.0, 60.0, 90.0))
    assert np.ptp(pts[:, 0]) == pytest.approx(60.0) and np.ptp(pts[:, 1]) == pytest.approx(120.0)
