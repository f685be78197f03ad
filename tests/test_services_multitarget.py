"""Multi-target tracking through the pipeline: ``polartrack run --filter epmcmc-elpda`` on the people
scene, the real services as separate processes on a private loopback Zenoh network. The tracker
asks the detector service every colour-histogram question (HISTOGRAMS / SIMILARITY queries), the
recorder records them with the multi-target estimates, and the estimates equal the in-process
filter's bit for bit; ``replay --offline`` and ``--retrack`` reproduce them; the detector answers
malformed histogram queries with an error reply and counts them."""

import subprocess
import sys
import time

import numpy as np
import pytest

from common.msgs import ScoreQuery, ScoreReply, ServiceStatus, pack
from common.msgs.image_wire import encode_image
from common.multitarget import HistogramEvidence
from common.msgs.convert import multi_estimate_msg
from common.multitarget.runner import MultiRun, track_frames
from common.record.retrack import same_multi_estimate
from common.record.retrack import offline_retrack
from common.record.reader import read_recording
from common.sources import open_source
from services.bus import Inbox, ns_attachment, open_session, payload_bytes, publisher, wait_for_alive
from services.launcher import Pipeline, client_args, free_ports, router_config, stop_process
from tests.outage import DetectorOutage, outage_report

pytestmark = pytest.mark.slow  # services as separate processes on a loopback bus

SOURCE = "people:3:3"  # seed 3, three people
FRAMES = 10
PARTS = 2
PARTICLES = 16


def multi_run(seed=0, method="epmcmc-elpda"):
    return MultiRun.make(method, open_source(SOURCE, n_frames=FRAMES).person_boxes(), seed=seed, n_parts=PARTS,
                         particles=PARTICLES)


def in_process(run):
    return [multi_estimate_msg(f.index, s, run) for f, s in track_frames(open_source(SOURCE, n_frames=FRAMES), run)]


@pytest.fixture(scope="module")
def multi_pipeline(tmp_path_factory):
    out = tmp_path_factory.mktemp("multi")
    run = multi_run()
    from common.settings import TrackerSettings

    with Pipeline(SOURCE, None, TrackerSettings(), out_dir=out, frames=FRAMES, viewer=False, log_dir=out,
                  multi=run) as pipe:
        result = pipe.run(progress=False, timeout=240)
    return {"result": result, "run": run, "dir": out, "rec": read_recording(result.mcap)}


def test_the_recording_holds_frames_estimates_and_histogram_queries(multi_pipeline):
    r, rec = multi_pipeline["result"], multi_pipeline["rec"]
    assert r.returncodes == {"ingest": 0, "tracker": 0, "viewer": None, "detector": 0, "recorder": 0}, \
        (multi_pipeline["dir"] / "tracker.log").read_text()[-2000:]
    infos = [i for i in rec.decoded("frame/info") if not i.end_of_stream]
    assert [i.index for i in infos] == list(range(FRAMES)) and len(rec.messages["frame/image"]) == FRAMES
    assert all(i.truth_people == 3 for i in infos)  # the people scene's part truth travels with the frames
    est = sorted(rec.decoded("track/multi_estimate"), key=lambda e: e.frame_index)
    assert [e.frame_index for e in est] == list(range(FRAMES))
    assert all(e.targets == 3 and e.parts == PARTS and e.filter == "epmcmc-elpda" for e in est)
    assert not rec.messages.get("track/estimate")  # no single-target estimates
    queries, replies = rec.decoded("detector/query"), rec.decoded("detector/reply")
    kinds = [q.kind for q in queries]
    hist = sorted(q.frame_index for q in queries if q.kind == ScoreQuery.HISTOGRAMS)
    assert hist.count(0) >= 3  # first frame: the placement in the boxes (surroundings, shifts), the references
    assert len(set(hist[3:])) == len(hist[3:])  # then one a frame at most: who stands in front where targets overlap
    assert kinds.count(ScoreQuery.SIMILARITY) >= 2 * FRAMES  # gating and weighting, every frame
    assert {q.frame_index for q in queries} == set(range(FRAMES))
    assert len(replies) == len(queries) and all(rep.status == ScoreReply.OK for rep in replies)
    assert {(q.client, q.request_id) for q in queries} == {(p.client, p.request_id) for p in replies}
    assert rec.run["multi_json"] and MultiRun.from_json(rec.run["multi_json"]) == multi_pipeline["run"]
    assert r.mean_err is not None and r.mean_err < 25.0  # mean part error against the scene's truth


def test_the_run_summary_scores_every_frame_against_its_truth(multi_pipeline):
    """The launcher's mean part error is every frame's, recomputed from the recording (an estimate
    that overtook its frame's truth on the way to the launcher is scored too, not left out)."""
    import numpy as np

    from common.msgs import unpack
    from common.multitarget.runner import people_truth_parts

    r, rec = multi_pipeline["result"], multi_pipeline["rec"]
    infos = {i.index: i for i in rec.decoded("frame/info") if not i.end_of_stream}
    per_frame = []
    for e in rec.decoded("track/multi_estimate"):
        pos = unpack(e.positions, np.float64, (e.targets, e.parts, 2))
        gt = people_truth_parts(infos[e.frame_index], PARTS)
        per_frame.append(np.mean(np.linalg.norm(pos - gt, axis=-1)))
    assert r.estimates == len(per_frame) == FRAMES
    assert r.mean_err == pytest.approx(float(np.mean(per_frame)), rel=1e-12)


