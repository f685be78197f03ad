"""A run under fire: over a thousand malformed messages on every key a run uses (and malformed
queries of every kind) sent with the run's own sender ids, then forged-but-valid messages from a
foreign sender (a second queryable answering with fake scores, frames and infos with upcoming
indices, estimates, an end of stream, a template, a status). Nothing crashes, every frame is
estimated and recorded once, the bad ones are counted per key, and the estimates are those of
the in-process tracker, bit for bit. Loopback only: the run's private router, the test's own
client session (explicit endpoint, multicast scouting off); seeded; bounded in count and time."""

import threading
import time

import numpy as np
import pytest
import zenoh

from common.msgs import (Estimate, FrameInfo, ImageAnnotations, MultiEstimate, ParticleCloud, RawImage, RunConfig, ScoreQuery,
                         ScoreReply, ServiceStatus, Template, pack)
from common.msgs.convert import image_to_msg
from common.record.reader import read_recording
from common.single_target.runner import track_frames
from common.settings import profile_for
from common.sources import open_source
from services.bus import BusConfig, attachment_sender, open_session
from services.launcher import Pipeline

pytestmark = pytest.mark.slow  # services as separate processes on a loopback bus

SOURCE = "synthetic:3"
FRAMES = 40
SEED = 17


def attachment(ns: int, sender: str) -> bytes:
    return int(ns).to_bytes(8, "little", signed=True) + sender.encode()


def undecodable(rng, cls) -> bytes:
    """Random bytes that are not a ``cls``."""
    while True:
        b = rng.bytes(int(rng.integers(2, 200)))
        try:
            cls.FromString(b)
        except Exception:  # noqa: BLE001
            return b


@pytest.fixture(scope="module")
def expected():
    """The in-process tracker's estimates on the same frames (what every run here must equal)."""
    src = open_source(SOURCE, n_frames=FRAMES)
    settings = profile_for(src, seed=3)
    states = [s for _, s in track_frames(src, src.frame(0).truth.box, settings)]
    return settings, src.frame(0).truth.box, [
        (s.map_estimate.image_x, s.map_estimate.image_y, s.map_estimate.theta, s.p_visible, s.map_estimate.x, s.n_eff)
        for s in states]


def estimates_of(path):
    rec = read_recording(path)
    ests = sorted(rec.decoded("track/estimate"), key=lambda e: e.frame_index)
    return rec, ests, [(e.x, e.y, e.theta_deg, e.p_visible, e.world_x, e.n_eff) for e in ests]


def frame_ids(rec) -> list[int]:
    """The frame index of every recorded frame image, and each image's frame_id the one camera's."""
    from common.msgs.image_wire import CAMERA_FRAME, decode_frame

    decoded = [decode_frame(data)[:2] for _, data in rec.messages["frame/image"]]
    assert {msg.frame_id for _, msg in decoded} == {CAMERA_FRAME}
    return [index for index, _ in decoded]


def client_session(pipe):
    return open_session(BusConfig(stream=pipe.stream, mode="client", connect=[f"tcp/127.0.0.1:{pipe.hub_port}"]))


def run_with(pipe_kwargs, attack, tmp_path, pause_at=30, timeout=300):
    """A run of FRAMES frames; ``attack(pipe, stop, armed)`` runs in a thread from the first
    estimate, the source held (``Pipeline.pause_source``) until the attack has set up (``armed``), so that it goes
    on while frames flow; at frame ``pause_at`` the source waits again until the attack is over
    (every message of it sent while the run goes on)."""
    src = open_source(SOURCE, n_frames=FRAMES)
    box = src.frame(0).truth.box
    started: list[threading.Thread] = []
    stop, armed = threading.Event(), threading.Event()
    out = {}

    def paused(pipe, until):
        pipe.pause_source()
        try:
            until()
        finally:
            pipe.resume_source()

    def on_estimate(pipe, est):
        if not started:
            t = threading.Thread(target=lambda: out.setdefault("attack", attack(pipe, stop, armed)), daemon=True)
            t.start()
            started.append(t)
            paused(pipe, lambda: armed.wait(60))
        elif est.frame_index >= pause_at and "paused" not in out:
            out["paused"] = est.frame_index
            paused(pipe, lambda: started[0].join(120))

    with Pipeline(SOURCE, box, profile_for(src, seed=3), out_dir=tmp_path, frames=FRAMES, log_dir=tmp_path,
                  **pipe_kwargs) as pipe:
        result = pipe.run(progress=False, timeout=timeout, on_estimate=on_estimate)
        stop.set()
        if started:
            started[0].join(30)
    return result, out.get("attack")


