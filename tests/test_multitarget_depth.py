"""Depth order of overlapping targets from their feet and their pixels (:mod:`common.multitarget.depth`)."""

import numpy as np
import pytest

from common.multitarget import HistogramEvidence, body_model
from common.multitarget.appearance import part_boxes
from common.multitarget.config import DepthConfig
from common.multitarget.depth import DepthOrder, overlap_evidence

BODY = body_model(1)  # the torso alone: its box is the bounding box, so every area is by hand
SIZE = np.full((2, 1, 2), [20.0, 40.0])
CORE = np.array([True])


def _scene(front_colour_first: bool):
    """Red target 0 at x 20-40, blue target 1 at x 30-50 (both y 10-50), one painted over the other."""
    img = np.full((60, 80, 3), 128, np.uint8)
    red, blue = (220, 20, 20), (20, 20, 220)
    order = [(slice(20, 40), red), (slice(30, 50), blue)]
    if not front_colour_first:  # target 0 (red) painted last: red in front
        order = order[::-1]
    for xs, colour in order:
        img[10:50, xs] = colour
    ev = HistogramEvidence(img)
    parts = np.array([[[30.0, 30.0]], [[40.0, 30.0]]])
    alone = np.array([[[30.0 - 5, 30.0]], [[40.0 + 5, 30.0]]])  # each one's unshared half, for the references
    refs = ev.histograms(part_boxes(alone, np.full((2, 1, 2), [10.0, 40.0])).reshape(-1, 4))[:, None]
    return ev, parts, refs


def test_overlap_evidence_by_hand():
    ev, parts, refs = _scene(front_colour_first=True)  # blue (target 1) painted last: in front
    score, share = overlap_evidence(ev, parts, SIZE, refs, CORE)
    # overlap of the boxes x 30-40, y 10-50: all blue
    assert score[1, 0] == pytest.approx(1.0, abs=1e-6)  # target 1 explains it
    assert score[0, 1] == pytest.approx(0.0, abs=1e-6)  # target 0's red is not there
    assert share == pytest.approx(np.array([[0.0, 0.5], [0.5, 0.0]]))  # 10 x 40 of 20 x 40
    assert np.isnan(score[0, 0]) and np.isnan(score[1, 1])
    apart = parts + np.array([[[0.0, 0.0]], [[40.0, 0.0]]])  # boxes no longer overlap: no evidence
    score, share = overlap_evidence(ev, apart, SIZE, refs, CORE)
    assert np.isnan(score).all() and not share.any()


@pytest.mark.parametrize("blue_in_front", [True, False])
def test_pixels_overrule_feet_a_pixel_apart(blue_in_front):
    ev, parts, refs = _scene(front_colour_first=blue_in_front)
    feet = parts.copy()
    feet[0, 0, 1] += 1.0  # target 0's feet 1 px lower: by the feet alone it stands in front
    depth = DepthOrder(2, DepthConfig())
    assert depth.front(feet, SIZE).tolist() == [[False, False], [True, False]]  # before any pixels: the feet
    front = depth.update(feet, SIZE, refs, CORE, ev)
    near = 1 if blue_in_front else 0
    assert front[1 - near, near] and not front[near, 1 - near]  # the painted order, whichever it is
    # overlap x 30-40, y 11-50 (target 0 one px lower), all painted: each core has 10 x 39 of 20 x 40 in it
    e = 20.0 * np.sqrt(10 * 39 / 800) * (1.0 - 0.0)  # gain sqrt(share) (s_near - s_far)
    assert depth.evidence[near, 1 - near] == pytest.approx(e, rel=1e-5)
    assert depth.evidence == pytest.approx(-depth.evidence.T)
    # negative control: without the pixels the feet decide, wrongly where blue is in front
    feet_only = DepthOrder(2, DepthConfig(evidence_gain=0.0)).update(feet, SIZE, refs, CORE, ev)
    assert feet_only.tolist() == [[False, False], [True, False]]


