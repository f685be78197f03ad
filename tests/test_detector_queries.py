"""The Tracker's detector client over queries, answered by the detector service's core (no bus):
every per-frame mechanism on, the estimates equal the in-process ones bit for bit; and bad
queries of the new kinds get BAD_REQUEST."""

import numpy as np
import pytest

from common.detector.remote import QueryDetector
from common.msgs import ScoreQuery, ScoreReply, pack
from common.msgs.convert import estimate_msg, frame_info_msg, info_frame, msg_to_template, template_to_msg
from common.record.retrack import same_estimate
from common.single_target.runner import Tracker
from common.sources import open_source
from parity import parity_settings
from common.detector.server import DetectorCore

FRAMES = 12


def test_queries_answered_by_the_detector_core_equal_in_process():
    src = open_source("synthetic:3", n_frames=FRAMES)
    frames = list(src)
    st = parity_settings(src)
    box = frames[0].truth.box
    core = DetectorCore()
    kinds = []

    def ask(q):
        kinds.append((q.kind, q.one_off, q.factor))
        return core.handle(ScoreQuery.FromString(q.SerializeToString()))[0]

    def publish(template, version):  # the template key: a message the detector installs
        core.install_template(version, msg_to_template(template_to_msg(template, version, 0)))

    remote = None
    local = Tracker.start(frames[0], box, st)
    for f in frames:
        core.add_frame(f.index, f.image, f.time)
        # the remote side sees the frame as the bus describes it, with the pixels (it stabilises)
        rf = info_frame(frame_info_msg(f), f.image)
        remote = remote or Tracker.start(rf, box, st, QueryDetector(ask, "t", publish))
        a, b = local.step(f), remote.step(rf)
        assert same_estimate(estimate_msg(f.index, 0, a, "rbpf"), estimate_msg(f.index, 0, b, "rbpf")), f.index
    assert local.adaptations == remote.adaptations > 3 and local.scale.searches == remote.scale.searches > 0
    assert np.array_equal(local.template.pmatrix, remote.template.pmatrix)
    assert local.factor != 1.0 and remote.detector.version == 1 + remote.adaptations
    assert {(ScoreQuery.PEAK, False), (ScoreQuery.GRID, True), (ScoreQuery.AT, False)} <= {k[:2] for k in kinds}


def test_new_query_kinds_bad_input_is_bad_request():
    f = open_source("synthetic:1", n_frames=1).frame(0)
    core = DetectorCore()
    core.add_frame(0, f.image, 0.0)
    cx, cy = f.truth.centre
    x, y, w, h = f.truth.box
    q = ScoreQuery(request_id=1, client="t", kind=ScoreQuery.TEMPLATE, count=1, factor=1.5,
                   hypotheses=pack(np.array([[cx, cy, x, y, w, h]])))
    rep, tm = core.handle(q)
    assert rep.status == ScoreReply.OK and tm.version == 1

    def status(**kw):
        base = dict(request_id=2, client="t", kind=ScoreQuery.AT, count=1, template_version=1, factor=1.5,
                    hypotheses=pack(np.array([[cx, cy, 0.0]])))
        base.update(kw)
        return core.handle(ScoreQuery(**base))[0]

    assert status().status == ScoreReply.OK
    before = core.counters["malformed"]
    for kw in (dict(factor=-2.0), dict(factor=float("nan")), dict(factor=1e6),
               dict(kind=ScoreQuery.PEAK, count=2, hypotheses=pack(np.zeros((2, 2)))),
               dict(kind=ScoreQuery.PEAK, hypotheses=pack(np.zeros((1, 3)))),
               dict(one_off=True)):  # one_off is for the scale search's GRID queries
        rep = status(**kw)
        assert rep.status == ScoreReply.BAD_REQUEST and rep.error, kw
    assert core.counters["malformed"] == before + 6
    peak = status(kind=ScoreQuery.PEAK, hypotheses=pack(np.array([[cx, cy]])))
    theta, score = np.frombuffer(peak.scores, "<f8")
    assert peak.status == ScoreReply.OK and score > 0.99 and abs(theta) < 1.0
    assert len(peak.pmatrix) == 12 * peak.pmatrix_columns * 8
    far = status(kind=ScoreQuery.PEAK, hypotheses=pack(np.array([[2.0, 2.0]])))  # out of support
    assert far.status == ScoreReply.OK and far.pmatrix == b"" and np.frombuffer(far.valid, np.uint8)[0] == 0


@pytest.mark.parametrize("seed", [4])
def test_a_different_seed_differs(seed):
    """Negative control of the parity test: the comparison tells two runs apart."""
    src = open_source("synthetic:3", n_frames=6)
    frames = list(src)
    box = frames[0].truth.box
    a = Tracker.start(frames[0], box, parity_settings(src, seed=3))
    b = Tracker.start(frames[0], box, parity_settings(src, seed=seed))
    diff = [not same_estimate(estimate_msg(f.index, 0, a.step(f), "rbpf"), estimate_msg(f.index, 0, b.step(f), "rbpf"))
            for f in frames]
    assert any(diff)