def test_the_recording_draws_every_person_in_foxglove(multi_pipeline):
    """``track/annotations`` (foxglove.ImageAnnotations), one per multi-target estimate at its
    log time: each target's parts as points and its skeleton (part to parent) as a line list."""
    import numpy as np

    from common.msgs import unpack

    rec = multi_pipeline["rec"]
    est = {t: e for (t, _), e in zip(rec.messages["track/multi_estimate"], rec.decoded("track/multi_estimate"))}
    anns = list(zip((t for t, _ in rec.messages["track/annotations"]), rec.decoded("track/annotations")))
    assert sorted(t for t, _ in anns) == sorted(est)
    for t, ann in anns:
        e = est[t]
        pos = unpack(e.positions, np.float64, (e.targets, e.parts, 2))
        parents = unpack(e.parents, np.int32, (e.parts,))
        points = [p for p in ann.points if p.type == p.POINTS]
        lines = [p for p in ann.points if p.type == p.LINE_LIST]
        assert len(points) == len(lines) == e.targets == 3
        for k in range(e.targets):
            assert [(q.x, q.y) for q in points[k].points] == [tuple(v) for v in pos[k].tolist()]
            bones = [(i, j) for i, j in enumerate(parents) if j >= 0]
            want = [tuple(pos[k][n]) for i, j in bones for n in (i, j)]
            assert [(q.x, q.y) for q in lines[k].points] == want and len(want) == 2 * (e.parts - 1)
        assert {p.timestamp.ToNanoseconds() for p in ann.points} == {t}


def test_run_equals_in_process_bit_for_bit(multi_pipeline):
    got = sorted(multi_pipeline["rec"].decoded("track/multi_estimate"), key=lambda e: e.frame_index)
    expected = in_process(multi_pipeline["run"])
    assert len(got) == len(expected) == FRAMES
    assert [e.frame_index for e, x in zip(got, expected) if not same_multi_estimate(e, x)] == []


def test_the_comparison_tells_another_seed_apart(multi_pipeline):
    """Negative control: the in-process filter with another seed gives other estimates."""
    got = sorted(multi_pipeline["rec"].decoded("track/multi_estimate"), key=lambda e: e.frame_index)
    other = in_process(multi_run(seed=1))
    assert sum(not same_multi_estimate(e, x) for e, x in zip(got, other)) >= FRAMES - 1


def test_offline_replay_is_bit_identical(multi_pipeline):
    out = offline_retrack(multi_pipeline["result"].mcap)
    assert out["identical"] and out["compared"] == FRAMES, out
    assert out["query_mismatch"] == 0 and out["unanswered"] == 0


def test_offline_replay_detects_a_changed_reply(multi_pipeline, tmp_path):
    """A recording whose similarity replies were altered does not replay identically."""
    from parity import rewrite_mcap

    def edit(topic, data):
        if topic != "detector/reply":
            return data
        rep = ScoreReply.FromString(data)
        if rep.dtype == "float64" and rep.frame_index == 5 and rep.count:
            s = np.frombuffer(rep.scores, "<f8").copy()
            s *= 0.9
            rep.scores = s.tobytes()
        return rep.SerializeToString()

    bad = tmp_path / "changed.mcap"
    rewrite_mcap(multi_pipeline["result"].mcap, bad, edit)
    out = offline_retrack(str(bad))
    assert not out["identical"] and 5 in out["mismatched"]


def test_retrack_with_a_live_detector_is_bit_identical(multi_pipeline, tmp_path):
    from services.replay import retrack

    out = retrack(multi_pipeline["result"].mcap, timeout=120, log_dir=str(tmp_path))
    assert out["identical"] and out["compared"] == FRAMES, out


def test_the_recording_converts_to_rerun_with_skeletons(multi_pipeline, tmp_path):
    from collections import Counter

    from rerun.chunk import RrdReader

    from common.record.rerun import mcap_to_rrd

    rrd = tmp_path / "multi.rrd"
    stats = mcap_to_rrd(multi_pipeline["result"].mcap, rrd)
    assert stats["multi_estimates"] == FRAMES and stats["malformed"] == 0
    rows = Counter()
    for chunk in RrdReader(rrd).stream().to_chunks():
        if not chunk.is_static and "frame" in chunk.timeline_names:
            rows[chunk.entity_path] += chunk.num_rows
    for t in range(3):
        for what in ("parts", "skeleton"):
            assert rows[f"/camera/targets/{t}/{what}"] == FRAMES
            assert rows[f"/camera/people_truth/{t}/{what}"] == FRAMES
        assert rows[f"/plots/error/target_{t}"] == FRAMES


