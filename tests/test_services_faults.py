"""Malformed payloads are counted and logged, answered with an error where a reply is due, and
never stop a service. Real processes on a private loopback router started by the test."""

import subprocess
import sys
import time

import numpy as np
import pytest

from common.msgs import FrameInfo, ScoreQuery, ScoreReply, ServiceStatus, pack
from common.msgs.convert import image_to_msg
from common.sources import open_source
from services.bus import Inbox, ns_attachment, open_session, payload_bytes, publisher, wait_for_alive
from services.launcher import client_args, free_ports, router_config, stop_process

pytestmark = pytest.mark.slow  # services as separate processes on a loopback bus


@pytest.fixture()
def bus_with(tmp_path):
    hub = free_ports(1)[0]
    bus = router_config(hub, f"faults{hub}")
    session = open_session(bus)
    procs = []

    def start(name, *extra):
        log = open(tmp_path / f"{name}.log", "ab")
        p = subprocess.Popen([sys.executable, "-m", f"services.{name}", "--stream", bus.stream, *client_args(hub), *extra],
                             stdout=log, stderr=subprocess.STDOUT)
        procs.append(p)
        return p

    try:
        yield bus, session, start
    finally:
        for p in procs:
            stop_process(p)
        session.close()


def ask(session, bus, payload: bytes) -> ScoreReply | None:
    for r in session.get(bus.key("detector/score"), payload=payload, timeout=5.0):
        if r.ok is not None:
            return ScoreReply.FromString(r.ok.payload.to_bytes())
    return None


def test_detector_survives_malformed_input(bus_with):
    bus, session, start = bus_with
    det = start("detector")
    assert wait_for_alive(session, bus, ["detector"], 60)
    inbox = Inbox()
    session.declare_subscriber(bus.key("status/detector"), inbox.callback("status"))
    img_pub = publisher(session, bus.key("frame/image"))
    frame = open_source("synthetic:1", n_frames=1).frame(0)
    # garbage and a truncated image, then a good one
    img_pub.put(b"\x00\xffnot protobuf at all")
    bad = image_to_msg(frame.image, 1, "0")
    bad.data = bad.data[:1000]
    img_pub.put(bad.SerializeToString())
    img_pub.put(image_to_msg(frame.image, 1000, "0").SerializeToString(), attachment=ns_attachment(1000))
    time.sleep(0.5)
    # a payload that is not a ScoreQuery
    r = ask(session, bus, b"\x08\x96\x01garbage\xff\xff")
    assert r is not None and r.status == ScoreReply.BAD_REQUEST
    # an unknown frame
    q = ScoreQuery(request_id=1, client="t", frame_index=99, kind=ScoreQuery.AT, count=1, hypotheses=pack(np.zeros((1, 3))))
    r = ask(session, bus, q.SerializeToString())
    assert r.status == ScoreReply.UNKNOWN_FRAME and r.request_id == 1
    # wrong sizes: count says 5 rows but the bytes hold 2
    q = ScoreQuery(request_id=2, client="t", frame_index=0, kind=ScoreQuery.AT, count=5, hypotheses=pack(np.zeros((2, 3))))
    r = ask(session, bus, q.SerializeToString())
    assert r.status == ScoreReply.BAD_REQUEST and "bytes" in r.error
    # NaN hypotheses
    q = ScoreQuery(request_id=3, client="t", frame_index=0, kind=ScoreQuery.AT, count=1,
                   hypotheses=pack(np.array([[np.nan, 1.0, 0.0]])))
    r = ask(session, bus, q.SerializeToString())
    assert r.status == ScoreReply.BAD_REQUEST and "NaN" in r.error
    # no template yet
    q = ScoreQuery(request_id=4, client="t", frame_index=0, kind=ScoreQuery.AT, count=1, template_version=7,
                   hypotheses=pack(np.array([[600.0, 400.0, 0.0]])))
    assert ask(session, bus, q.SerializeToString()).status == ScoreReply.NO_TEMPLATE
    # and it still works: template then scores
    cx, cy = frame.truth.centre
    x, y, w, h = frame.truth.box
    q = ScoreQuery(request_id=5, client="t", frame_index=0, kind=ScoreQuery.TEMPLATE, count=1,
                   hypotheses=pack(np.array([[cx, cy, x, y, w, h]])))
    r = ask(session, bus, q.SerializeToString())
    assert r.status == ScoreReply.OK and r.template.version == 1
    q = ScoreQuery(request_id=6, client="t", frame_index=0, kind=ScoreQuery.AT, count=2, template_version=1,
                   hypotheses=pack(np.array([[cx, cy, 0.0], [cx + 200, cy, 0.0]])))
    r = ask(session, bus, q.SerializeToString())
    scores = np.frombuffer(r.scores, "<f8")
    assert r.status == ScoreReply.OK and scores[0] == pytest.approx(1.0, abs=1e-5) and scores[1] < 0.6
    assert det.poll() is None
    deadline = time.monotonic() + 5
    status = None
    while time.monotonic() < deadline:
        inbox.wait(0.5)
        while (s := inbox.pop("status")) is not None:
            status = ServiceStatus.FromString(payload_bytes(s))
        if status is not None and status.malformed >= 5:
            break
    assert status is not None and status.malformed >= 5  # 2 images, 1 query, wrong sizes, NaN


