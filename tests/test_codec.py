"""Message <-> domain conversions (common.msgs.convert): round trips and refusals."""

from types import SimpleNamespace

import numpy as np
import pytest

from common.msgs import ParticleCloud, pack
from common.msgs.convert import msg_to_cloud, particles_msg


def _state(n: int, rng: np.random.Generator):
    return SimpleNamespace(particles=rng.normal(0, 300, (n, 5)), particles_image=rng.uniform(0, 1280, (n, 2)),
                           weights=rng.dirichlet(np.ones(n)), particle_visibility=rng.uniform(0, 1, n),
                           p_visible=0.5, time=1.25)


def test_particle_cloud_round_trips_in_float32():
    st = _state(400, np.random.default_rng(0))
    msg = ParticleCloud.FromString(particles_msg(7, st).SerializeToString())
    assert msg.frame_index == 7 and msg.count == 400 and len(msg.particles) == 400 * 5 * 4  # float32 on the wire
    cloud = msg_to_cloud(msg)
    for got, want in [(cloud.states, st.particles), (cloud.image_xy, st.particles_image),
                      (cloud.weights, st.weights), (cloud.p_visible, st.particle_visibility)]:
        assert got.dtype == np.float64 and got.shape == want.shape
        assert np.array_equal(got, want.astype(np.float32).astype(np.float64))
        assert np.allclose(got, want, rtol=1e-6, atol=1e-4) and not np.array_equal(got, want)


def test_particle_cloud_of_an_older_recording_reads_as_float64():
    st = _state(3, np.random.default_rng(1))
    old = ParticleCloud(count=3, particles=pack(st.particles), image_xy=pack(st.particles_image), weights=pack(st.weights))
    cloud = msg_to_cloud(old)
    assert np.array_equal(cloud.states, st.particles) and cloud.p_visible is None  # bit for bit


def test_particle_cloud_whose_size_disagrees_with_its_count_is_refused():
    st = _state(3, np.random.default_rng(2))
    good = particles_msg(0, st)
    for bad in [ParticleCloud(count=4, particles=good.particles, image_xy=good.image_xy, weights=good.weights),
                ParticleCloud(count=3, particles=good.particles[:-1], image_xy=good.image_xy, weights=good.weights)]:
        with pytest.raises(ValueError):
            msg_to_cloud(bad)


# -- frames --------------------------------------------------------------------------------------

def test_image_round_trips_and_garbled_geometry_is_refused():
    from common.msgs import RawImage
    from common.msgs.convert import image_to_msg, msg_to_image

    img = np.random.default_rng(3).integers(0, 256, (7, 11, 3), dtype=np.uint8)
    msg = RawImage.FromString(image_to_msg(img, 123, "camera").SerializeToString())
    assert msg.frame_id == "camera" and msg.timestamp.ToNanoseconds() == 123 and msg.encoding == "rgb8"
    assert np.array_equal(msg_to_image(msg), img)
    for field, value in (("step", 30), ("encoding", "bgr8"), ("width", 12)):
        bad = RawImage()
        bad.CopyFrom(msg)
        setattr(bad, field, value)
        with pytest.raises(ValueError):
            msg_to_image(bad)


def test_frame_info_carries_what_a_tracker_steps_on():
    from common.msgs import FrameInfo
    from common.msgs.convert import frame_info_msg, info_frame
    from common.sources import Frame, GroundTruth

    h = np.array([[2.0, 0.1, 5.0], [0.0, 2.0, 7.0], [0.0, 1e-4, 1.0]])
    frame = Frame(index=4, time=0.4, image=np.zeros((9, 13, 3), np.uint8), homography=h,
                  truth=GroundTruth(box=(1.0, 2.0, 3.0, 4.0), angle_deg=30.0))
    info = FrameInfo.FromString(frame_info_msg(frame, 777, "clip", 50).SerializeToString())
    assert (info.index, info.time_s, info.capture_ns, info.width, info.height, info.source, info.total_frames) == (
        4, 0.4, 777, 13, 9, "clip", 50)
    t = info.truth
    assert t.visible and (t.box_x, t.box_y, t.box_w, t.box_h) == (1.0, 2.0, 3.0, 4.0) and t.angle_deg == 30.0
    assert (t.centre_x, t.centre_y) == (2.5, 4.0) and np.isnan(t.visible_fraction)
    back = info_frame(info)
    assert (back.index, back.time, back.size) == (4, 0.4, (13, 9)) and np.array_equal(back.homography, h)
    hidden = frame_info_msg(Frame(index=0, time=0.0, image=np.zeros((2, 2, 3), np.uint8), truth=GroundTruth(box=None)),
                            1, "s", 1, true_centre=(5.0, 6.0))
    assert not hidden.truth.visible and (hidden.truth.centre_x, hidden.truth.centre_y) == (5.0, 6.0)
    assert info_frame(hidden).homography is None


