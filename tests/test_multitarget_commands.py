"""``run`` / ``track`` with the multi-target filters: arguments, the people source, and the in-process
``track`` equal to ``track-multi``; the part-evidence queries answered by the detector core equal the
in-process evidence, bit for bit (no processes here)."""

import argparse
import csv

import numpy as np
import pytest

from services.cli import main
from common.msgs import pack
from services.commands.common_args import boxes_arg
from common.msgs.convert import multi_estimate_msg
from common.multitarget.runner import MultiRun, MultiTracker, track_frames
from common.record.retrack import same_multi_estimate
from common.detector.remote import EvidenceUnavailable, QueryPartEvidence
from common.sources import PeopleSource, SourceError, open_source
from common.detector.server import DetectorCore


def test_boxes_arg():
    assert boxes_arg("1,2,3,4") == [(1.0, 2.0, 3.0, 4.0)]
    assert boxes_arg("1,2,3,4;5,6,7,8") == [(1.0, 2.0, 3.0, 4.0), (5.0, 6.0, 7.0, 8.0)]
    with pytest.raises(argparse.ArgumentTypeError):
        boxes_arg("1,2,3;4")


def test_people_source():
    src = open_source("people:3", n_frames=12)
    assert isinstance(src, PeopleSource) and len(src) == 12 and src.n_people == 3
    assert open_source("people:3:2").n_people == 2
    assert src.person_boxes().shape == (3, 4)
    assert src.frame(0).people.parts.shape == (3, 10, 2)  # the per-part truth travels with the frame
    for bad in ("people:x", "people:1:9", "people:1:2:3"):
        with pytest.raises(SourceError):
            open_source(bad)


def _rows(path):
    with open(path) as fh:
        return list(csv.reader(fh))


def test_track_multi_filter_equals_the_filter_run_by_hand(tmp_path):
    """``track --filter`` (and its alias ``track-multi``) give the estimates of the filter stepped by
    hand on the scene's frames with in-process evidence."""
    from common.multitarget import HistogramEvidence, MultiInit, body_model, make_filter, method_config
    from common.multitarget.placement import place_in_boxes

    a, b = tmp_path / "track.csv", tmp_path / "track_multi.csv"
    common = ["people:3", "--filter", "epmcmc-pda", "--parts", "2", "--particles", "12", "--frames", "10",
              "--seed", "5", "--no-progress"]
    assert main(["track", *common, "--out", str(a)]) == 0
    assert main(["track-multi", *common, "--out", str(b)]) == 0
    ra, rb = _rows(a), _rows(b)
    assert ra == rb and ra[0] == ["frame", "target", "part", "x", "y"] and len(ra) == 1 + 10 * 3 * 2
    source = open_source("people:3", n_frames=10)
    cfg = method_config("epmcmc-pda", n_parts=2, n_particles=12)
    body = body_model(2)
    flt, want = None, []
    for frame in source:
        ev = HistogramEvidence(frame.image, cfg.histogram)
        if flt is None:
            boxes = source.person_boxes()
            start, shifts = place_in_boxes(MultiInit.from_boxes(boxes, body, frame.size), boxes, body, ev, cfg.placement)
            assert np.any(shifts != 0)  # the placement moved someone: the comparison covers it
            flt = make_filter(cfg, start, ev, 5)
        state = flt.step(frame.time, ev)
        want += [[str(frame.index), str(t), name, f"{x:.6f}", f"{y:.6f}"]
                 for t, parts in enumerate(state.parts) for name, (x, y) in zip(body.names, parts)]
    assert ra[1:] == want


def test_track_multi_filter_with_given_boxes(tmp_path):
    boxes = open_source("people:0", n_frames=10).person_boxes()
    text = ";".join(",".join(f"{v:.1f}" for v in b) for b in boxes[:2])
    out = tmp_path / "two.csv"
    assert main(["track", "people:0", "--filter", "jpda-pf", "--init", text, "--parts", "1", "--particles", "8",
                 "--frames", "10", "--no-progress", "--out", str(out)]) == 0
    rows = _rows(out)[1:]
    assert {r[1] for r in rows} == {"0", "1"} and len(rows) == 10 * 2


