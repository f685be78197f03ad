"""The pure message checks every service runs (common.validation): each bad message is rejected
with its reason, each good one passes, the counters and the rate-limited log are bounded."""

import logging
import math

import numpy as np
import pytest

from common.msgs import Estimate, FrameInfo, ScoreQuery, ServiceStatus
from common.validation import (MAX_HYPOTHESES, FrameOrder, Guard, Invalid, RateLimitedLog, Rejects, Senders,
                               check_estimate, check_frame_info, check_homography, check_query, check_status,
                               decode, parse_rejects)


def info(i, t=None, **kw):
    return FrameInfo(index=i, time_s=i / 30 if t is None else t, capture_ns=1_000_000_000 + int(i * 1e9 / 30),
                     width=kw.pop("width", 1280), height=kw.pop("height", 720), **kw)


def reason(fn, *args):
    with pytest.raises(Invalid) as exc:
        fn(*args)
    return exc.value.reason


def test_frame_infos_in_order_pass_and_every_bad_one_is_named():
    order = FrameOrder()
    for i in range(3):
        check_frame_info(info(i), order)
    assert order.index == 2
    bad = {
        "bad_time": info(3, t=math.nan),
        "time_jump": info(3, t=1e6),  # 1e6 s ahead put the estimate 1e7 px off
        "time_backwards": info(3, t=0.01),
        "index_not_increasing": info(1),  # an old index replayed
        "bad_size": info(3, width=0),
        "size_changed": info(3, width=640),
    }
    for want, msg in bad.items():
        assert reason(check_frame_info, msg, order) == want
    neg = info(3)
    neg.time_s = -1.0
    assert reason(check_frame_info, neg, order) == "bad_time"
    for h in ([math.nan] * 9, [0.0] * 9, [1, 2, 3, 2, 4, 6, 0, 0, 1], [1.0] * 4):
        m = info(3)
        m.homography.extend(h)
        assert reason(check_frame_info, m, order) == "bad_homography"
    assert order.index == 2  # none of them moved the stream on
    good = info(3)
    good.homography.extend(np.eye(3).ravel())
    check_frame_info(good, order)
    # the end of stream only after the last frame, once
    assert reason(check_frame_info, FrameInfo(index=2, end_of_stream=True), order) == "bad_end_of_stream"
    check_frame_info(FrameInfo(index=4, end_of_stream=True), order)
    assert reason(check_frame_info, info(5), order) == "after_end_of_stream"


def test_homography_check_accepts_a_real_one():
    check_homography([])
    check_homography(list((np.diag([2.0, 2.0, 1.0]) @ np.array([[1, 0.1, 5], [0, 1, 3], [1e-4, 0, 1]])).ravel()))


def test_homography_check_is_blind_to_the_planes_units_not_to_rank():
    """A good camera over a ground plane in metres far from its origin (the 30-minute synthetic
    scene's frame 53,999: condition number 5e8, plain determinant 3e-13, all its infos had been
    refused) passes; so does any rescaling of either plane; a rank-2 matrix at the same scale,
    and a zero column, do not."""
    h = np.array([[-6073.5852, -5338.9142, -51492438.4236], [-4967.2673, 6110.3526, 11109513.4152],
                  [0.3073, -0.3781, 1.0]])
    assert np.linalg.cond(h / np.abs(h).max()) > 1e8
    check_homography(list(h.ravel()))
    for left, right in ((np.diag([1e-3, 1e-3, 1.0]), np.eye(3)), (np.eye(3), np.diag([1e4, 1e4, 1.0]))):
        check_homography(list((left @ h @ right).ravel()))
    rank2 = h.copy()
    rank2[:, 1] = 3.0 * rank2[:, 0]
    assert reason(check_homography, list(rank2.ravel())) == "bad_homography"
    zero_col = h.copy()
    zero_col[:, 2] = 0.0
    assert reason(check_homography, list(zero_col.ravel())) == "bad_homography"


def test_rejected_frames_do_not_poison_the_stream():
    """After a run of rejected frames (a minute of them at 30 fps), the next good frame is many
    index steps on and that much later: accepted (the stream had refused every frame after such
    a gap, comparing each with the last accepted one by a per-frame jump bound). A jump that is
    too large for its index step is still refused."""
    order = FrameOrder()
    check_frame_info(info(0, t=0.0), order)
    later = info(1801, t=1801 / 30)  # 60.03 s later, 1,801 index steps on
    check_frame_info(later, order)
    assert order.index == 1801
    assert reason(check_frame_info, info(1802, t=1801 / 30 + 61.0), order) == "time_jump"