# -- the detector's questions and answers --------------------------------------------------------

def test_query_round_trips_per_kind_and_a_wrong_size_is_refused():
    from common.msgs import ScoreQuery
    from common.msgs.convert import QUERY_WIDTHS, query_hypotheses, score_query

    rng = np.random.default_rng(4)
    for kind, width in QUERY_WIDTHS.items():
        hyps = rng.normal(0, 100, (5, width))
        q = ScoreQuery.FromString(score_query(9, "t", 3, kind, hyps, template_version=2, factor=0.5).SerializeToString())
        assert (q.request_id, q.client, q.frame_index, q.kind, q.count, q.template_version, q.factor) == (
            9, "t", 3, kind, 5, 2, 0.5)
        assert np.array_equal(query_hypotheses(q), hyps)
        q.count = 4
        with pytest.raises(ValueError):
            query_hypotheses(q)
    with pytest.raises(ValueError, match="unknown query kind"):
        query_hypotheses(ScoreQuery(kind=99))


def test_reply_scores_round_trip():
    from common.msgs import ScoreReply
    from common.msgs.convert import reply_scores

    scores, valid = np.arange(12.0).reshape(3, 4), np.array([True, False, True])
    rep = ScoreReply.FromString(ScoreReply(scores=pack(scores), valid=pack(valid, np.uint8)).SerializeToString())
    got_s, got_v = reply_scores(rep, 3, 4)
    assert np.array_equal(got_s, scores) and np.array_equal(got_v, valid) and got_v.dtype == bool
    with pytest.raises(ValueError):
        reply_scores(rep, 3, None)  # 12 scores are not 3


def test_template_round_trips_and_a_wrong_shape_is_refused():
    from common.detector.template import Template
    from common.msgs import Template as TemplateMsg
    from common.msgs.convert import msg_to_template, template_to_msg

    rng = np.random.default_rng(5)
    pm = (rng.normal(size=(12, 68)) + 1j * rng.normal(size=(12, 68))).astype(np.complex64)
    t = Template(pmatrix=pm, centre=(3.5, 4.5), box=(1.0, 2.0, 5.0, 6.0))
    back = msg_to_template(TemplateMsg.FromString(template_to_msg(t, 7, 2).SerializeToString()))
    assert np.array_equal(back.pmatrix, pm) and back.centre == t.centre and back.box == t.box
    bad = template_to_msg(t, 7, 2)
    bad.columns = 35
    with pytest.raises(ValueError):
        msg_to_template(bad)


# -- estimates -----------------------------------------------------------------------------------

def test_estimate_carries_the_state_and_its_oriented_box():
    from common.msgs import Estimate
    from common.msgs.convert import estimate_msg

    point = SimpleNamespace(image_x=10.5, image_y=20.25, theta=33.0, x=1.0, y=2.0, vx=0.5, vy=-0.5)
    mmse = SimpleNamespace(image_x=11.0, image_y=21.0)
    state = SimpleNamespace(map_estimate=point, mmse_estimate=mmse, time=0.5, observed=True, p_visible=0.9, speed=0.7,
                            n_eff=123.0, resampled=True, size=(30.0, 12.0), reacquired=False, box_offset=(2.5, -1.25))
    e = Estimate.FromString(estimate_msg(6, 0, state, "rbpf").SerializeToString())
    assert (e.frame_index, e.x, e.y, e.theta_deg, e.w, e.h, e.p_visible, e.mmse_x, e.n_eff, e.filter) == (
        6, 10.5, 20.25, 33.0, 30.0, 12.0, 0.9, 11.0, 123.0, "rbpf")
    assert (e.box_dx, e.box_dy) == (2.5, -1.25)  # the box's centre apart from the MAP
    no_size = estimate_msg(6, 0, SimpleNamespace(**{**state.__dict__, "size": None, "n_eff": float("nan"),
                                                    "box_offset": None}), "sir")
    assert (no_size.w, no_size.h, no_size.n_eff, no_size.box_dx, no_size.box_dy) == (0.0, 0.0, 0.0, 0.0, 0.0)


