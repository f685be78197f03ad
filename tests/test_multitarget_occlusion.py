"""Occlusion-aware detection probability (:mod:`common.multitarget.occlusion`) and the initial velocity spread."""

import math

import numpy as np
import pytest

from common.multitarget import HistogramEvidence, MultiInit, body_model, make_filter, method_config
from common.multitarget import association as da
from common.multitarget.occlusion import bounding_boxes, covered_fraction, detection_probability
from common.scene.people import PeopleScene, PeopleSceneConfig


def test_covered_fraction_by_hand():
    boxes = np.array([
        [0.0, 0.0, 10.0, 20.0],   # far (y1 = 20)
        [5.0, 2.0, 15.0, 22.0],   # nearer: covers x 5-10, y 2-20 of box 0 -> 5 * 18 / 200 = 0.45
        [100.0, 0.0, 110.0, 20.0],  # far away from both: nothing in front of it
    ])  # fmt: skip
    cov = covered_fraction(boxes)
    assert cov == pytest.approx([0.45, 0.0, 0.0])  # the nearest box is never covered by a farther one


def test_covered_fraction_caps_at_one_and_ties_hide_nothing():
    far = [0.0, 0.0, 10.0, 10.0]
    front = [[-1.0, -1.0, 11.0, 11.0], [0.0, 0.0, 10.0, 12.0]]  # both nearer and both covering all of it
    assert covered_fraction(np.array([far, *front]))[0] == 1.0
    tie = np.array([[0.0, 0.0, 10.0, 10.0], [2.0, 0.0, 12.0, 10.0]])  # same feet line: neither in front
    assert covered_fraction(tie) == pytest.approx([0.0, 0.0])


def test_detection_probability_scales_with_the_visible_share():
    parts = np.array([[[5.0, 10.0]], [[10.0, 12.0]], [[5.0, 10.0]]])  # 1-part bodies, box 10 x 20 around each
    size = np.full((3, 1, 2), [10.0, 20.0])
    boxes = bounding_boxes(parts, size)
    assert boxes[0] == pytest.approx([0.0, 0.0, 10.0, 20.0])
    # target 0 and 2 coincide (a tie); target 1 is in front of both and covers (5 * 18) / 200 of each
    pd = detection_probability(0.9, parts, size, floor=0.05)
    assert pd == pytest.approx([0.9 * 0.55, 0.9, 0.9 * 0.55])
    hidden = np.array([[[5.0, 10.0]], [[5.0, 12.0]]])
    assert detection_probability(0.9, hidden, np.full((2, 1, 2), [10.0, 20.0]), floor=0.05)[0] == pytest.approx(0.9 * 0.1)
    assert detection_probability(0.9, hidden, np.full((2, 1, 2), [10.0, 20.0]), floor=0.2)[0] == pytest.approx(0.9 * 0.2)


def test_per_gate_detection_probability_in_eq_12():
    lg = np.log(np.array([[0.01, 0.002], [0.01, 0.002]]))
    valid = np.ones((2, 2), bool)
    per_gate = da.association_probabilities(lg, valid, np.array([100.0, 100.0]), np.array([0.9, 0.2]), 0.95, 0.01)
    for g, pd in enumerate([0.9, 0.2]):
        alone = da.association_probabilities(lg[g], valid[g], np.array(100.0), pd, 0.95, 0.01)
        assert per_gate[g] == pytest.approx(alone, rel=1e-12)
    assert per_gate.sum(axis=-1) == pytest.approx([1.0, 1.0])
    # classical form beta_0 : beta_j = lambda (1 - P_D P_G) / P_D : N_j -- a hidden target's gate goes to beta_0
    b = 0.01 * (1 - 0.2 * 0.95) / 0.2
    assert per_gate[1] == pytest.approx(np.array([b, 0.01, 0.002]) / (b + 0.012), rel=1e-12)
    assert per_gate[1, 0] > 0.75 > 0.2 > per_gate[0, 0]


