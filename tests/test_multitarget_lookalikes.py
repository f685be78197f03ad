"""Look-alikes: people standing still in clothes like a walker's, the whole-body clutter that makes the
association matter (Bhaskar and Mihaylova 2011, section 3.2: one measurement in the gate is the
target's, the rest clutter). In the scene: where they stand and what they wear. In the gate: a
look-alike beside the person is a measurement of its own, PDA weighs it like the person, ELPDA by its
colour (the expected likelihood's attribute) almost not at all."""

import math

import cv2
import numpy as np
import pytest

from common.multitarget import gating
from common.multitarget.appearance import HistogramEvidence, part_boxes
from common.multitarget.association import association_probabilities, attribute_ratio, log_gauss2
from common.multitarget.body import body_model
from common.multitarget.config import AssociationConfig, GateConfig
from common.scene.people import PeopleScene, PeopleSceneConfig
from common.scene.people import body as people_body
from common.scene.people.render import FLOOR, SKIN, TROUSERS, draw_person, hue_shifted, part_colours


def _hue(rgb) -> float:
    return float(cv2.cvtColor(np.uint8([[rgb]]), cv2.COLOR_RGB2HSV)[0, 0, 0]) * 2.0


def test_lookalikes_stand_on_the_walkers_paths_in_turned_shirts_behind_everyone():
    cfg = PeopleSceneConfig(n_people=3, noise_sigma=0.0)
    scene = PeopleScene(cfg, seed=5)
    assert len(scene.lookalikes) == 3 * cfg.lookalikes_per_person
    first = scene.frame(0)
    duration = cfg.n_frames / cfg.fps
    for k, w in enumerate(scene.walkers):
        own = scene.lookalikes[k * cfg.lookalikes_per_person: (k + 1) * cfg.lookalikes_per_person]
        xs = [w.x(t) for t in np.linspace(0.0, duration, 200)]
        for la in own:
            torso = la.pose.centres[1]
            assert min(xs) <= torso[0] <= max(xs)  # the walker passes it
            assert 2.0 <= w.feet_y - la.feet_y <= 8.0  # just behind the walker's lane
            turn = abs((_hue(la.colours[1]) - _hue(w.colours[1]) + 180.0) % 360.0 - 180.0)
            assert 20.0 <= turn <= 44.0, turn  # 25-40 degrees, up to OpenCV's 2-degree hue steps
            assert not np.array_equal(la.colours[6], w.colours[6])  # other trousers
    shown = 0
    for la in scene.lookalikes:
        x, y = np.round(la.pose.centres[1]).astype(int)
        if first.labels[y, x] == 0:  # not hidden by a walker: the background shows a look-alike's shirt, label 0
            assert any(np.array_equal(first.image[y, x], o.colours[1]) for o in scene.lookalikes)
            shown += np.array_equal(first.image[y, x], la.colours[1])
    assert shown >= len(scene.lookalikes) // 2  # most are not hidden by a nearer look-alike
    # negative control: without look-alikes no shirt is there
    bare = PeopleScene(cfg.model_copy(update={"lookalikes_per_person": 0}), seed=5)
    assert bare.lookalikes == []
    for la in scene.lookalikes:
        x, y = np.round(la.pose.centres[1]).astype(int)
        assert not np.array_equal(bare.background[y, x], la.colours[1])
    # everything else (walkers, their truth, the clutter boxes) is the same scene
    f = bare.frame(0)
    assert np.array_equal(f.truth.parts, first.truth.parts) and np.array_equal(f.labels, first.labels)


def _two_people(lookalike: bool):
    """A 70 px person at x = 80 and, optionally, a look-alike (shirt hue turned 30 degrees, other
    trousers) standing 20 px to its right just behind it; plain floor, no noise."""
    img = np.empty((180, 200, 3), np.uint8)
    img[:] = FLOOR
    labels = np.zeros(img.shape[:2], np.uint8)
    person = part_colours((200, 30, 30), TROUSERS[0], SKIN[0])
    pose = people_body.pose(80.0, 150.0, 70.0, 1.0, 0.3, math.radians(25), math.radians(22))
    if lookalike:
        clone = part_colours(hue_shifted((200, 30, 30), 30.0), TROUSERS[1], SKIN[1])
        draw_person(img, labels, people_body.pose(100.0, 146.0, 70.0, -1.0, 1.0, 0.07, 0.07), clone, 1)
    draw_person(img, labels, pose, person, 0)
    return img, pose


