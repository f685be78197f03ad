"""The real services as separate processes on a private loopback Zenoh network.

Every test starts its own processes (a router hosted by the test process on a free loopback
port, services as clients, multicast scouting off) and stops them all, whatever happens.
"""

import json
import signal

import numpy as np
import pytest

from common.msgs import Estimate, ScoreQuery, ScoreReply
from common.record.retrack import offline_retrack
from common.record.reader import read_recording
from common.single_target.runner import track_frames
from common.settings import profile_for
from common.sources import open_source
from parity import rewrite_mcap
from tests.outage import DetectorOutage, outage_report
from services.launcher import Pipeline

pytestmark = pytest.mark.slow  # services as separate processes on a loopback bus

SOURCE = "synthetic:3"
FRAMES = 12


@pytest.fixture(scope="module")
def recorded_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    src = open_source(SOURCE, n_frames=FRAMES)
    settings = profile_for(src, seed=3)
    init = src.frame(0).truth.box
    from services.shm_files import segments_mapped_by

    used: set[str] = set()  # this run's shared-memory segments (others may run beside it)
    environ: dict[str, dict[str, str]] = {}

    def note_segments(pipe, est):
        if est.frame_index == FRAMES // 2:
            used.update(segments_mapped_by(p.pid for p in pipe.procs.values()))
            for name, p in pipe.procs.items():
                raw = open(f"/proc/{p.pid}/environ", "rb").read().split(b"\0")
                environ[name] = dict(kv.decode().split("=", 1) for kv in raw if b"=" in kv)

    with Pipeline(SOURCE, init, settings, out_dir=out, frames=FRAMES, viewer=False, log_dir=out) as pipe:
        result = pipe.run(progress=False, timeout=240, on_estimate=note_segments)
    return {"result": result, "settings": settings, "init": init, "dir": out, "shm_used": used, "environ": environ}


def test_services_keep_frame_buffers_on_the_heap(recorded_run):
    """Every service runs with the launcher's glibc settings (frame buffers reused, not re-mapped)."""
    from services.launcher import MALLOC_ENV

    environ = recorded_run["environ"]
    assert {"tracker", "detector", "recorder"} <= set(environ), sorted(environ)
    for name, env in environ.items():
        for k, v in MALLOC_ENV.items():
            assert env.get(k) == v, (name, k)


def test_every_service_exits_cleanly(recorded_run):
    r = recorded_run["result"]
    assert r.returncodes == {"ingest": 0, "tracker": 0, "viewer": None, "detector": 0, "recorder": 0}, \
        (recorded_run["dir"] / "tracker.log").read_text()[-2000:]
    assert r.estimates == FRAMES and r.frames == FRAMES
    assert r.mean_err < 3.0 and r.frames_lost == 0


def test_recording_holds_everything(recorded_run):
    rec = read_recording(recorded_run["result"].mcap)
    n = {k: len(v) for k, v in rec.messages.items()}
    assert n["frame/image"] == FRAMES
    assert n["frame/info"] == FRAMES + 1  # and the end-of-stream marker
    assert n["track/estimate"] == FRAMES and n["track/particles"] == FRAMES == n["track/annotations"]
    queries = rec.decoded("detector/query")
    replies = rec.decoded("detector/reply")
    at = [q for q in queries if q.kind == ScoreQuery.AT]
    assert sorted(q.frame_index for q in at) == list(range(FRAMES))  # one batched query per tracked frame
    assert all(q.count == 200 for q in at)  # all the particles in it
    assert len([q for q in queries if q.kind == ScoreQuery.TEMPLATE]) == 1
    assert len(replies) == len(queries) and all(r.status == ScoreReply.OK for r in replies)
    assert n["template"] == 1
    # the capture time is the log time of everything about a frame
    infos = {i.index: i for i in rec.decoded("frame/info") if not i.end_of_stream}
    est_times = [t for t, _ in rec.messages["track/estimate"]]
    assert est_times == [infos[i].capture_ns for i in range(FRAMES)]
    run = rec.run
    assert run["source"] == SOURCE and json.loads(run["init_box"]) == list(recorded_run["init"])
    assert json.loads(run["settings_json"]) == recorded_run["settings"].model_dump(mode="json")
    assert int(run["seed"]) == 3 and "numpy" in json.loads(run["versions_json"])


