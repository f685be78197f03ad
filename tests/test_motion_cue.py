"""The moving-target cue (common/single_target/motion_cue.py) and its place in the filters.

The cue against known answers on generated frames: a small patch moving over textured ground is
lit, the ground and a stopped patch are not, the camera's motion is taken out (negative control:
without the homographies the whole region moves), a large target is analysed on a coarser level.
The filters multiply the particles' weights by it exactly, whatever their visibility (it says where
the target is, not whether the template sees it), a zero cue changes nothing, a malformed cue is
refused. End to end: a small
low-contrast car driving over textured ground under a panning camera is lost by the polar match
alone and held with the cue.
"""

import math

import cv2
import numpy as np
import pytest
from scipy.stats import norm

from common.settings import MotionCueSettings, profile_for, with_overrides
from common.single_target.motion_cue import MotionCue
from common.single_target.runner import Tracker
from common.sources import Frame
from common.tracking import RBPF, SIR, InitialState, RBPFConfig, SIRConfig
from common.tracking.observation import CuedObservation, cue_log_ratio
from test_scale import texture

CFG = MotionCueSettings(enabled=True)
FPS = 30.0
W, H = 320, 240
CAP = -(math.log(2.0) + norm.logsf(CFG.z_cap))
"""The cue's largest log ratio (z at the cap)."""


def scene(n, speed, contrast=25.0, size=(10, 7), pan=(2.0, 0.5), seed=5, noise=4.0, last_jump=0):
    """``n`` frames (RGB uint8) of a textured patch of ``size`` moving ``speed`` px/frame (right and a
    little down, drawn at sub-pixel positions) over textured ground, seen by a camera panning ``pan``
    px/frame (and ``last_jump`` px more to the right on the last frame), with sensor noise; with each
    frame's true patch centre and the exact first-frame -> image homography."""
    ground = texture(size=(600, 700), seed=seed)
    rng = np.random.default_rng(seed + 1)
    sw, sh = size
    patch = np.clip(128 + contrast * rng.standard_normal((sh, sw, 3)), 0, 255).astype(np.float32)
    gh, gw = ground.shape[:2]
    out = []
    for i in range(n):
        cx, cy = 350 + speed * i, 300 + 0.3 * speed * i
        m = np.float32([[1, 0, cx - sw / 2], [0, 1, cy - sh / 2]])
        sprite = cv2.warpAffine(patch, m, (gw, gh), flags=cv2.INTER_LINEAR)
        mask = cv2.warpAffine(np.ones((sh, sw), np.float32), m, (gw, gh), flags=cv2.INTER_LINEAR)[:, :, None]
        g = ground * (1 - mask) + sprite * mask
        ox, oy = int(190 + pan[0] * i + (last_jump if i == n - 1 else 0)), int(180 + pan[1] * i)
        img = g[oy:oy + H, ox:ox + W] + rng.normal(0.0, noise, (H, W, 3))
        hom = np.array([[1.0, 0, 190 - ox], [0, 1.0, 180 - oy], [0, 0, 1]])
        out.append((np.clip(img, 0, 255).astype(np.uint8), (cx - ox, cy - oy), hom))
    return out


def cue_after(frames, size=(10, 7), homographies=True, scale=1.0):
    cue = MotionCue(CFG, size)
    for i, (img, c, hom) in enumerate(frames):
        cue.update(i / FPS, img, hom if homographies else np.eye(3), c, scale)
    return cue


def test_the_mover_is_lit_and_the_ground_is_not():
    """A patch moving more than its length in D (5 px/frame, D = 3 frames): lit where it is; dark
    where it was D and 2 D ago (the double difference: the current frame equals the other past
    frame there) and on the ground far from it."""
    frames = scene(10, speed=5.0)
    cue = cue_after(frames)
    c = np.array(frames[-1][1])
    step = np.array([5.0, 1.5]) * 3  # the patch's motion over D
    pts = np.array([c, c - step, c - 2 * step, c + [60.0, -40.0]])
    z, lr = cue.z_scores(pts), cue.log_ratio(pts)
    assert z[0] > 2 * CFG.z_cap and lr[0] == pytest.approx(CAP)  # far beyond the cap
    assert z[1] < 2.0 and z[2] < 3.5 and abs(z[3]) < 1.0, z  # the ghosts well below five sigma
    assert cue.frames_with_cue >= 8  # from the third frame on