def test_a_detector_holding_no_template_says_so_at_once_one_holding_some_waits_for_the_version(bus_with):
    """A restarted detector holds no template; the tracker re-sends its own only once told
    NO_TEMPLATE, so a detector with none answers at once (were it to wait for the version, as
    one holding templates does for an adapted one still on its way, a NO_TEMPLATE later than the
    tracker's query timeout left the run unobserved to its end). Waits long enough (30 s) that
    the two answers cannot be confused."""
    bus, session, start = bus_with
    start("detector", "--wait-frame-s", "30")
    assert wait_for_alive(session, bus, ["detector"], 60)
    frame = open_source("synthetic:1", n_frames=1).frame(0)
    publisher(session, bus.key("frame/image")).put(image_to_msg(frame.image, 1000, "0").SerializeToString(),
                                                  attachment=ns_attachment(1000))
    time.sleep(0.5)
    cx, cy = frame.truth.centre
    x, y, w, h = frame.truth.box

    def at(request_id: int, version: int) -> bytes:
        return ScoreQuery(request_id=request_id, client="t", frame_index=0, kind=ScoreQuery.AT, count=1,
                          template_version=version, hypotheses=pack(np.array([[cx, cy, 0.0]]))).SerializeToString()

    r = ask(session, bus, at(1, 1))  # ask's timeout is 5 s
    assert r is not None and r.status == ScoreReply.NO_TEMPLATE and r.request_id == 1
    q = ScoreQuery(request_id=2, client="t", frame_index=0, kind=ScoreQuery.TEMPLATE, count=1,
                   hypotheses=pack(np.array([[cx, cy, x, y, w, h]])))
    made = ask(session, bus, q.SerializeToString())
    assert made.status == ScoreReply.OK and made.template.version == 1
    # holding version 1, a query naming version 2 waits for it (negative control) ...
    assert ask(session, bus, at(3, 2)) is None
    # ... and is answered once it has come
    adapted = made.template
    adapted.version = 2
    publisher(session, bus.key("template")).put(adapted.SerializeToString())
    time.sleep(0.5)
    r = ask(session, bus, at(4, 2))
    assert r is not None and r.status == ScoreReply.OK and r.request_id == 4
    assert np.frombuffer(r.scores, "<f8")[0] == pytest.approx(1.0, abs=1e-5)


def test_tracker_survives_malformed_frame_info(bus_with, tmp_path):
    bus, session, start = bus_with
    cfg = tmp_path / "tracker.json"
    cfg.write_text('{"init_box": [600, 350, 40, 20], "detector_wait_s": 0}')
    trk = start("tracker", "--config", str(cfg))
    assert wait_for_alive(session, bus, ["tracker"], 60)
    inbox = Inbox()
    session.declare_subscriber(bus.key("status/tracker"), inbox.callback("status"))
    session.declare_subscriber(bus.key("track/estimate"), inbox.callback("estimate"))
    pub = publisher(session, bus.key("frame/info"))
    pub.put(b"\xff\xfe definitely not a FrameInfo")
    pub.put(FrameInfo(index=0, time_s=0.0, width=1280, height=720).SerializeToString())  # no detector: no template
    time.sleep(1.0)
    assert trk.poll() is None  # still running
    pub.put(FrameInfo(index=1, end_of_stream=True).SerializeToString())
    assert trk.wait(20) == 0
    status = None
    while (s := inbox.pop("status")) is not None:
        status = ServiceStatus.FromString(payload_bytes(s))
    assert status is not None and status.final and status.malformed == 1 and status.errors >= 1