@pytest.fixture()
def detector(tmp_path):
    hub = free_ports(1)[0]
    bus = router_config(hub, f"multifaults{hub}")
    session = open_session(bus)
    log = open(tmp_path / "detector.log", "ab")
    proc = subprocess.Popen([sys.executable, "-m", "services.detector", "--stream", bus.stream, *client_args(hub)],
                            stdout=log, stderr=subprocess.STDOUT)
    try:
        yield bus, session, proc
    finally:
        stop_process(proc)
        session.close()
        log.close()


def _ask(session, bus, q: ScoreQuery) -> ScoreReply | None:
    for r in session.get(bus.key("detector/score"), payload=q.SerializeToString(), timeout=5.0):
        if r.ok is not None:
            return ScoreReply.FromString(r.ok.payload.to_bytes())
    return None


def test_detector_answers_malformed_histogram_queries_with_errors(detector):
    bus, session, proc = detector
    assert wait_for_alive(session, bus, ["detector"], 60)
    inbox = Inbox()
    session.declare_subscriber(bus.key("status/detector"), inbox.callback("status"))
    frame = open_source(SOURCE, n_frames=FRAMES).frame(0)
    publisher(session, bus.key("frame/image")).put(encode_image(frame.image, 1000, 0), attachment=ns_attachment(1000))
    time.sleep(0.5)
    ev = HistogramEvidence(frame.image)
    boxes = np.array([[100.0, 100.0, 120.0, 140.0], [200.5, 90.2, 230.7, 160.1]])
    refs = ev.histograms(boxes)

    def sim(**kw):
        fields = dict(request_id=1, client="t", frame_index=0, kind=ScoreQuery.SIMILARITY, count=2,
                      hypotheses=pack(boxes), reference_count=2, bins=refs.shape[1],
                      references=pack(refs), ref_index=pack(np.array([1, 0]), np.int64))
        fields.update(kw)
        return _ask(session, bus, ScoreQuery(**fields))

    nan_boxes = boxes.copy()
    nan_boxes[1, 2] = np.nan
    r = sim(hypotheses=pack(nan_boxes))
    assert r.status == ScoreReply.BAD_REQUEST and "NaN" in r.error
    r = sim(count=5)  # the count says 5 boxes, the bytes hold 2
    assert r.status == ScoreReply.BAD_REQUEST and "bytes" in r.error
    r = sim(bins=7)
    assert r.status == ScoreReply.BAD_REQUEST and "bins" in r.error
    r = sim(ref_index=pack(np.array([0, 2]), np.int64))
    assert r.status == ScoreReply.BAD_REQUEST and "ref_index" in r.error
    r = sim(histogram_json="{not json")
    assert r.status == ScoreReply.BAD_REQUEST
    r = sim(frame_index=99)
    assert r.status == ScoreReply.UNKNOWN_FRAME
    # and it still answers, with the in-process numbers, bit for bit
    r = sim(request_id=7)
    assert r.status == ScoreReply.OK and r.request_id == 7 and r.dtype == "float64"
    assert np.array_equal(np.frombuffer(r.scores, "<f8"), ev.similarity(boxes, refs, np.array([1, 0])))
    h = _ask(session, bus, ScoreQuery(request_id=8, client="t", frame_index=0, kind=ScoreQuery.HISTOGRAMS, count=2,
                                      hypotheses=pack(boxes)))
    assert h.status == ScoreReply.OK and h.dtype == "float32"
    assert np.array_equal(np.frombuffer(h.scores, "<f4").reshape(2, -1), refs)
    assert proc.poll() is None
    status = None
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline and (status is None or status.malformed < 6):
        inbox.wait(0.5)
        while (s := inbox.pop("status")) is not None:
            status = ServiceStatus.FromString(payload_bytes(s))
    assert status is not None and status.malformed >= 6  # NaN, sizes, bins, ref_index, config, unknown frame


def test_detector_killed_and_restarted_multi(tmp_path):
    """Without the detector the multi-target tracker reports the frames sent meanwhile as
    predictions (``observed`` false) and weighs again once a new detector is up; ingest holds the
    source meanwhile; nothing stops (:class:`tests.outage.DetectorOutage`: killed at frame 4)."""
    from common.settings import TrackerSettings

    frames = 16
    inject = DetectorOutage(4)

    run = MultiRun.make("epmcmc-elpda", open_source(SOURCE, n_frames=frames).person_boxes(), n_parts=PARTS,
                        particles=PARTICLES)
    with Pipeline(SOURCE, None, TrackerSettings(), out_dir=tmp_path, frames=frames, viewer=False, log_dir=tmp_path,
                  multi=run, supervise=False, ingest_options=inject.ingest_options) as pipe:  # restarted by hand here
        result = pipe.run(progress=False, timeout=300, on_estimate=inject)
    rec = read_recording(result.mcap)
    report = outage_report(rec, tmp_path, "track/multi_estimate")
    ests = sorted(rec.decoded("track/multi_estimate"), key=lambda e: e.frame_index)
    assert [e.frame_index for e in ests] == list(range(frames)), report
    inject.check(ests, report)
    assert "held until one is back" in (tmp_path / "ingest.log").read_text(), report
    assert result.returncodes["tracker"] == 0 and result.returncodes["recorder"] == 0