@pytest.mark.parametrize("argv, message", [
    (["run", "--source", "synthetic:1", "--init", "600,300,40,20;700,300,40,20", "--frames", "3"], "tracks one target"),
    (["track", "synthetic:1", "--init", "600,300,40,20", "--init", "700,300,40,20", "--frames", "3"], "tracks one target"),
    (["run", "--source", "people:1", "--filter", "epmcmc-elpda", "--init", "1,1,5,5", "--init-file", "x.txt"], "not both"),
    (["run", "--source", "people:1", "--filter", "epmcmc-elpda", "--init", "1000,1,5,5"], "not inside"),
    (["track", "synthetic:1", "--filter", "epmcmc-elpda", "--people", "2", "--frames", "3"], "people[:SEED] source only"),
    (["run", "--source", "synthetic:1", "--filter", "epmcmc-elpda", "--frames", "3"], "--init-file"),
    (["track", "people:1", "--filter", "epmcmc-elpda", "--init-file", "/nonexistent/boxes.txt"], "no such file"),
])
def test_bad_multi_target_arguments(argv, message, capsys):
    assert main([*argv, "--no-progress"]) == 2
    assert message in capsys.readouterr().err


def test_query_evidence_answered_by_the_detector_core_is_bit_identical():
    """A filter fed by QueryPartEvidence whose queries the detector core answers (over serialised
    messages) gives the in-process estimates bit for bit; a failed reply raises EvidenceUnavailable."""
    from common.msgs import ScoreQuery, ScoreReply

    src = open_source("people:2", n_frames=10)
    run = MultiRun.make("epmcmc-elpda", src.person_boxes(), seed=2, n_parts=6, particles=10)
    core = DetectorCore()

    def ask(q):
        rep, _ = core.handle(ScoreQuery.FromString(q.SerializeToString()))
        return ScoreReply.FromString(rep.SerializeToString())

    tracker = None
    remote = []
    for f in src:
        core.add_frame(f.index, f.image, f.time)
        ev = QueryPartEvidence(ask, "t", f.index, f.size, run.config.histogram)
        if tracker is None:
            tracker = MultiTracker(run, ev)
        remote.append(multi_estimate_msg(f.index, tracker.step(f.time, ev), run))
    local = [multi_estimate_msg(f.index, s, run) for f, s in track_frames(open_source("people:2", n_frames=10), run)]
    assert all(same_multi_estimate(a, b) for a, b in zip(remote, local)) and len(remote) == 10
    with pytest.raises(EvidenceUnavailable):
        QueryPartEvidence(ask, "t", 99, f.size).histograms(np.zeros((1, 4)))
    with pytest.raises(EvidenceUnavailable):
        QueryPartEvidence(lambda q: None, "t", 0, f.size).histograms(np.zeros((1, 4)))
    assert core.counters["malformed"] == 1  # the unknown frame


def test_set_overrides_the_multi_target_config(tmp_path, capsys):
    """``--set`` reaches the multi-target filter's config: a wider gate changes the estimates (the
    default run is the negative control); an unknown key is a usage error."""
    common = ["track", "people:3", "--filter", "epmcmc-pda", "--parts", "2", "--particles", "12", "--frames", "10",
              "--seed", "5", "--no-progress"]
    a, b = tmp_path / "default.csv", tmp_path / "wide.csv"
    assert main([*common, "--out", str(a)]) == 0
    assert main([*common, "--set", "gate.gate_size=40", "--set", "association_model.p_detect=0.6", "--out", str(b)]) == 0
    assert _rows(a) != _rows(b) and len(_rows(a)) == len(_rows(b))
    assert main([*common, "--set", "gate.no_such_knob=1"]) == 2
    assert "no setting 'gate.no_such_knob'" in capsys.readouterr().err
    assert main([*common, "--set", "gate.gate_size=-3"]) == 2
    assert "gate.gate_size" in capsys.readouterr().err


def test_the_cli_names_the_multi_target_filters_as_the_library_does():
    from services.commands.common_args import MULTI_METHODS
    from common.multitarget import METHODS

    assert tuple(MULTI_METHODS) == tuple(METHODS)


def test_replay_compares_estimates_not_transport_counts():
    """Frames skipped by a live tracker and the timings differ on replay; the estimates must not."""
    from common.msgs import MultiEstimate
    from common.record.retrack import compare_multi

    a = MultiEstimate(frame_index=3, targets=1, parts=1, positions=pack(np.array([[[1.0, 2.0]]])), frames_skipped=5,
                      step_ms=30.0)
    b = MultiEstimate(frame_index=3, targets=1, parts=1, positions=pack(np.array([[[1.0, 2.0]]])), frames_skipped=0,
                      step_ms=12.0)
    c = MultiEstimate(frame_index=3, targets=1, parts=1, positions=pack(np.array([[[1.0, 2.0 + 1e-12]]])))
    assert same_multi_estimate(a, b) and not same_multi_estimate(a, c)
    assert compare_multi([a], [b])["identical"] and not compare_multi([a], [c])["identical"]