def test_decode_caps_size_before_parsing():
    assert reason(decode, FrameInfo, b"\x00" * (2 << 20), "frame/info") == "too_large"
    assert reason(decode, FrameInfo, b"\xff\xfe garbage", "frame/info") == "undecodable"
    assert decode(FrameInfo, info(7).SerializeToString(), "frame/info").index == 7


def test_estimates_statuses_and_queries():
    e = Estimate(frame_index=5, x=1.0, y=2.0)
    check_estimate(e, max_index=5)
    assert reason(check_estimate, Estimate(frame_index=10**9, x=1, y=1), 5) == "unknown_frame"
    assert reason(check_estimate, Estimate(frame_index=1, x=math.inf, y=1), None) == "not_finite"
    assert reason(check_estimate, Estimate(frame_index=1, x=1, y=1, box_dy=math.nan), None) == "not_finite"
    check_status(ServiceStatus(service="detector", cpu_s=1.0), "status/detector")
    assert reason(check_status, ServiceStatus(service="tracker"), "status/detector") == "wrong_service"
    assert reason(check_status, ServiceStatus(service="x", cpu_s=math.nan), "status/x") == "not_finite"
    check_query(ScoreQuery(count=MAX_HYPOTHESES, client="tracker"))
    assert reason(check_query, ScoreQuery(count=MAX_HYPOTHESES + 1)) == "too_many_hypotheses"
    assert reason(check_query, ScoreQuery(client="c" * 65)) == "bad_client"
    check_query(ScoreQuery(count=MAX_HYPOTHESES + 1, kind=ScoreQuery.HISTOGRAMS), (ScoreQuery.HISTOGRAMS,))


def test_senders_accept_only_the_run_s_service_on_each_key():
    s = Senders({"ingest": "i1", "tracker": "t1", "detector": "d1"})
    s.check("frame/info", "i1")
    s.check("template", "d1")
    s.check("template", "t1")
    s.check("status/detector", "d1")
    for key, sender in (("frame/info", "t1"), ("frame/info", ""), ("track/estimate", "i1"),
                        ("detector/score", "x"), ("status/detector", "t1"), ("made/up", "i1")):
        assert reason(s.check, key, sender) == "foreign_sender", key
    Senders().check("frame/info", "")  # no ids: a service started by hand accepts everyone


def test_rejects_and_log_are_bounded():
    r = Rejects(max_keys=3)
    for i in range(10):
        r.add(f"k{i}", "bad")
    snap = r.snapshot()
    assert len(snap) == 4 and snap["(other)"] == {"bad": 7} and r.total() == 10
    assert parse_rejects(r.to_json()) == snap
    for bad in (b"[1]", b"{\"a\": {\"b\": -1}}", b"not json"):
        with pytest.raises(Invalid):
            parse_rejects(bad)

    lines = []

    class H(logging.Handler):
        def emit(self, record):
            lines.append(record.getMessage())

    logger = logging.getLogger("test.validation")
    logger.addHandler(H())
    logger.propagate = False
    now = [0.0]
    rl = RateLimitedLog(logger, period_s=5.0, clock=lambda: now[0])
    for _ in range(100):
        rl.warning("k", "bad")
    assert lines == ["bad"]
    now[0] = 6.0
    rl.warning("k", "bad")
    assert len(lines) == 2 and "99 more" in lines[1]


def test_guard_counts_per_key_and_reason_and_calls_the_hook():
    seen = []
    g = Guard("t", Senders({"ingest": "i"}), logging.getLogger("test.guard"), on_reject=lambda k, r: seen.append((k, r)))
    assert g.decode("frame/info", FrameInfo, b"\xff", "i") is None
    assert g.decode("frame/info", FrameInfo, info(0).SerializeToString(), "rogue") is None
    order = FrameOrder()
    assert g.decode("frame/info", FrameInfo, info(0).SerializeToString(), "i", check_frame_info, order).index == 0
    assert g.decode("frame/info", FrameInfo, info(0).SerializeToString(), "i", check_frame_info, order) is None
    assert g.rejects.snapshot() == {"frame/info": {"undecodable": 1, "foreign_sender": 1, "index_not_increasing": 1}}
    assert len(seen) == 3