def test_recording_draws_the_track_in_foxglove(recorded_run):
    """``track/annotations``: one foxglove.ImageAnnotations per estimate, read back through the
    file's own schema (as Foxglove reads it, not through our classes), stamped with the frame's
    capture time, equal to the estimate: its oriented box's corners, a circle at its centre, a
    p(visible) label; the frame's true box; the particle cloud's points."""
    import math

    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    from common.msgs.convert import msg_to_cloud
    from common.tracking.state import oriented_box_corners

    path = recorded_run["result"].mcap
    with open(path, "rb") as fh:
        got = [(schema.name, schema.encoding, msg.log_time, dec)
               for schema, _ch, msg, dec in make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
                   topics=["track/annotations"])]
    assert len(got) == FRAMES and {(g[0], g[1]) for g in got} == {("foxglove.ImageAnnotations", "protobuf")}
    rec = read_recording(path)
    ests = {e.frame_index: (t, e) for (t, _), e in zip(rec.messages["track/estimate"], rec.decoded("track/estimate"))}
    infos = {i.capture_ns: i for i in rec.decoded("frame/info") if not i.end_of_stream}
    clouds = {c.frame_index: c for c in rec.decoded("track/particles")}
    by_time = {t: e for t, e in ests.values()}
    for _name, _enc, log_time, ann in got:
        e, info = by_time[log_time], infos[log_time]
        stamps = {p.timestamp.ToNanoseconds() for p in ann.points} | {c.timestamp.ToNanoseconds() for c in ann.circles}
        assert stamps == {info.capture_ns}
        loops = [p for p in ann.points if p.type == p.LINE_LOOP]
        truth, box = loops  # the truth's box first, then the estimate's
        t = info.truth
        assert [(q.x, q.y) for q in truth.points] == [(t.box_x, t.box_y), (t.box_x + t.box_w, t.box_y),
                                                      (t.box_x + t.box_w, t.box_y + t.box_h), (t.box_x, t.box_y + t.box_h)]
        assert e.w > 0 and [(q.x, q.y) for q in box.points] == oriented_box_corners(e.x, e.y, e.w, e.h, e.theta_deg)
        assert [(c.position.x, c.position.y) for c in ann.circles] == [(e.x, e.y)]
        assert ann.texts[0].text.startswith(f"p(visible) {e.p_visible:.2f}")
        (cloud_pts,) = [p for p in ann.points if p.type == p.POINTS]
        c = clouds[e.frame_index]
        xy = msg_to_cloud(c).image_xy
        assert [(q.x, q.y) for q in cloud_pts.points] == [tuple(v) for v in xy.tolist()]
        assert not math.isnan(box.points[0].x)