def test_a_stopped_target_gives_no_evidence():
    frames = scene(10, speed=0.0)
    cue = cue_after(frames)
    lr = cue.log_ratio(np.array([frames[-1][1]]))
    assert lr[0] < 1.0, lr


def test_the_camera_motion_is_taken_out():
    """Negative control: the same frames with identity homographies (no stabilisation) move
    everywhere: the background's energy is many times the noise's, and the mover no longer
    stands out of it."""
    frames = scene(10, speed=2.0, pan=(3.0, 1.0))
    good, bad = cue_after(frames), cue_after(frames, homographies=False)
    c = np.array([frames[-1][1]])
    assert bad._stats[0] > 4 * good._stats[0], (good._stats, bad._stats)
    assert good.log_ratio(c)[0] == pytest.approx(CAP)
    assert bad.z_scores(c)[0] < 0.5 * good.z_scores(c)[0]


def test_a_large_target_is_analysed_on_a_coarser_level():
    frames = scene(8, speed=8.0, size=(60, 40), contrast=40.0)
    cue = cue_after(frames, size=(60, 40))
    assert cue._factor == 0.5  # a 60 px target at most 32 px long: level 1
    c = np.array(frames[-1][1])
    lr = cue.log_ratio(np.array([c, c - [120.0, 60.0]]))
    assert lr[0] > 0.5 * CAP and lr[1] < 1.0, lr


def test_no_cue_before_two_past_frames():
    frames = scene(3, speed=2.0)
    cue = MotionCue(CFG, (10, 7))
    for i, (img, c, hom) in enumerate(frames[:2]):
        cue.update(i / FPS, img, hom, c, 1.0)
    assert np.all(cue.log_ratio(np.array([frames[1][1]])) == 0.0)


# -- the filters --------------------------------------------------------------------------------

class Flat:
    """An observation scoring every hypothesis the same (the cue alone then moves the weights)."""

    time, homography, image_size = 0.0, None, (1000, 1000)

    def score_at(self, hyps):
        return np.full(len(hyps), 0.6), np.ones(len(hyps), bool)

    def score_grid(self, xy):
        return np.full((len(xy), 48), 0.6), np.ones(len(xy), bool)


def right_half(xy):
    return np.where(xy[:, 0] > 500.0, 3.0, 0.0)


def test_sir_multiplies_the_weights_by_the_cue_exactly():
    init = InitialState.from_image_point((500.0, 500.0), None, time=0.0, pos_std=20.0, vel_std=0.0)
    f = SIR(SIRConfig(n_particles=400, ess_threshold_fraction=0.0), init, seed=1)
    f.step(0.0, CuedObservation(Flat(), right_half))
    right = f.particles[:, 0] > 500.0
    for v in (0, 1):  # the cue is about the position: the same factor whatever the visibility
        sel = f.visible == v
        a, b = f.log_w[sel & right], f.log_w[sel & ~right]
        if len(a) and len(b):
            assert np.allclose(a, a[0]) and np.allclose(b, b[0])
            assert a[0] - b[0] == pytest.approx(3.0, abs=1e-12)


def test_rbpf_cue_moves_the_weight_not_the_visibility():
    """The cue multiplies a particle's weight (both visibility hypotheses alike): the lit half takes
    e^3 / (1 + e^3) of the weight, each particle's p(V=1) is what it is without the cue, and a zero
    cue changes nothing at all."""
    init = InitialState.from_image_point((500.0, 500.0), None, time=0.0, pos_std=20.0, vel_std=0.0,
                                         p_visible=0.7)
    cfg = RBPFConfig(n_particles=400, ess_threshold_fraction=0.0)
    plain, zero, cued = (RBPF(cfg, init, seed=2) for _ in range(3))
    s0 = plain.step(0.0, Flat())
    s1 = zero.step(0.0, CuedObservation(Flat(), lambda xy: np.zeros(len(xy))))
    cued.step(0.0, CuedObservation(Flat(), right_half))
    assert np.array_equal(plain.log_w, zero.log_w) and s0.map_estimate == s1.map_estimate
    assert np.array_equal(plain.particles, cued.particles)
    np.testing.assert_allclose(cued.log_pv, plain.log_pv, atol=1e-12)
    right = cued.particles[:, 0] > 500.0
    expected = np.exp(plain.log_w[right]).sum() * math.e ** 3
    expected /= expected + np.exp(plain.log_w[~right]).sum()
    assert float(np.exp(cued.log_w[right]).sum()) == pytest.approx(expected, rel=1e-9)
    assert 0.4 < float(np.exp(plain.log_w[right]).sum()) < 0.6