def test_per_target_detection_probability_in_jpda():
    # two targets, one measurement in both gates; joint events: (0,0), (1,0), (0,1) -- by hand
    lg = np.log(np.array([[0.02], [0.01]]))
    gated = np.ones((2, 1), bool)
    pd, pg, lam = np.array([0.9, 0.3]), 0.95, 0.01
    beta = da.jpda_probabilities(lg, gated, pd, pg, lam)
    miss = 1 - pd * pg
    hit = pd * np.exp(lg[:, 0]) / lam
    e00, e10, e01 = miss[0] * miss[1], hit[0] * miss[1], miss[0] * hit[1]
    tot = e00 + e10 + e01
    assert beta[0] == pytest.approx([(e00 + e01) / tot, e10 / tot], rel=1e-12)
    assert beta[1] == pytest.approx([(e00 + e10) / tot, e01 / tot], rel=1e-12)
    same = da.jpda_probabilities(lg, gated, 0.9, pg, lam)
    assert same == pytest.approx(da.jpda_probabilities(lg, gated, np.array([0.9, 0.9]), pg, lam), rel=1e-12)
    assert not np.allclose(beta, same)


def _filter(**cfg):
    scene = PeopleScene(PeopleSceneConfig(n_people=2, n_frames=10), seed=1)
    f0 = scene.frame(0)
    config = method_config("epmcmc-elpda", n_particles=400, **cfg)
    init = MultiInit.from_truth(f0.truth.parts, f0.truth.boxes, body_model(config.n_parts))
    return make_filter(config, init, HistogramEvidence(f0.image), 3)


def test_filter_lowers_p_detect_of_the_hidden_target_only():
    flt = _filter()
    a = flt.config.association_model
    parts = flt.moments()[0]
    near = int(np.argmax(bounding_boxes(parts, flt.targets.box_size)[:, 3]))
    far = 1 - near
    apart = parts.copy()
    apart[far] += parts[near, 0] - parts[far, 0] + np.array([80.0, -1.0])  # 80 px to the side
    assert flt.detection_probability(apart) == pytest.approx([a.p_detect, a.p_detect])
    behind = parts.copy()
    behind[far] += parts[near, 0] - parts[far, 0] - np.array([0.0, 1.0])  # same place, feet 1 px higher
    pd = flt.detection_probability(behind)
    assert pd[near] == a.p_detect and pd[far] < 0.2 * a.p_detect
    off = _filter(association_model=flt.config.association_model.model_copy(update={"occlusion_floor": None}))
    assert off.detection_probability(behind) == pytest.approx([a.p_detect, a.p_detect])


def test_initial_velocities_spread_per_body():
    flt = _filter()
    vel = flt.particles[..., 2:]  # (T, N, P, 2)
    assert np.all(vel == vel[:, :, :1])  # one body velocity per particle, shared by every part
    sd = vel[:, :, 0].std(axis=1)
    assert sd == pytest.approx(np.full((2, 2), flt.config.init_speed_spread), rel=0.15)
    still = _filter(init_speed_spread=0.0)
    assert not still.particles[..., 2:].any()
    np.testing.assert_array_equal(still.particles[..., :2], flt.particles[..., :2])  # positions drawn first, unchanged
    assert math.isclose(float(vel.mean()), 0.0, abs_tol=4.0)


def test_depth_order_comes_from_the_root_not_the_noisy_limbs():
    flt = _filter()
    a = flt.config.association_model
    parts = flt.moments()[0]
    near = int(np.argmax(parts[:, 0, 1] + flt.targets.height))  # feet of the rest pose: root + a share of H
    far = 1 - near
    behind = parts.copy()
    behind[far] += parts[near, 0] - parts[far, 0] - np.array([0.0, 2.0])  # same place, standing 2 px higher
    behind[far, 2:, 1] += 10.0  # ... but with its limbs estimated 10 px low (lower than the near one's)
    pd = flt.detection_probability(behind)
    assert pd[near] == a.p_detect and pd[far] < 0.2 * a.p_detect
    raw = detection_probability(a.p_detect, behind, flt.targets.box_size, a.occlusion_floor)  # judged on the limbs
    assert raw[far] == a.p_detect  # the limb boxes would have put the far person in front


def test_occluder_boxes_and_covered_share_by_hand():
    from common.multitarget.occlusion import covered_share, occluder_boxes

    parts = np.array([[[10.0, 20.0]], [[14.0, 24.0]], [[100.0, 20.0]]])  # 1 stands in front of 0 (feet lower)
    size = np.full((3, 1, 2), [10.0, 20.0])
    occ = occluder_boxes(parts, size)
    boxes = bounding_boxes(parts, size)
    assert np.array_equal(occ[0, 1], boxes[1]) and not occ[0, [0, 2]].any()  # only 1 is in front of 0
    assert not occ[1].any()  # nobody is in front of the nearest
    assert np.array_equal(occ[2, 1], boxes[1])  # in front by depth, even where it covers nothing
    part = np.array([[5.0, 10.0, 15.0, 30.0], [105.0, 10.0, 115.0, 30.0]])
    # target 0's box x 5-15, y 10-30 under target 1's x 9-19, y 14-34: 6 x 16 of 10 x 20
    assert covered_share(part, occ[0][None]) == pytest.approx([0.48, 0.0])
    assert covered_share(part[:1], np.array([[[0.0, 0.0, 20.0, 40.0], [0.0, 0.0, 20.0, 40.0]]]))[0] == 1.0  # capped