@pytest.mark.parametrize("lookalike", [True, False])
def test_a_lookalike_in_the_gate_is_a_measurement_that_elpda_tells_from_the_person(lookalike):
    body = body_model(10)
    height = np.array([70.0])
    ref_img, pose = _two_people(False)
    parts = body.from_ten(pose.centres[None])  # (1, 10, 2)
    size = body.box[None] * height[:, None, None]
    refs = HistogramEvidence(ref_img).histograms(part_boxes(parts, size).reshape(-1, 4)).reshape(1, 10, -1)
    img, _ = _two_people(lookalike)
    ev = HistogramEvidence(img)
    cfg = GateConfig()  # fixed 15 px gate, the whole structure
    pred = parts + np.array([5.0, 0.0])  # the prediction a little towards the look-alike: both in its 15 px gate
    meas = gating.measure(pred, np.zeros((1, 10, 2, 2)), np.zeros((1, 1, 2, 2)), size, refs, ev, cfg)
    z, rho = meas.z[0, 0][meas.valid[0, 0]], meas.rho[0, 0][meas.valid[0, 0]]
    torso = parts[0, 0]
    near = np.linalg.norm(z - torso, axis=1) <= 2.5
    assert near.sum() == 1 and rho[near][0] > 0.9  # the person is measured where it is
    if not lookalike:
        assert len(z) == 1  # negative control: one person, one measurement
        return
    far = np.linalg.norm(z - (torso + [16.0, -3.0]), axis=1) <= 4.0  # its torso, 20 px right and 2 px up
    assert len(z) == 2 and far.sum() == 1  # the look-alike is a second measurement in the gate
    assert 0.3 < rho[far][0] < rho[near][0] - 0.15  # similar, but less than the person itself
    a = AssociationConfig()
    lg = log_gauss2(meas.z - meas.centre[:, :, None], meas.s_cov[:, :, None])
    args = (lg, meas.valid, meas.volume, a.p_detect, cfg.p_gate, a.clutter_density)
    pda = association_probabilities(*args)[0, 0, 1:][meas.valid[0, 0]]
    elpda = association_probabilities(*args, attribute_ratio(meas.rho, a.attribute_lambda))[0, 0, 1:][meas.valid[0, 0]]
    assert pda[far][0] > 0.15  # kinematics alone cannot tell them apart: the PDAF's combined measurement is pulled
    assert elpda[near][0] > 0.95 and elpda[far][0] < 0.01  # the colour attribute can



def test_the_structure_is_measured_where_its_core_matches_not_where_the_swung_limbs_pull_it():
    """The gate's measurement shifts the predicted structure over the image. Predicted at the rest pose
    (what the filter predicts of limbs it cannot follow), walkers mid-stride match best where their
    swinging limbs overlap the boxes, off the torso; matched on the core (torso and head,
    ``GateConfig.core_deviation``), the measurement is at the torso. Walkers of scene 101 (three
    people, 80 frames), predicted 2 px off their torso."""
    body = body_model(10)
    scene = PeopleScene(PeopleSceneConfig(), seed=101)
    first = scene.frame(0)
    height = np.array([w.height for w in scene.walkers])
    size = body.box[None] * height[:, None, None]
    refs = HistogramEvidence(first.image).histograms(part_boxes(body.from_ten(first.truth.parts), size).reshape(-1, 4))
    refs = refs.reshape(len(height), 10, -1)
    cfg = GateConfig(stride=1)
    core = body.max_dev <= cfg.core_deviation
    assert core.tolist() == [True, True] + [False] * 8  # torso and head
    err = {"all": [], "core": []}
    for i in range(4, len(scene), 6):
        frame = scene.frame(i)
        torso = body.from_ten(frame.truth.parts)[:, 0]
        pred = np.stack([body.place(c + [2.0, 0.0], h) for c, h in zip(torso, height)])
        args = (pred, np.zeros(pred.shape + (2,)), np.zeros((len(height), 1, 2, 2)), size, refs,
                HistogramEvidence(frame.image), cfg)
        for name, parts in (("all", None), ("core", core)):
            meas = gating.measure(*args, core=parts)
            err[name] += np.linalg.norm(meas.z[:, 0, 0] - torso, axis=-1).tolist()  # each gate's highest peak
    med = {k: float(np.median(v)) for k, v in err.items()}
    assert med["core"] <= 1.5
    assert med["all"] >= med["core"] + 0.75