def test_a_malformed_cue_is_refused_and_nan_is_no_evidence():
    xy = np.zeros((4, 2))
    with pytest.raises(ValueError):
        cue_log_ratio(CuedObservation(Flat(), lambda p: np.zeros(3)), xy)
    assert cue_log_ratio(Flat(), xy) is None
    got = cue_log_ratio(CuedObservation(Flat(), lambda p: np.array([1.0, np.nan, np.inf, -2.0])), xy)
    assert got.tolist() == [1.0, 0.0, 0.0, -2.0]


# -- end to end ----------------------------------------------------------------------------------

def track_errors(frames, cue: bool, seed: int, size=(10, 7)):
    class Src:
        name, fps = "generated", FPS

    st = with_overrides(profile_for(Src(), seed=seed), {"motion_cue": {"enabled": cue}})
    c0 = frames[0][1]
    box = (c0[0] - size[0] / 2, c0[1] - size[1] / 2, *size)
    tracker, errs = None, []
    for i, (img, c, _) in enumerate(frames):
        f = Frame(index=i, time=i / FPS, image=img)
        tracker = tracker or Tracker.start(f, box, st)
        s = tracker.step(f)
        errs.append(math.hypot(s.map_estimate.image_x - c[0], s.map_estimate.image_y - c[1]))
    return tracker, np.array(errs)


def test_a_small_car_over_textured_ground_is_held_with_the_cue_and_lost_without():
    """A 10x7 px low-contrast car at 1.5 px/frame: its template is mostly the ground around it, and
    the polar match alone does not hold it (over 40 px off on every seed while such a car was
    enlarged 4x, 25-92 px enlarged to the design size, stop 46; on an AMD EPYC two seeds of six
    stay 15-17 px off over the last second, 35-38 px at worst: stop 52; with the likelihood tempered
    to a half, stop 55, one seed of six, seed 0, stays within 12 px over the last second, drifting
    off to 21 px by the last frame, and the other five end 26-80 px off); with the cue the track
    stays on the car in most runs (the cue re-weights the particles it reaches: a run whose cloud
    has left the car before the cue takes hold is lost as without it; 3 of seeds 0-4 hold when this
    was written, 6 of 0-5 on the AMD machine, with the model as fitted and tempered). Held: within
    12 px (about a car length) over the last second and never beyond 25 px, one criterion for both."""
    def held(err):
        return bool(np.median(err[-30:]) < 12.0 and err.max() < 25.0)

    frames = scene(90, speed=1.5, contrast=15.0)
    holds, plain_holds = [], []
    for seed in range(4):
        plain, off = track_errors(frames, cue=False, seed=seed)
        cued, on = track_errors(frames, cue=True, seed=seed)
        assert plain.motion_cue is None and cued.motion_cue is not None
        plain_holds.append(held(off))
        holds.append(held(on))
    assert sum(plain_holds) <= 1, plain_holds
    assert sum(holds) >= 2 and sum(holds) >= sum(plain_holds) + 2, (holds, plain_holds)


@pytest.mark.parametrize("size, box", [((10, 7), (10, 7)), ((30, 20), (10, 7))])
def test_movers_over_the_whole_frame_and_the_blob_gives_the_scale(size, box):
    """The re-acquisition's whole-frame movers: the strongest box is the mover (far beyond the
    background's tail over the whole frame); the blob it lies in spans the target (and its motion
    smear), so its scale is the target's or up to twice it, never below. ``box`` is the first box
    the cue was made for: a target three times that is read as three times."""
    from common.single_target.reacquire import tail_probability

    frames = scene(10, speed=5.0, size=size, contrast=40.0)
    cue = cue_after(frames, size=box)
    true_scale = max(size) / max(box)
    xy, z = cue.movers(true_scale)
    top = int(np.argmax(z))
    c = np.array(frames[-1][1])
    assert np.hypot(*(xy[top] - c)) < 0.8 * max(size)
    far = np.hypot(*(xy - xy[top]).T) > max(size)
    assert len(z) * tail_probability(z, top, far, 0.9) < 1e-4
    assert 1.0 <= cue.blob_scale(tuple(xy[top])) / true_scale <= 2.0
    still = cue.blob_scale((5.0, 5.0))  # the still ground: no blob, or a speck of noise
    assert still is None or still < 0.3