def test_bad_service_flags_exit_2(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("max_frames = -3\n")
    p = subprocess.run([sys.executable, "-m", "services.detector", "--config", str(bad)], capture_output=True, text=True)
    assert p.returncode == 2 and "max_frames" in p.stderr and p.stderr.count("\n") == 1
    p = subprocess.run([sys.executable, "-m", "services.recorder", "--stream", "has space", "--out", "x.mcap"],
                       capture_output=True, text=True)
    assert p.returncode == 2 and "stream" in p.stderr
    p = subprocess.run([sys.executable, "-m", "services.ingest", "--source", "/no/such/thing", "--wait-for", ""],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and "no such file" in p.stderr


def test_status_ticker_publishes_at_most_once_a_period():
    import time as _time

    from common.msgs import ServiceStatus
    from services.bus import Counters, StatusTicker

    class Pub:
        def __init__(self):
            self.sent = []

        def put(self, data, **kw):
            self.sent.append((ServiceStatus.FromString(data), kw))

    pub, c = Pub(), Counters("test")
    ticker = StatusTicker(pub, c, period=0.5)  # long enough for a loaded machine between two ticks
    assert not ticker.tick() and pub.sent == []  # not yet a period since it was made
    c.add("published", 3)
    _time.sleep(0.55)
    assert ticker.tick(attachment=b"x") and not ticker.tick()
    assert len(pub.sent) == 1 and pub.sent[0][0].published == 3 and pub.sent[0][1] == {"attachment": b"x"}


def test_detector_caches_are_bounded_per_querier():
    """A querier's prepared regions are kept for the last ``max_clients`` queriers only (200
    names had grown the detector by 2 GB), and queriers with the same client name are kept
    apart by their sender id."""
    from common.detector import Template
    from common.detector.server import DetectorCore, DetectorSettings

    frame = open_source("synthetic:1", n_frames=1).frame(0)
    core = DetectorCore(DetectorSettings(max_clients=3))
    core.add_frame(0, frame.image, 0.0)
    cx, cy = frame.truth.centre
    core.install_template(1, Template.from_image(frame.image.astype(np.float32), (cx, cy)))
    for i in range(20):
        q = ScoreQuery(request_id=i, client=f"c{i}", frame_index=0, kind=ScoreQuery.AT, count=1, template_version=1,
                       hypotheses=pack(np.array([[cx, cy, 0.0]])))
        rep, _ = core.handle(q, querier="someone")
        assert rep.status == ScoreReply.OK
        assert len(core.caches) <= 3 and len({k[0] for k in core.observations}) <= 3
    assert list(core.caches) == ["someone/c17", "someone/c18", "someone/c19"]
    core.handle(ScoreQuery(request_id=99, client="c19", frame_index=0, kind=ScoreQuery.AT, count=1, template_version=1,
                           hypotheses=pack(np.array([[cx, cy, 0.0]]))), querier="other")
    assert "other/c19" in core.caches and "someone/c19" in core.caches
    big = ScoreQuery(request_id=100, client="c", frame_index=0, kind=ScoreQuery.AT, count=100_000, template_version=1)
    rep, _ = core.handle(big)
    assert rep.status == ScoreReply.BAD_REQUEST and "at most" in rep.error


def test_a_query_for_an_unknown_frame_does_not_hold_up_the_others(bus_with):
    """Ten queries wait (a second each) for a frame that never comes; a query for a held frame
    is answered meanwhile, at once."""
    bus, session, start = bus_with
    start("detector")
    assert wait_for_alive(session, bus, ["detector"], 60)
    frame = open_source("synthetic:1", n_frames=1).frame(0)
    publisher(session, bus.key("frame/image")).put(image_to_msg(frame.image, 1000, "0").SerializeToString(),
                                                   attachment=ns_attachment(1000))
    time.sleep(0.5)
    key = bus.key("detector/score")
    waiting = [session.get(key, timeout=10.0, payload=ScoreQuery(
        request_id=i, client="t", frame_index=50 + i, kind=ScoreQuery.AT, count=1, template_version=1,
        hypotheses=pack(np.zeros((1, 3)))).SerializeToString()) for i in range(10)]
    t0 = time.monotonic()
    cx, cy = frame.truth.centre
    x, y, w, h = frame.truth.box
    q = ScoreQuery(request_id=77, client="t", frame_index=0, kind=ScoreQuery.TEMPLATE, count=1,
                   hypotheses=pack(np.array([[cx, cy, x, y, w, h]])))
    r = ask(session, bus, q.SerializeToString())
    took = time.monotonic() - t0
    assert r.status == ScoreReply.OK and took < 0.8, took  # not after the waiting ones' second each
    t1 = time.monotonic()
    statuses = [ScoreReply.FromString(rep.ok.payload.to_bytes()).status for h in waiting for rep in h if rep.ok]
    assert statuses == [ScoreReply.UNKNOWN_FRAME] * 10
    assert time.monotonic() - t1 < 3.0  # they waited together, not one after another (10 s)


def test_bench_pipeline_fails_loudly_when_it_cannot_run():
    """480 s of frames would need 37 GiB prerendered: the bench says so in one line with a
    non-zero exit, before starting anything (it had printed fps 0 and exited 0)."""
    p = subprocess.run([sys.executable, "-c", "import sys; from services.cli import main; sys.exit(main())",
                        "bench", "--pipeline", "--seconds", "480", "--no-viewer", "--json"],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 1, (p.stdout[-500:], p.stderr[-2000:])
    err = [ln for ln in p.stderr.splitlines() if ln.startswith("bench --pipeline: error:")]
    assert len(err) == 1 and "prerendering 14400 frames needs 37.1 GiB" in err[0], p.stderr[-2000:]