# --------------------------------------------------------------------------- malformed, run's ids

def fuzz(pipe, stop, armed) -> dict:
    """Over 1,000 malformed messages on every key of a run, with the ids of the run's services
    that speak there (as a broken service of the run would send them), and malformed queries of
    every kind. Returns how many went to each key, and the replies to the queries."""
    rng = np.random.default_rng(SEED)
    ids = pipe.ids
    sent: dict[str, int] = {}
    replies: list = []
    frame = open_source(SOURCE, n_frames=1).frame(0)
    with client_session(pipe) as session:
        def put(key, data, sender):
            session.put(f"polartrack/{pipe.stream}/{key}", data, attachment=attachment(time.time_ns(), ids.get(sender, sender)),
                        congestion_control=zenoh.CongestionControl.BLOCK)  # every one delivered: counted exactly
            sent[key] = sent.get(key, 0) + 1

        def bad_infos():
            nan = float("nan")
            yield FrameInfo(index=10**6, time_s=nan, width=1280, height=720)
            yield FrameInfo(index=10**6, time_s=float("inf"), width=1280, height=720)
            yield FrameInfo(index=10**6, time_s=-5.0, width=1280, height=720)
            yield FrameInfo(index=0, time_s=0.0, width=1280, height=720)  # an old frame replayed
            yield FrameInfo(index=10**6, time_s=1e6, width=1280, height=720, capture_ns=10**18)  # far ahead
            z = FrameInfo(index=10**6, time_s=1e6, width=0, height=720)
            yield z
            h = FrameInfo(index=0, time_s=0.0, width=1280, height=720)
            h.homography.extend([0.0] * 9)
            yield h
            yield FrameInfo(index=0, end_of_stream=True)  # an end of stream before the last frame

        infos = list(bad_infos())
        cut = image_to_msg(frame.image, 1, "0")
        cut.data = cut.data[:999]
        old = image_to_msg(frame.image, 1, "0").SerializeToString()  # frame 0 again
        keys = {  # key: (speaker, [payload makers])
            "frame/info": ("ingest", [lambda: undecodable(rng, FrameInfo),
                                      lambda: infos[int(rng.integers(len(infos)))].SerializeToString()]),
            "frame/image": ("ingest", [lambda: undecodable(rng, RawImage), lambda: cut.SerializeToString(),
                                       lambda: old]),
            "track/estimate": ("tracker", [lambda: undecodable(rng, Estimate),
                                           lambda: Estimate(frame_index=10**9, x=1.0, y=1.0).SerializeToString(),
                                           lambda: Estimate(frame_index=0, x=float("nan")).SerializeToString()]),
            "track/multi_estimate": ("tracker", [lambda: undecodable(rng, MultiEstimate)]),
            "track/particles": ("tracker", [lambda: undecodable(rng, ParticleCloud)]),
            "track/annotations": ("recorder", [lambda: undecodable(rng, ImageAnnotations)]),
            "template": ("tracker", [lambda: undecodable(rng, Template)]),
            "detector/query": ("detector", [lambda: undecodable(rng, ScoreQuery)]),
            "detector/reply": ("detector", [lambda: undecodable(rng, ScoreReply)]),
            "run/config": ("ingest", [lambda: undecodable(rng, RunConfig)]),
            "status/detector": ("detector", [lambda: undecodable(rng, ServiceStatus),
                                             lambda: ServiceStatus(service="tracker").SerializeToString(),
                                             lambda: ServiceStatus(service="detector",
                                                                   cpu_s=float("nan")).SerializeToString()]),
            "health/tracker": ("tracker", [lambda: rng.bytes(int(rng.integers(1, 100))) + b"}"]),
            "evil/blob": ("ingest", [lambda: rng.bytes(64 << 10)]),  # not a topic of the run
        }
        per_key = 90
        armed.set()
        for i in range(per_key):
            for key, (speaker, makers) in keys.items():
                put(key, makers[i % len(makers)](), speaker)
            time.sleep(0.01)  # spread over the run (a burst of images would push real ones out of the detector's queue)
        put("frame/info", b"\x00" * (2 << 20), "ingest")  # over the size caps
        put("status/detector", b"\x00" * (2 << 20), "detector")
        put("frame/image", b"\x00" * (33 << 20), "ingest")

        # malformed queries of every kind, with the tracker's id (each one answered with an error)
        hyps = pack(np.zeros((2, 3)))
        queries = [b"\x08\x96\x01garbage\xff\xff",
                   ScoreQuery(request_id=1, client="fuzz", kind=ScoreQuery.AT, count=5, hypotheses=hyps),
                   ScoreQuery(request_id=2, client="fuzz", kind=ScoreQuery.AT, count=1,
                              hypotheses=pack(np.array([[np.nan, 1.0, 0.0]]))),
                   ScoreQuery(request_id=3, client="fuzz", kind=ScoreQuery.AT, count=10**6),
                   ScoreQuery(request_id=4, client="x" * 100, kind=ScoreQuery.AT, count=1),
                   ScoreQuery(request_id=5, client="fuzz", kind=99, count=1, hypotheses=pack(np.zeros((1, 3)))),
                   ScoreQuery(request_id=6, client="fuzz", kind=ScoreQuery.HISTOGRAMS, count=1,
                              hypotheses=pack(np.array([[np.nan, 0, 4, 4]]))),
                   ScoreQuery(request_id=7, client="fuzz", kind=ScoreQuery.AT, factor=1e9, count=1,
                              hypotheses=pack(np.zeros((1, 3)))),
                   ScoreQuery(request_id=8, client="fuzz", frame_index=10**6, kind=ScoreQuery.AT, count=1,
                              hypotheses=pack(np.zeros((1, 3))))]  # an unknown frame: waits, never blocks
        handlers = []
        for i in range(100):
            q = queries[i % len(queries)]
            payload = q if isinstance(q, bytes) else q.SerializeToString()
            handlers.append(session.get(f"polartrack/{pipe.stream}/detector/score", payload=payload, timeout=10.0,
                                        attachment=attachment(time.time_ns(), ids["tracker"])))
        for h in handlers:
            got = [ScoreReply.FromString(r.ok.payload.to_bytes()) for r in h if r.ok is not None]
            replies.append(got)
    return {"sent": sent, "replies": replies}


