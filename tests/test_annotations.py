"""The Foxglove annotations of an estimate, against hand-built cases: a box turned by 90 degrees,
no box (a circle and a label only), no estimate at all (the truth and the particles only), a
prediction labelled so, and a large cloud thinned to MAX_PARTICLES evenly spaced points."""

import math

import numpy as np
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations

from common.msgs import Estimate, MultiEstimate, ParticleCloud, Truth, pack
from common.msgs.annotations import MAX_PARTICLES, estimate_annotations, multi_annotations

NS = 1_700_000_000_123_456_789


def roundtrip(ann) -> ImageAnnotations:
    return ImageAnnotations.FromString(ann.SerializeToString())


def test_a_box_turned_by_90_degrees_swaps_its_sides():
    e = Estimate(x=100.0, y=50.0, w=40.0, h=10.0, theta_deg=90.0, p_visible=0.876, observed=True)
    ann = roundtrip(estimate_annotations(e, NS))
    (box,) = ann.points
    xs, ys = [p.x for p in box.points], [p.y for p in box.points]
    assert math.isclose(max(xs) - min(xs), 10.0, abs_tol=1e-9) and math.isclose(max(ys) - min(ys), 40.0, abs_tol=1e-9)
    assert box.timestamp.ToNanoseconds() == NS and box.type == box.LINE_LOOP
    assert ann.texts[0].text == "p(visible) 0.88" and ann.circles[0].position.x == 100.0
    moved = roundtrip(estimate_annotations(Estimate(x=100.0, y=50.0, w=40.0, h=10.0, theta_deg=90.0, box_dx=3.0,
                                                    box_dy=-2.0), NS))
    xs, ys = [p.x for p in moved.points[0].points], [p.y for p in moved.points[0].points]
    assert (min(xs) + max(xs)) / 2 == 103.0 and (min(ys) + max(ys)) / 2 == 48.0  # the box about its own centre
    assert moved.circles[0].position.x == 100.0  # the MAP where it is


def test_no_box_no_estimate_and_a_prediction():
    ann = roundtrip(estimate_annotations(Estimate(x=5.0, y=6.0, observed=False, reacquired=True), NS))
    assert not ann.points and len(ann.circles) == 1 and ann.texts[0].text == "p(visible) 0.00 re-acquired predicted"
    truth = Truth(visible=True, box_x=1, box_y=2, box_w=3, box_h=4)
    cloud = ParticleCloud(count=3, image_xy=pack(np.array([[1.0, 2.0], [np.nan, 1.0], [3.0, 4.0]])))
    ann = roundtrip(estimate_annotations(Estimate(x=math.nan, y=math.nan), NS, cloud, truth))
    assert not ann.circles and not ann.texts
    truth_box, points = ann.points
    assert [(p.x, p.y) for p in truth_box.points] == [(1, 2), (4, 2), (4, 6), (1, 6)]
    assert [(p.x, p.y) for p in points.points] == [(1.0, 2.0), (3.0, 4.0)]  # the non-finite one left out
    hidden = roundtrip(estimate_annotations(Estimate(x=1.0, y=1.0), NS, None, Truth(visible=False)))
    assert all(p.type != p.LINE_LOOP for p in hidden.points)


def test_a_large_cloud_is_thinned_evenly():
    n = 5 * MAX_PARTICLES + 3
    xy = np.stack([np.arange(n, dtype=float), np.zeros(n)], axis=1)
    ann = roundtrip(estimate_annotations(Estimate(x=1.0, y=1.0), NS, ParticleCloud(count=n, image_xy=pack(xy))))
    (pts,) = [p for p in ann.points if p.type == p.POINTS]
    got = [p.x for p in pts.points]
    assert len(got) <= MAX_PARTICLES and got[0] == 0.0 and np.all(np.diff(got) == np.diff(got)[0])
    bad = ParticleCloud(count=n, image_xy=b"\x00" * 7)  # sizes disagree with count: no points, no error
    assert not roundtrip(estimate_annotations(Estimate(x=1.0, y=1.0), NS, bad)).points


def test_multi_target_skeletons_skip_parts_that_are_not_finite():
    pos = np.array([[[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]], [[5.0, 5.0], [np.nan, 6.0], [7.0, 7.0]]])
    msg = MultiEstimate(targets=2, parts=3, positions=pack(pos), parents=pack(np.array([-1, 0, 1]), np.int32))
    ann = roundtrip(multi_annotations(msg, NS))
    lines = [[(q.x, q.y) for q in p.points] for p in ann.points if p.type == p.LINE_LIST]
    assert lines == [[(1.0, 1.0), (0.0, 0.0), (2.0, 2.0), (1.0, 1.0)]]  # target 2's bones both touch the NaN part
    points = [[(q.x, q.y) for q in p.points] for p in ann.points if p.type == p.POINTS]
    assert points == [[(0.0, 0.0), (1.0, 1.0), (2.0, 2.0)], [(5.0, 5.0), (7.0, 7.0)]]
    assert not roundtrip(multi_annotations(MultiEstimate(targets=2, parts=3, positions=b"bad"), NS)).points