@pytest.mark.parametrize("size", [(60, 40), (100, 60)])
def test_a_large_car_in_small_boxes_stands_out_only_of_the_ground_without_its_own_blob(size):
    """A car six to ten times the boxes' length (the re-acquisition's sweep at a small scale, as on
    uav123-car16 at frames 410-428, docs/real-footage.md, stop 46): its strongest box lies on it, but
    its other parts' boxes, beyond a box length from that one, are as strong. Counted as the
    background (the rule before) they make the car expected by chance (tail n P 0.04-0.3 here,
    against the 0.005 a 10 fps frame allows); the background fitted without the blob the strongest
    box lies in (:func:`background_boxes`) leaves the car far beyond it. The blob spans the car and
    its smear: its box holds the car's centre and is at most twice the car each way."""
    from common.single_target.reacquire import background_boxes, tail_probability

    frames = scene(10, speed=5.0, size=size, contrast=40.0)
    cue = cue_after(frames)  # boxes of the 10 x 7 px first box
    xy, z = cue.movers(1.0)
    top = int(np.argmax(z))
    c = np.array(frames[-1][1])
    blob = cue.blob_box(tuple(xy[top]))
    x0, y0, w, h = blob
    assert x0 <= c[0] <= x0 + w and y0 <= c[1] <= y0 + h
    assert size[0] <= w <= 2 * size[0] and size[1] <= h <= 2 * size[1], blob
    allowed = 0.05 * 0.1
    plain = len(z) * tail_probability(z, top, background_boxes(xy, top, 10.0), 0.9)
    off_blob = len(z) * tail_probability(z, top, background_boxes(xy, top, 10.0, blob, (5.0, 3.5)), 0.9)
    assert plain > 5 * allowed and off_blob < 1e-20 * allowed, (plain, off_blob)
    assert cue.blob_scale(tuple(xy[top])) == pytest.approx(min(w, h) / 7.0)


def test_no_mover_stands_out_of_a_still_scene():
    """Negative control: the same ground with the patch stopped: the strongest box is one of the
    background's (many expected false alarms at its z), not a detection."""
    from common.single_target.reacquire import background_boxes, tail_probability

    cue = cue_after(scene(10, speed=0.0))
    xy, z = cue.movers(1.0)
    top = int(np.argmax(z))
    far = np.hypot(*(xy - xy[top]).T) > 10
    assert len(z) * tail_probability(z, top, far, 0.9) > 0.1
    # leaving out the strongest box's blob (a speck of noise, if any) does not make it a mover
    blob = cue.blob_box(tuple(xy[top]))
    assert blob is None or max(blob[2], blob[3]) < 20
    far = background_boxes(xy, top, 10.0, blob, (5.0, 3.5))
    assert len(z) * tail_probability(z, top, far, 0.9) > 0.1
    # movers() replaced the tracking cue's map: prepare() restores it
    cue.prepare(scene(10, speed=0.0)[-1][1], 1.0)
    assert cue._stats is not None and cue._grid.shape[1] == 2


def test_ground_just_come_into_view_is_no_evidence_of_calm():
    """The still scene with the camera jumping 170 px (53 % of the view) on the last frame: most of
    the frame is ground neither past frame saw, where d is 0. Boxes not wholly seen are left out of
    the statistics and of the movers, so the strongest box is one of the background's again (many
    false alarms expected at its z, as without the jump) and no blob stands out. Counted as boxes of
    no motion (the rule before) they pulled the median towards 0: the strongest box of this still
    scene had z 10.6 and the seen ground was one blob read as 20x the box (uavdt-S1001-away after its
    camera's jump: a mover at z 78 read as 12x the target, docs/real-footage.md, stop 40)."""
    from common.single_target.reacquire import tail_probability

    frames = scene(10, speed=0.0, last_jump=170)
    cue = cue_after(frames)
    xy, z = cue.movers(1.0)
    assert cue._seen.mean() < 0.5  # most of the view was not seen before the jump
    assert np.all(xy[:, 0] < W - 170 + 10)  # only boxes on the ground the past frames saw
    top = int(np.argmax(z))
    far = np.hypot(*(xy - xy[top]).T) > 10
    assert len(z) * tail_probability(z, top, far, 0.9) > 0.1 and z[top] < 6.0
    blob = cue.blob_scale(tuple(xy[top]))
    assert blob is None or blob < 3.0