def test_a_hidden_part_counts_as_hidden_similarity_not_as_the_occluders_pixels():
    from common.multitarget.appearance import part_boxes
    from common.multitarget.likelihood import AssociationTerms, TargetModels, log_likelihood
    from common.multitarget.config import LikelihoodConfig
    from common.multitarget.occlusion import occluder_boxes

    body = body_model(1)
    img = np.full((120, 160, 3), 128, np.uint8)
    img[30:70, 20:40] = (220, 20, 20)  # target 0 (red), standing clear
    img[40:80, 90:110] = (20, 20, 220)  # target 1 (blue), nearer (feet at y 80)
    ev = HistogramEvidence(img)
    size = np.full((2, 1, 2), [20.0, 40.0])
    height = size[:, 0, 1] / body.box[0, 1]
    home = np.array([[[30.0, 50.0]], [[100.0, 60.0]]])
    refs = ev.histograms(part_boxes(home, body.box[None] * height[:, None, None]).reshape(-1, 4))[:, None]
    targets = TargetModels(body, height, refs)
    pred = np.array([[[95.0, 55.0]], [[100.0, 60.0]]])  # target 0 predicted just behind target 1
    occ = occluder_boxes(pred, targets.box_size)  # target 1's box covers all of target 0's there
    terms = AssociationTerms(z=np.zeros((2, 1, 1, 2)), valid=np.zeros((2, 1, 1), bool), beta=np.ones((2, 1, 2)) / 2,
                             volume=np.ones((2, 1)), r_cov=np.broadcast_to(np.eye(2), (2, 1, 2, 2)), p_gate=0.95,
                             located=np.zeros(1, np.intp), centre=np.zeros((2, 1, 2)), occluders=occ)
    pos = np.array([[[[100.0, 60.0]], [[30.0, 50.0]], [[60.0, 100.0]]]])  # behind 1; on its own pixels; on the floor
    cfg = LikelihoodConfig(w_association=0.0, w_structure=0.0, hidden_similarity=0.8)
    ll = log_likelihood(pos, np.array([0]), targets, ev, terms, cfg)[0]
    lam, w = cfg.colour_lambda, cfg.w_appearance
    assert ll[0] == pytest.approx(-w * lam * (1 - 0.8))  # fully hidden: the occluder's blue does not count
    assert ll[1] == pytest.approx(0.0, abs=1e-5)  # visible on its own pixels: rho = 1
    off = log_likelihood(pos, np.array([0]), targets, ev, terms, cfg.model_copy(update={"hidden_similarity": None}))[0]
    rho_blue = ev.similarity(part_boxes(pos[0, :1, 0], targets.box_size[0]), refs[0], np.zeros(1, np.intp))[0]
    assert rho_blue < 0.6  # the occluder's blue (and a little floor) against target 0's red
    assert off[0] == pytest.approx(-w * lam * (1 - max(rho_blue, cfg.colour_floor)))  # negative control: its pixels count
    assert off[0] < ll[0] - 0.5
    assert ll[1] == off[1] and ll[2] == off[2] < -1.0  # uncovered boxes (own pixels, the floor): unchanged
    # the nearest target is hidden by nobody: its pixels always count
    on1 = log_likelihood(pos, np.array([1]), targets, ev, terms, cfg)[0]
    off1 = log_likelihood(pos, np.array([1]), targets, ev, terms, cfg.model_copy(update={"hidden_similarity": None}))[0]
    assert np.array_equal(on1, off1)