def test_run_config_decodes_typed_from_the_recording_alone(recorded_run):
    """A generic MCAP reader decodes run/config from the schema the file carries (struct.proto
    included): the settings field by field, as the run used them."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    with open(recorded_run["result"].mcap, "rb") as fh:
        (cfg,) = [dec for _s, _c, _m, dec in make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
            topics=["run/config"])]
    settings = recorded_run["settings"]
    assert cfg.settings["filter"] == settings.filter and cfg.settings["rbpf"]["n_particles"] == settings.rbpf.n_particles
    assert cfg.versions["numpy"] and not cfg.settings_json  # typed, not JSON text


def test_multiprocess_equals_in_process(recorded_run):
    rec = read_recording(recorded_run["result"].mcap)
    ests = sorted(rec.decoded("track/estimate"), key=lambda e: e.frame_index)
    src = open_source(SOURCE, n_frames=FRAMES)
    states = [s for _, s in track_frames(src, recorded_run["init"], recorded_run["settings"])]
    assert len(states) == len(ests)
    for e, s in zip(ests, states):
        assert (e.x, e.y, e.theta_deg, e.p_visible, e.world_x, e.n_eff) == (
            s.map_estimate.image_x, s.map_estimate.image_y, s.map_estimate.theta, s.p_visible,
            s.map_estimate.x, s.n_eff)


def test_offline_replay_is_bit_identical(recorded_run):
    out = offline_retrack(recorded_run["result"].mcap)
    assert out["identical"] and out["compared"] == FRAMES and out["query_mismatch"] == 0


def test_retrack_with_live_detector_is_bit_identical(recorded_run):
    from services.replay import retrack

    out = retrack(recorded_run["result"].mcap, timeout=120)
    assert out["identical"], out
    assert out["compared"] == FRAMES


def test_replay_detects_a_changed_estimate(recorded_run, tmp_path):
    """Negative control: tamper with one recorded estimate; the replay must say so."""
    def edit(topic, data):
        if topic == "track/estimate":
            e = Estimate.FromString(data)
            if e.frame_index == 5:
                e.x = np.nextafter(e.x, np.inf)  # one ulp
                return e.SerializeToString()
        return data

    dst = tmp_path / "tampered.mcap"
    rewrite_mcap(recorded_run["result"].mcap, dst, edit)
    out = offline_retrack(str(dst))
    assert not out["identical"] and out["mismatched"] == [5]


def test_no_zenoh_shared_memory_left(recorded_run):
    from services.shm_files import segment_files

    assert recorded_run["shm_used"], "the services mapped no shared-memory segment mid-run"
    assert not (segment_files() & recorded_run["shm_used"])


def test_detector_killed_and_restarted(tmp_path):
    """The tracker predicts the frames sent while the detector is gone and recovers when one is
    back; ingest holds the source meanwhile, and the recording holds every frame
    (:class:`tests.outage.DetectorOutage`: killed at frame 8, the source stopped before frame 9
    until then, and started again at once)."""
    frames = 40
    src = open_source(SOURCE, n_frames=frames)
    settings = profile_for(src, seed=3)
    inject = DetectorOutage(8)

    with Pipeline(SOURCE, src.frame(0).truth.box, settings, out_dir=tmp_path, frames=frames, viewer=False,
                  log_dir=tmp_path, supervise=False, ingest_options=inject.ingest_options) as pipe:  # restarted by hand here (supervised: test_services_supervision)
        result = pipe.run(progress=False, timeout=300, on_estimate=inject)
        published = pipe.statuses["ingest"].published
    rec = read_recording(result.mcap)
    report = outage_report(rec, tmp_path)
    ests = sorted(rec.decoded("track/estimate"), key=lambda e: e.frame_index)
    assert [e.frame_index for e in ests] == list(range(frames)) and published == frames, report  # never stopped
    unobserved = inject.check(ests, report)  # predicted only while the detector was gone
    print(f"killed at frame {inject.events[0][1]}: frames {unobserved} predicted")
    assert "held until one is back" in (tmp_path / "ingest.log").read_text(), report
    assert ests[-1].p_visible > 0.9, report  # and recovered when it came back
    infos = {i.index: i for i in rec.decoded("frame/info") if not i.end_of_stream}
    last = ests[-1]
    assert np.hypot(last.x - infos[last.frame_index].truth.centre_x, last.y - infos[last.frame_index].truth.centre_y) < 5
    assert len(rec.messages["frame/image"]) == published  # every frame published is in the recording
    assert result.returncodes["tracker"] == 0 and result.returncodes["recorder"] == 0


def test_recorder_killed_leaves_a_readable_file(synthetic_pipeline):
    from mcap.reader import NonSeekingReader

    frames = 30

    def kill_recorder(pipe, est):
        if est.frame_index == 20:
            pipe.procs["recorder"].send_signal(signal.SIGKILL)

    with synthetic_pipeline(SOURCE, frames) as pipe:
        pipe.run(progress=False, timeout=300, on_estimate=kill_recorder)
        path = pipe.mcap
    n = 0
    with open(path, "rb") as fh:
        try:
            for _schema, channel, _msg in NonSeekingReader(fh).iter_messages(log_time_order=False):
                n += channel.topic == "frame/image"
        except Exception:  # noqa: BLE001 - the file ends mid-chunk: everything before is readable
            pass
    assert n >= 5  # the frames of every complete chunk survive (a 4 MB chunk holds one raw frame)


def test_killed_services_leave_no_shared_memory(synthetic_pipeline):
    """The frames go through Zenoh shared memory; a service killed mid-run (SIGKILL: no clean-up
    of its own) leaves no segment file once the run is over."""
    from services.shm_files import segment_files, segments_mapped_by

    frames = 20
    during: set[str] = set()

    def kill(pipe, est):
        if est.frame_index == 8 and not during:
            during.update(segments_mapped_by(p.pid for p in pipe.procs.values()))
            for service in ("detector", "recorder"):
                pipe.procs[service].send_signal(signal.SIGKILL)
                pipe.procs[service].wait(10)

    with synthetic_pipeline(SOURCE, frames) as pipe:
        result = pipe.run(progress=False, timeout=300, on_estimate=kill)
    # both restarted by the launcher (their new processes stopped at the end)
    assert [(r["service"], r["status"]) for r in result.restarts] == [("detector", -signal.SIGKILL),
                                                                      ("recorder", -signal.SIGKILL)]
    assert result.failure is None and not result.ok
    assert during, "no shared-memory segment while frames were flowing"
    assert not (segment_files() & during)