def test_the_order_is_held_then_forgotten_and_capped():
    ev, parts, refs = _scene(front_colour_first=True)
    cfg = DepthConfig(forget=0.5, cap=25.0)
    depth = DepthOrder(2, cfg)
    for _ in range(5):
        depth.update(parts, SIZE, refs, CORE, ev)
    assert depth.evidence[1, 0] == pytest.approx(25.0)  # 14.1 per frame, capped
    apart = parts + np.array([[[0.0, 0.0]], [[40.0, 0.0]]])
    front = depth.update(apart, SIZE, refs, CORE, ev)  # apart: nothing new, the old evidence decays
    assert depth.evidence[1, 0] == pytest.approx(12.5)
    assert front[0, 1] and not front[1, 0]  # still in front until forgotten...
    far = apart + np.array([[[0.0, 40.0]], [[0.0, 0.0]]])  # ...and the feet weigh in: target 0 now 40 px lower
    assert depth.log_odds(far, SIZE)[0, 1] == pytest.approx(40.0 / cfg.feet_scale - 12.5)
    assert depth.front(far, SIZE)[1, 0]


def test_filter_judges_who_is_hidden_by_the_pixels():
    """Two people a pixel apart in depth, the feet saying the wrong one is in front: after one frame the
    filter's P_D lowers the one the pixels show hidden."""
    from common.multitarget import MultiInit, make_filter, method_config

    body = body_model(10)
    img = np.full((200, 240, 3), 128, np.uint8)
    h = 60.0
    rest = body.to_absolute(body.offset * h)  # (P, 2) root at 0
    size = body.box * h
    torsos = np.array([[100.0, 100.0], [108.0, 99.0]])  # target 1's feet 1 px higher: the feet put it behind
    colours = [(200, 30, 30), (30, 30, 200)]
    for t in (0, 1):  # target 1 painted last: in front
        for b in np.rint(part_boxes(rest + torsos[t], size)).astype(int):
            img[b[1]:b[3], b[0]:b[2]] = colours[t]
    init = MultiInit(parts=rest[None] + torsos[:, None], height=np.array([h, h]))
    cfg = method_config("epmcmc-elpda", n_particles=50, reference_min_visible=None)
    ev = HistogramEvidence(img)
    flt = make_filter(cfg, init, ev, 0)
    before = flt.detection_probability(init.parts)
    assert before[0] == cfg.association_model.p_detect and before[1] < before[0]  # feet: target 1 hidden
    flt.associate(ev)
    after = flt.detection_probability(init.parts)
    assert after[1] == cfg.association_model.p_detect and after[0] < after[1]  # pixels: target 0 hidden


def test_no_depth_query_when_nothing_uses_the_order():
    from common.multitarget import MultiInit, make_filter, method_config

    class Counting:
        """Evidence that counts the HISTOGRAMS questions (the depth order's; the gates ask SIMILARITY)."""

        def __init__(self, ev):
            self.ev, self.image_size, self.calls = ev, ev.image_size, 0

        def histograms(self, boxes):
            self.calls += 1
            return self.ev.histograms(boxes)

        def similarity(self, boxes, references, ref_index):
            return self.ev.similarity(boxes, references, ref_index)

    ev, parts, refs = _scene(front_colour_first=True)
    body = body_model(1)
    init = MultiInit(parts=parts, height=SIZE[:, 0, 1] / body.box[0, 1])
    on = method_config("epmcmc-elpda", n_parts=1, n_particles=20)
    off = on.model_copy(update={
        "likelihood": on.likelihood.model_copy(update={"hidden_similarity": None}),
        "association_model": on.association_model.model_copy(update={"occlusion_floor": None}),
    })  # fmt: skip
    counts = []
    for cfg in (on, off):
        flt = make_filter(cfg, init, ev, 0)
        counting = Counting(ev)
        flt.associate(counting)
        counts.append(counting.calls)
    assert counts == [1, 0]  # the overlap cuts are asked for only where P_D or the hidden share use them