@pytest.fixture(scope="module")
def fuzzed_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("fuzz")
    t0 = time.monotonic()
    result, attack = run_with({"viewer": True}, fuzz, tmp)
    return {"result": result, "attack": attack, "wall_s": time.monotonic() - t0, "dir": tmp}


def test_fuzz_crashes_nothing_and_every_frame_is_estimated_and_recorded(fuzzed_run, expected):
    r, attack = fuzzed_run["result"], fuzzed_run["attack"]
    assert attack is not None, "the fuzzer never ran"
    assert sum(attack["sent"].values()) >= 1000 and len(attack["sent"]) >= 12
    assert r.failure is None and r.restarts == [] and r.ok, (r.failure, r.returncodes)
    assert r.returncodes == {"ingest": 0, "tracker": 0, "viewer": 0, "detector": 0, "recorder": 0}
    assert r.estimates == FRAMES
    rec, ests, values = estimates_of(r.mcap)
    assert [e.frame_index for e in ests] == list(range(FRAMES))
    assert sorted(frame_ids(rec)) == list(range(FRAMES))
    infos = rec.decoded("frame/info")
    assert [i.index for i in infos] == list(range(FRAMES + 1)) and [i.end_of_stream for i in infos].count(True) == 1
    assert "evil/blob" not in rec.messages and "health/tracker" not in rec.messages
    assert values == expected[2]  # bit for bit: nothing of it reached the filter