def test_track_drawing_joins_truth_estimate_and_cloud_in_arrival_order():
    from common.msgs import FrameInfo
    from common.msgs.annotations import TrackDrawing

    d = TrackDrawing()
    assert d.info(FrameInfo(index=0, truth=Truth(visible=True, box_x=1, box_y=1, box_w=2, box_h=2))) == []
    assert d.estimate(Estimate(frame_index=0, x=3.0, y=3.0), 100) == []  # waits for its cloud
    cloud = ParticleCloud(frame_index=0, count=1, image_xy=pack(np.array([[3.0, 4.0]])))
    assert d.cloud(ParticleCloud(frame_index=7, count=0)) == []  # another frame's: ignored
    ((t, data),) = d.cloud(cloud)
    ann = ImageAnnotations.FromString(data)
    assert t == 100 and [p.type for p in ann.points] == [ann.points[0].LINE_LOOP, ann.points[0].POINTS]
    # an estimate without a cloud goes out with the next estimate, or at the flush
    assert d.info(FrameInfo(index=1)) == [] and d.info(FrameInfo(index=2)) == []
    assert d.estimate(Estimate(frame_index=1, x=1.0, y=1.0), 200) == []
    ((t1, _),) = d.estimate(Estimate(frame_index=2, x=1.0, y=1.0), 300)
    ((t2, _),) = d.flush()
    assert (t1, t2) == (200, 300) and d.flush() == []


def _loops(data: bytes) -> int:
    ann = ImageAnnotations.FromString(data)
    return sum(p.type == p.LINE_LOOP for p in ann.points)


def test_a_drawing_whose_estimate_overtook_its_frames_info_waits_for_the_truth():
    """The estimate and its cloud arrive before their frame's info (they come from another service):
    the drawing waits, and goes out with the truth's box when the info comes; an info without a
    truth, or a later frame's info (this one's lost), lets it go without; more than ``keep`` waiting,
    the oldest goes out; the flush draws every one still held. Drawn on arrival, frame 5 would have
    lost its truth's box (the fault a loaded machine showed in
    tests/test_services_pipeline.py::test_recording_draws_the_track_in_foxglove)."""
    from common.msgs import FrameInfo
    from common.msgs.annotations import TrackDrawing

    def est(i):
        return Estimate(frame_index=i, x=3.0, y=3.0, w=4.0, h=2.0)

    def cloud(i):
        return ParticleCloud(frame_index=i, count=1, image_xy=pack(np.array([[3.0, 4.0]])))

    truth = Truth(visible=True, box_x=1, box_y=1, box_w=2, box_h=2)
    d = TrackDrawing(keep=2)
    assert d.info(FrameInfo(index=4)) == []
    assert d.estimate(est(5), 500) == [] and d.cloud(cloud(5)) == []  # before frame 5's info: held
    ((t, data),) = d.info(FrameInfo(index=5, truth=truth))
    assert t == 500 and _loops(data) == 2  # the truth's box and the estimate's
    assert d.estimate(est(6), 600) == [] and d.cloud(cloud(6)) == []
    ((t, data),) = d.info(FrameInfo(index=6))  # a frame without a truth (a real video)
    assert t == 600 and _loops(data) == 1
    assert d.estimate(est(7), 700) == [] and d.cloud(cloud(7)) == []
    ((t, data),) = d.info(FrameInfo(index=8, truth=truth))  # frame 7's info lost: 8's lets it go
    assert t == 700 and _loops(data) == 1
    for i in (9, 10, 11):  # three waiting where two are kept: the oldest goes out
        d.estimate(est(i), 100 * i)
        out = d.cloud(cloud(i))
    assert [t for t, _ in out] == [900]
    assert [t for t, _ in d.flush()] == [1000, 1100] and d.flush() == []
    d.info(FrameInfo(index=12, truth=truth))
    d.estimate(est(12), 1200)
    assert d.info(FrameInfo(end_of_stream=True)) == []
    ((t, data),) = d.flush()  # an estimate without its cloud: at the flush, with its truth
    assert t == 1200 and _loops(data) == 2