def test_multi_estimate_round_trips_the_parts():
    from common.msgs import MultiEstimate
    from common.msgs.convert import msg_positions, multi_estimate_msg

    rng = np.random.default_rng(6)
    parts = rng.normal(100, 20, (2, 6, 2))
    state = SimpleNamespace(parts=parts, time=1.0, velocity=rng.normal(size=(2, 2)), n_eff=np.array([50.0, 60.0]),
                            moved=np.array([1, 0]), gate_area=np.ones((2, 3)), n_measurements=np.array([3, 4]),
                            acceptance={"mutation": 0.25})
    run = SimpleNamespace(config=SimpleNamespace(n_parts=6), method="epmcmc-elpda")
    m = MultiEstimate.FromString(multi_estimate_msg(8, state, run).SerializeToString())
    assert (m.frame_index, m.targets, m.parts, m.filter, dict(m.acceptance)) == (8, 2, 6, "epmcmc-elpda", {"mutation": 0.25})
    assert np.array_equal(msg_positions(m), parts) and len(m.part_names) == 6
    m.parts = 5
    with pytest.raises(ValueError):
        msg_positions(m)


def test_service_status_carries_the_counters():
    from common.msgs import ServiceStatus
    from common.validation import Counters

    c = Counters("tracker")
    c.add("received", 3)
    c.add("errors")
    s = ServiceStatus.FromString(c.status(final=True).SerializeToString())
    assert (s.service, s.received, s.errors, s.published, s.final) == ("tracker", 3, 1, 0, True) and s.cpu_s > 0


# -- the run's configuration ---------------------------------------------------------------------

def test_run_config_is_typed_and_older_json_text_reads_the_same():
    """RunConfig carries the settings, versions and a multi-target run as typed fields (Struct,
    map); the recording's ``run`` metadata (text, as MCAP metadata is) holds them as JSON, bit for
    bit the settings that ran, and a RunConfig written before (JSON text fields) reads the same."""
    import json

    from google.protobuf.json_format import Parse

    from common.msgs import RunConfig
    from common.record.meta import run_config_json, run_metadata
    from common.settings import TrackerSettings, profile_for

    st = profile_for(SimpleNamespace(name="clip", fps=29.97), filter="sir", seed=2**40 + 1, particles=333)
    typed = Parse(run_config_json("r", "clip.mp4", (1.5, 2.0, 3.0, 4.0), st, "realtime"), RunConfig())
    assert typed.settings["sir"]["n_particles"] == 333 and typed.versions["numpy"] and not typed.settings_json
    meta = run_metadata(typed.SerializeToString())
    assert TrackerSettings.model_validate_json(meta["settings_json"]) == st
    assert json.loads(meta["settings_json"])["seed"] == 2**40 + 1  # an integer again, exact
    assert json.loads(meta["versions_json"]) == dict(typed.versions) and meta["multi_json"] == ""
    legacy = RunConfig(run_id="r", source="clip.mp4", init_box=[1.5, 2.0, 3.0, 4.0], seed=st.seed, pace="realtime",
                       settings_json=st.model_dump_json(), versions_json=meta["versions_json"])
    old = run_metadata(legacy.SerializeToString())
    assert set(old) == set(meta) and TrackerSettings.model_validate_json(old["settings_json"]) == st
    assert {k: v for k, v in old.items() if k != "settings_json"} == {k: v for k, v in meta.items() if k != "settings_json"}