def test_fuzz_every_malformed_message_is_counted_per_key(fuzzed_run):
    r, sent = fuzzed_run["result"], fuzzed_run["attack"]["sent"]
    rej = r.rejected
    total = {svc: {k: sum(v.values()) for k, v in table.items()} for svc, table in rej.items()}
    # the recorder hears every key: each malformed message dropped and counted once
    for key, n in sent.items():
        assert total["recorder"].get(key, 0) == n or (key == "health/tracker" and key not in total["recorder"]), key
    # the launcher reads infos, estimates, statuses and health reports: each one it got, dropped
    for key in ("frame/info", "track/estimate", "track/multi_estimate", "status/detector", "health/tracker"):
        assert total["launcher"][key] == sent[key], key
    assert total["tracker"]["frame/info"] == sent["frame/info"]
    assert total["ingest"]["track/estimate"] == sent["track/estimate"]
    assert total["ingest"]["track/multi_estimate"] == sent["track/multi_estimate"]
    assert total["detector"]["frame/image"] == sent["frame/image"]
    assert total["detector"]["template"] == sent["template"]
    assert total["viewer"]["frame/info"] >= sent["frame/info"] - 1  # (the viewer may stop before the last)
    reasons = rej["tracker"]["frame/info"]
    assert {"undecodable", "bad_time", "index_not_increasing", "too_large", "bad_end_of_stream"} <= set(reasons)
    assert rej["launcher"]["track/estimate"].get("unknown_frame", 0) > 0


def test_fuzz_malformed_queries_each_get_an_error_reply(fuzzed_run):
    replies = fuzzed_run["attack"]["replies"]
    assert len(replies) == 100
    assert all(len(got) == 1 for got in replies), [len(g) for g in replies]
    statuses = [got[0].status for got in replies]
    assert ScoreReply.OK not in statuses
    assert statuses.count(ScoreReply.UNKNOWN_FRAME) == 11 and statuses.count(ScoreReply.BAD_REQUEST) == 89
    assert sum(fuzzed_run["result"].rejected["detector"]["detector/score"].values()) >= 89


# --------------------------------------------------------------------------- forged, foreign sender