def test_visible_strip_by_hand():
    from common.multitarget.occlusion import visible_strip

    box = np.array([0.0, 0.0, 10.0, 20.0])
    cases = [
        ([[6.0, -5.0, 20.0, 30.0]], [0.0, 0.0, 6.0, 20.0]),  # covered on the right, full height
        ([[-5.0, 15.0, 20.0, 30.0]], [0.0, 0.0, 10.0, 15.0]),  # covered below
        ([[-5.0, -5.0, 2.0, 30.0], [8.0, -5.0, 20.0, 30.0]], [2.0, 0.0, 8.0, 20.0]),  # between two people
        ([[7.0, 12.0, 20.0, 30.0]], [0.0, 0.0, 7.0, 20.0]),  # a corner: the larger strip (7 x 20 > 10 x 12)
        ([[3.0, 8.0, 20.0, 30.0]], [0.0, 0.0, 10.0, 8.0]),  # ... (10 x 8 > 3 x 20)
        ([[50.0, 0.0, 60.0, 20.0], [0.0, 0.0, 0.0, 0.0]], [0.0, 0.0, 10.0, 20.0]),  # apart, and an empty box
    ]
    for occ, want in cases:
        assert visible_strip(box, np.array(occ)).tolist() == want, occ
    whole = visible_strip(box, np.array([[-1.0, -1.0, 11.0, 21.0]]))
    assert whole[0] == whole[2]  # covered whole: empty
    batch = visible_strip(np.stack([box, box + 100.0]), np.array([[[6.0, -5.0, 20.0, 30.0]], [[0.0, 0.0, 0.0, 0.0]]]))
    assert batch.tolist() == [[0.0, 0.0, 6.0, 20.0], (box + 100.0).tolist()]


def test_a_half_hidden_part_is_scored_on_its_visible_pixels():
    """Half behind a nearer person, a part on its own spot scores its visible half as its own colour: it beats
    hiding fully behind the occluder, where scoring the whole box (the occluder's half in it) lost."""
    from common.multitarget.appearance import part_boxes
    from common.multitarget.config import LikelihoodConfig
    from common.multitarget.likelihood import AssociationTerms, TargetModels, log_likelihood
    from common.multitarget.occlusion import occluder_boxes

    body = body_model(1)
    height = np.array([40.0, 40.0]) / body.box[0, 1]  # boxes 27.7 x 40 px
    size = body.box[None] * height[:, None, None]
    half = 0.5 * size[0, 0, 0]
    pred = np.array([[[30.0, 50.0]], [[30.0 + half, 51.0]]])  # target 1 (feet 1 px lower, in front) from x 30 on
    box0, box1 = np.rint(part_boxes(pred[:, 0], size[:, 0])).astype(int)
    img = np.full((120, 160, 3), 128, np.uint8)
    img[box0[1]:box0[3], box0[0]:box0[2]] = (220, 20, 20)  # target 0, red
    img[box1[1]:box1[3], box1[0]:box1[2]] = (20, 20, 220)  # target 1, blue, painted over target 0's right half
    ev = HistogramEvidence(img)
    refs = np.stack([ev.histograms(np.array([[box0[0], box0[1], 30, box0[3]]], float))[0],
                     ev.histograms(box1[None].astype(float))[0]])[:, None]  # fmt: skip
    targets = TargetModels(body, height, refs)
    terms = AssociationTerms(z=np.zeros((2, 1, 1, 2)), valid=np.zeros((2, 1, 1), bool), beta=np.ones((2, 1, 2)) / 2,
                             volume=np.ones((2, 1)), r_cov=np.broadcast_to(np.eye(2), (2, 1, 2, 2)), p_gate=0.95,
                             located=np.zeros(1, np.intp), centre=np.zeros((2, 1, 2)),
                             occluders=occluder_boxes(pred, targets.box_size))  # fmt: skip
    pos = pred[None]  # target 0 on its own spot (its right half hidden); on target 1's (hidden whole)
    cfg = LikelihoodConfig(w_association=0.0, w_structure=0.0, hidden_similarity=0.75, visible_pixels_only=True)
    lam, w = cfg.colour_lambda, cfg.w_appearance
    on = log_likelihood(pos, np.array([0]), targets, ev, terms, cfg)[0]
    assert on[0] == pytest.approx(-w * lam * (1 - (0.5 * 1.0 + 0.5 * 0.75)), abs=1e-5)  # visible half: rho 1
    assert on[1] == pytest.approx(-w * lam * (1 - 0.75))  # fully hidden
    assert on[0] > on[1]
    off = log_likelihood(pos, np.array([0]), targets, ev, terms, cfg.model_copy(update={"visible_pixels_only": False}))[0]
    assert off[0] < off[1]  # negative control: the whole box's mixed colours made hiding the better bet