def forge(pipe, stop, armed) -> dict:
    """Valid-looking messages from a process that is not one of the run's services."""
    src = open_source(SOURCE, n_frames=1)
    frame = src.frame(0)
    foreign = "f" * 16
    counts = {"rogue_replies": 0, "sent": 0, "foreign_query_replies": []}
    with client_session(pipe) as session:
        def rogue(query):  # a second queryable: fake, well-formed, confident scores, at once
            try:
                q = ScoreQuery.FromString(query.payload.to_bytes())
                n = q.count
                rep = ScoreReply(request_id=q.request_id, client=q.client, frame_index=q.frame_index,
                                 status=ScoreReply.OK, count=n, angles=1, scores=pack(np.ones(n)),
                                 valid=pack(np.ones(n), np.uint8))
                query.reply(query.key_expr, rep.SerializeToString(), attachment=attachment(time.time_ns(), foreign))
                counts["rogue_replies"] += 1
            except Exception as exc:  # noqa: BLE001
                counts.setdefault("rogue_errors", []).append(repr(exc))

        qable = session.declare_queryable(f"polartrack/{pipe.stream}/detector/score", rogue)
        time.sleep(0.3)  # known to the router before the source goes on
        armed.set()
        key = f"polartrack/{pipe.stream}/"
        i = 0
        while not stop.is_set() and i < 50:
            ahead = 5 + i  # upcoming frame ids
            att = attachment(time.time_ns(), foreign)
            info = FrameInfo(index=ahead, time_s=ahead / 30, capture_ns=time.time_ns(), width=frame.image.shape[1],
                             height=frame.image.shape[0])
            info.homography.extend(np.eye(3).ravel())
            for k, data in (("frame/image", image_to_msg(frame.image, time.time_ns(), str(ahead)).SerializeToString()),
                            ("frame/info", info.SerializeToString()),
                            ("frame/info", FrameInfo(index=ahead, end_of_stream=True).SerializeToString()),
                            ("track/estimate", Estimate(frame_index=10**9, x=5.0, y=5.0).SerializeToString()),
                            ("track/estimate", Estimate(frame_index=ahead, x=5.0, y=5.0).SerializeToString()),
                            ("status/detector", ServiceStatus(service="detector", final=True).SerializeToString())):
                session.put(key + k, data, attachment=att, congestion_control=zenoh.CongestionControl.BLOCK)
                counts["sent"] += 1
            session.put(key + "frame/info", FrameInfo(index=ahead + 1, end_of_stream=True).SerializeToString())  # no id
            counts["sent"] += 1
            if i % 10 == 0:  # a valid query in the tracker's name: refused, not answered from its caches
                q = ScoreQuery(request_id=1, client="tracker", frame_index=1, kind=ScoreQuery.AT, count=1,
                               hypotheses=pack(np.array([[600.0, 400.0, 0.0]])), template_version=1)
                got = [ScoreReply.FromString(r.ok.payload.to_bytes()).status
                       for r in session.get(key + "detector/score", payload=q.SerializeToString(), timeout=5.0,
                                            attachment=att)
                       if r.ok is not None and attachment_sender(r.ok) == pipe.ids["detector"]]
                counts["foreign_query_replies"].append(got)
            i += 1
            time.sleep(0.03)
        qable.undeclare()
    return counts


@pytest.fixture(scope="module")
def forged_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("forged")
    t0 = time.monotonic()
    result, attack = run_with({"viewer": False}, forge, tmp)
    return {"result": result, "attack": attack, "wall_s": time.monotonic() - t0}


def test_foreign_messages_leave_the_estimates_bit_identical(forged_run, expected):
    r, attack = forged_run["result"], forged_run["attack"]
    assert attack is not None and attack["sent"] >= 250 and attack["rogue_replies"] > 0, attack
    print({k: v for k, v in attack.items() if k != "foreign_query_replies"})
    assert r.failure is None and r.ok, (r.failure, r.returncodes)
    rec, ests, values = estimates_of(r.mcap)
    assert [e.frame_index for e in ests] == list(range(FRAMES))
    assert values == expected[2]
    ids = frame_ids(rec)
    assert sorted(ids) == list(range(FRAMES))  # no foreign frame recorded, none twice
    infos = rec.decoded("frame/info")
    assert [i.index for i in infos] == list(range(FRAMES + 1))
    assert all(e.frame_index < FRAMES for e in rec.decoded("track/estimate"))


def test_the_second_queryable_is_ignored_counted_and_reported(forged_run):
    r = forged_run["result"]
    # every fake reply that reached the tracker is counted (the rogue also answered the test's own queries)
    assert 0 < r.rejected["tracker"]["detector/score"]["foreign_sender"] <= forged_run["attack"]["rogue_replies"]
    assert r.rejected["recorder"]["frame/image"]["foreign_sender"] >= 1
    assert r.rejected["launcher"]["frame/info"]["foreign_sender"] >= 1
    assert r.rejected["detector"]["detector/score/query"]["foreign_sender"] >= 1
    replies = forged_run["attack"]["foreign_query_replies"]
    # a foreign query is never answered with scores: refused, or (a loaded machine) not answered in time
    assert all(set(statuses) <= {ScoreReply.BAD_REQUEST} for statuses in replies)
    assert any(statuses == [ScoreReply.BAD_REQUEST] for statuses in replies)
