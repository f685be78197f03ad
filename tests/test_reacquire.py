"""Loss and re-acquisition (common/single_target/reacquire.py) and the scale through a 10x zoom, on the synthetic
event sequences of common/scene/events.py (real-footage profile: no homography, stabilised)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import beta

from common.detector.layout import SUPPORT_RADIUS_PX
from common.detector.observation import DetectorObservation
from common.detector.resample import quantise_factor
from common.single_target.reacquire import (Detection, MoverGate, Reacquirer, acceptance_threshold, background_boxes,
                                            tail_probability)
from common.single_target.runner import Tracker
from common.tracking.likelihood import beta_by_moments
from common.scene.events import ExitSource, ZoomSource
from common.settings import ReacquisitionSettings, profile_for
from common.tracking.state import Estimate, TrackState


def _track(src, settings):
    f0 = src.frame(0)
    tracker = Tracker.start(f0, f0.truth.box, settings)
    rows = []
    for f in src:
        s = tracker.step(f)
        c = f.truth.centre
        err = np.nan if c is None else float(np.hypot(s.map_estimate.image_x - c[0], s.map_estimate.image_y - c[1]))
        lost = tracker.reacquirer is not None and tracker.reacquirer.lost
        rows.append((err, s.reacquired, tracker.scale.target_length_px,
                     max(f.truth.box[2:]) if f.truth.box else np.nan, s.axis_aligned_box(), f.truth.box,
                     lost, (s.map_estimate.image_x, s.map_estimate.image_y)))
    return tracker, rows


@pytest.fixture(scope="module")
def exit_source():
    return ExitSource(seed=0)


def test_exit_source_events(exit_source):
    src = exit_source
    assert src.frame(src.exit_frame - 3).truth.box is not None
    assert src.frame(src.exit_frame).truth.box is None
    assert src.frame(src.return_frame - 1).truth.box is None
    back = src.frame(src.return_frame + 3).truth.box
    start = src.frame(0).truth.box
    assert back is not None and back[0] < 100 and abs(back[1] - start[1]) > 150  # elsewhere: left edge, other row


def test_target_leaving_and_returning_is_reacquired(exit_source):
    """Re-acquired within 0.6 s (6 frames at 10 fps) of the car being wholly back in the frame, by
    the movers, and then held to within a tenth of its length (5.2 px); by the tiles alone within
    3 s; with re-acquisition off (negative control) it is never found again."""
    src = exit_source
    st = profile_for(src)
    assert st.reacquisition.enabled
    tracker, rows = _track(src, st)
    err = np.array([r[0] for r in rows])
    # held to within a tenth of its length while the matcher can score it (its footprint inside the
    # frame), to within a pixel on the median (measured: 3.4 px at most, on the second frame after
    # the start, before the cloud has learnt the car's 15 px a frame; 0.5 px median)
    tenth = 0.1 * max(src.frame(0).truth.box[2:])
    inner = [i for i in range(src.exit_frame) if src.frame(i).truth.box is not None
             and src.frame(i).truth.centre[0] < 1280 - SUPPORT_RADIUS_PX]
    assert len(inner) > 30 and np.max(err[inner]) < tenth and np.median(err[inner]) < 1.0
    whole = next(i for i in range(src.return_frame, len(src))
                 if src.frame(i).truth.visible_fraction >= 1.0)
    relocks = [i for i, r in enumerate(rows) if r[1]]
    # the car drives back in: found as the frame's strongest mover within 6 frames of being whole
    # in the frame (the first confirms the second, in boxes of the size that found it, restarting
    # once the matcher can score the mover and the quarter length about it, where the car's centre
    # may lie: measured 6, the car's centre 14 px nearer the edge than its box's on the frames
    # before), then within the restart cloud's width (a quarter of its length, restart_pos_lengths)
    # on the restart's frame, within two of its sigmas (half a length) on the next, while the
    # cloud, restarted with no velocity, learns the car's 15 px a frame, and within a tenth of its
    # length from the next on (measured: 0.9 px, 23.8 px, then 3.5 px at most; earlier code on
    # another machine, whose OpenCV takes other SIMD paths: 10.8 px on the frame after, then 1 px)
    assert relocks and whole <= relocks[0] <= whole + 6
    quarter, half = 2.5 * tenth, 5.0 * tenth
    assert err[relocks[0]] < quarter and err[relocks[0] + 1] < half and np.all(err[relocks[0] + 2:] < tenth)
    assert tracker.reacquirer.detections == 1 and tracker.reacquirer.mover_detections == 1
    # while lost the estimate stays in the frame (the filter's MAP there, else where the target was
    # last held): nothing is reported beyond the frame. Where in the frame is the lost cloud's MAP,
    # which drifts: on this scene within 5 footprints of the right edge with the model as fitted, 798
    # px from it with the likelihood tempered; over exit scenes 0-4 and filter seeds 0-1, more than 5
    # footprints from it on 2 runs of 10 as fitted and 4 tempered (stop 55)
    lost = [i for i, r in enumerate(rows) if r[6]]
    assert len(lost) > 10
    xy = np.array([rows[i][7] for i in lost])
    assert np.all((xy[:, 0] >= 0) & (xy[:, 0] <= 1279))
    assert np.all((xy[:, 1] >= 0) & (xy[:, 1] <= 719))

    off = st.model_copy(update={"reacquisition": st.reacquisition.model_copy(update={"enabled": False})})
    _, rows_off = _track(src, off)
    err_off = np.array([r[0] for r in rows_off])
    assert not any(r[1] for r in rows_off)
    assert np.median(err_off[whole:]) > 50.0 and np.mean(err_off[whole:] < 3.0) < 0.2

    # without the movers the tiled polar-match search alone finds it, later
    tiles = st.model_copy(update={"reacquisition": st.reacquisition.model_copy(update={"motion_search": False})})
    tracker_t, rows_t = _track(src, tiles)
    relocks_t = [i for i, r in enumerate(rows_t) if r[1]]
    assert tracker_t.reacquirer.searches > 10 and tracker_t.reacquirer.mover_detections == 0
    if not relocks_t and not tracker_t.reacquirer.lost and rows_t[-1][0] > 5 * max(src.frame(0).truth.box[2:]):
        # a known outcome on one machine of two (AVX-512; the same code, other floating-point sums):
        # without the movers the lost filter's own cloud reaches the parked white car at the top
        # right (a look-alike to the colour-blind matcher: score 0.97-0.99 from frame 78, above the
        # 0.966 the search's own tiles demand of a detection there) before the tiles reach the
        # moving car, and holds it (docs/real-footage.md, stop 36). The movers, on in the product,
        # find the moving car first (above). Only that outcome is excused: a search that runs and
        # does not find the car still fails below.
        pytest.xfail("without the movers the lost filter held a parked look-alike before the tiles found the car")
    assert relocks_t and relocks[0] < relocks_t[0] <= whole + 30
    # as above (measured: 3.8 px on the frame after it, the restart's cloud a quarter length wide,
    # then under 1 px)
    err_t = np.array([r[0] for r in rows_t])
    assert np.all(err_t[relocks_t[0]:relocks_t[0] + 2] < quarter) and np.all(err_t[relocks_t[0] + 2:] < tenth)


@pytest.mark.parametrize("edge_rule", [True, False])
def test_a_target_first_boxed_at_the_frame_edge_is_held(exit_source, edge_rule, monkeypatch):
    """The car first boxed as it comes back in at the left edge, its centre 31 px inside (its
    footprint, 64 px, passes the edge; the tracker refused such a box before): held to within a
    tenth of its length (5.2 px) on every frame of the next 3 s (measured: 2.5 px at most). Negative
    control: without the plain detector's edge rule the second frame is matched on no hypothesis at
    the car and the estimate falls 12.9 px behind it."""
    if not edge_rule:
        monkeypatch.setattr(DetectorObservation, "_at_edge", lambda self, xy: np.zeros(len(xy), bool))
    src = exit_source
    start = src.return_frame + 2
    f0 = src.frame(start)
    box = f0.truth.box
    assert box[0] + box[2] / 2 < SUPPORT_RADIUS_PX
    tracker = Tracker.start(f0, box, profile_for(src))
    errs = []
    for i in range(start, start + 30):
        f = src.frame(i)
        s = tracker.step(f)
        errs.append(float(np.hypot(s.map_estimate.image_x - f.truth.centre[0], s.map_estimate.image_y - f.truth.centre[1])))
    assert tracker.factor == 1.0
    if edge_rule:
        assert max(errs) < 0.1 * max(box[2:]), errs
    else:
        assert errs[1] > 0.1 * max(box[2:]), errs


def test_no_search_while_the_target_is_held():
    """A look-alike in view does not capture a held track: the search runs only once the target is lost."""
    src = ZoomSource(seed=1, n_frames=30)
    tracker, rows = _track(src, profile_for(src))
    assert tracker.reacquirer.searches == 0 and not any(r[1] for r in rows)
    # negative control: the same tracker declared lost searches on the next frame
    tracker.reacquirer.lost = True
    tracker.step(src.frame(29))
    assert tracker.reacquirer.searches == 1


def test_scale_follows_a_10x_zoom():
    src = ZoomSource(seed=0)
    first, last = src.frame(0).truth.box, src.frame(len(src) - 1).truth.box
    assert max(last[2:]) / max(first[2:]) == pytest.approx(10.0, rel=1e-6)
    tracker, rows = _track(src, profile_for(src))
    est_len = np.array([r[2] for r in rows])
    true_len = np.array([r[3] for r in rows])
    assert np.all(np.abs(est_len / true_len - 1) < 0.15)
    assert est_len[-1] / est_len[0] > 8.0
    err = np.array([r[0] for r in rows])
    assert np.all(err < 0.1 * true_len)
    # the boxes: the estimate's axis-aligned box overlaps the truth's
    def iou(a, b):
        ix = max(0.0, min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0]))
        iy = max(0.0, min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1]))
        return ix * iy / (a[2] * a[3] + b[2] * b[3] - ix * iy)
    assert np.median([iou(r[4], r[5]) for r in rows]) > 0.6
    # negative control: without the scale search the size stays at the first box (and without the
    # re-acquisition, whose restart takes the scale it detects at: with the likelihood tempered, stop
    # 55, a track of a car grown 2.5x past its template is declared lost and restarted at 2.5x)
    off = profile_for(src)
    off = off.model_copy(update={"scale": off.scale.model_copy(update={"mode": "off"}),
                                 "reacquisition": off.reacquisition.model_copy(update={"enabled": False})})
    tracker_off, rows_off = _track(ZoomSource(seed=0, n_frames=40), off)
    assert rows_off[-1][2] == pytest.approx(max(first[2:]))


@pytest.mark.parametrize("held", [True, False])
def test_the_camera_zoom_carries_the_scale_only_while_the_target_is_held(held):
    """While the posterior holds the target, the scale follows the camera's zoom at the target's ground
    point (10x over 60 frames: 3.9 % a frame). While it does not (p(V=1|Z) under ``lost_p_visible``,
    the track not yet declared lost), the estimate may be anywhere (the last held point at the
    frame's edge, the background), the zoom there is not the target's, and the scale is kept. No
    scale search after the first frame's and the target's own flow off, so that only the zoom moves
    it (the flow, measured only while held, adds its own reading of the car's growth: 4.6 % on this
    frame with the model as fitted, 5.1 % with the likelihood tempered, stop 55, for the zoom's 4.0 %)."""
    src = ZoomSource(seed=0)
    st = profile_for(src)
    st = st.model_copy(update={"scale": st.scale.model_copy(update={
        "search_interval_s": 1e6, "flow": st.scale.flow.model_copy(update={"enabled": False})})})
    f0 = src.frame(0)
    tracker = Tracker.start(f0, f0.truth.box, st)
    for i in range(10):
        tracker.step(src.frame(i))
    assert tracker.reacquirer.held and not tracker.reacquirer.lost
    before = tracker.scale.s
    if not held:
        # the latest posterior not held (p(V=1|Z) 0.2), as the re-acquisition saw it
        tracker.reacquirer.observe(tracker.last_state.time, replace(tracker.last_state, p_visible=0.2), before)
        assert not tracker.reacquirer.held and not tracker.reacquirer.lost
    tracker.step(src.frame(10))
    grown = max(src.frame(10).truth.box[2:]) / max(src.frame(9).truth.box[2:])
    assert grown == pytest.approx(10 ** (1 / 59))
    if held:
        assert tracker.scale.s / before == pytest.approx(grown, rel=1e-3)
    else:
        assert tracker.scale.s == before


def test_a_target_wider_than_the_footprint_shrinking_10x():
    """The 10x zoom played backwards: the car starts 169 px long, wider than the template's whole
    footprint (128 matched px), and shrinks to 17 px. Its first frame is matched reduced to the
    layout's design size (u = 48 / 169), so the template holds the car and its context: the
    estimated length within 15 % of the truth and the centre within a tenth of a length on every
    frame (measured: 2 % and 0.05). Negative control: matched at full resolution from the first
    frame (``target_size_px`` None, as every first box longer than 48 px was before stop 38), the
    template is the car's interior and the scale runs up to 2.5x the car's."""
    src = ZoomSource(seed=0)
    n = len(src)
    frames = [replace(src.frame(n - 1 - i), index=i, time=i / src.fps) for i in range(n)]
    first = max(frames[0].truth.box[2:])
    assert first > 2 * SUPPORT_RADIUS_PX

    def run(target_size_px):
        st = profile_for(src)
        st = st.model_copy(update={"scale": st.scale.model_copy(update={"target_size_px": target_size_px})})
        tracker = Tracker.start(frames[0], frames[0].truth.box, st)
        ratio, err = [], []
        for f in frames:
            s = tracker.step(f)
            length = max(f.truth.box[2:])
            ratio.append(tracker.scale.target_length_px / length)
            err.append(np.hypot(s.map_estimate.image_x - f.truth.centre[0], s.map_estimate.image_y - f.truth.centre[1])
                       / length)
        return tracker, np.array(ratio), np.array(err)

    tracker, ratio, err = run(48.0)
    assert tracker.scale.u == pytest.approx(48.0 / first)
    assert np.all(np.abs(ratio - 1) < 0.15) and np.all(err < 0.1)
    _, ratio_full, _ = run(None)
    assert ratio_full.max() > 1.5


def _state(t: float, p_visible: float, x: float = 100.0, y: float = 100.0) -> TrackState:
    e = Estimate(x=0, y=0, vx=0, vy=0, theta=0, image_x=x, image_y=y)
    return TrackState(time=t, observed=True, map_estimate=e, mmse_estimate=e, p_visible=p_visible,
                      n_eff=1.0, speed=0.0, orientation=0.0)


@pytest.mark.parametrize("fps", [10.0, 30.0])
def test_lost_after_the_stated_seconds_whatever_the_frame_rate(fps):
    r = Reacquirer(ReacquisitionSettings(enabled=True, lost_after_s=0.5), (0.25, 8.08), (640, 480))
    t = 0.0
    r.observe(t, _state(t, 1.0), 1.0)
    lost_at = None
    for i in range(1, int(2 * fps)):
        t = i / fps
        r.observe(t, _state(t, 0.1), 1.0)
        if r.lost and lost_at is None:
            lost_at = t
    assert lost_at == pytest.approx(1 / fps + 0.5, abs=1e-9)
    # an estimate outside the frame is not held either, however visible
    r2 = Reacquirer(ReacquisitionSettings(enabled=True, lost_after_s=0.0), (0.25, 8.08), (640, 480))
    r2.observe(0.0, _state(0.0, 1.0, x=700.0), 1.0)
    assert r2.lost


@pytest.mark.parametrize("fps, interval, gap", [(10.0, 1 / 15, 1), (30.0, 1 / 15, 2), (30.0, 0.0, 1)])
def test_the_tiles_are_searched_once_a_tile_interval_whatever_the_frame_rate(fps, interval, gap, monkeypatch):
    """While lost, the tiles are searched at most once every ``tile_interval_s`` of footage: every
    frame at 10 fps, every other frame at 30 fps (1/15 s), and each tile's threshold allows the
    false alarms of the whole time since the tile before (the same false alarms a second at any
    rate); with no interval (negative control) every searched frame at 30 fps, each on one frame's
    time. A frame that ends a sweep of the frame searches no tile and leaves the budget to the next."""
    cfg = ReacquisitionSettings(enabled=True, lost_after_s=0.0, tile_interval_s=interval)
    r = Reacquirer(cfg, (0.25, 8.08), (640, 480))
    r.observe(0.0, _state(0.0, 0.1), 1.0)
    budgets = []
    threshold = Reacquirer._threshold
    monkeypatch.setattr(Reacquirer, "_threshold", lambda self, dt, maxima: budgets.append(dt) or threshold(self, dt, maxima))
    searched = []  # the frames on which a tile was searched
    background = _grid_peaked_at(-1e4, -1e4)  # nothing in the frame: no detection
    for i in range(1, 3 * int(fps) + 1):
        before = r.tiles
        assert r.search(i / fps, background, _Scale, None) is None
        if r.tiles > before:
            searched.append(i)
    gaps = np.diff(searched)
    assert set(gaps) <= {gap, gap + 1} and np.sum(gaps == gap) >= 0.7 * len(gaps)  # gap + 1: over a sweep's end
    assert r.searches == 3 * fps and r.tiles == len(searched) == len(budgets)
    assert budgets[0] == cfg.assumed_interval_s  # the first search: no frame interval measured yet
    expected = gaps / fps if interval > 0 else np.full(len(gaps), 1 / fps)  # without: the last frame's time
    assert budgets[1:] == pytest.approx(list(expected), abs=1e-9)


@pytest.mark.parametrize("outside", [True, False])
def test_a_lost_track_reports_where_it_was_last_held_not_the_drifting_cloud(exit_source, outside):
    """Once the filter's cloud has left the frame, the estimate is the point where the target was
    last held (carried with the camera: this scene's camera is still), at rest; with the cloud on
    the target (negative control), the filter's MAP, lost or not."""
    src = exit_source
    st = profile_for(src)
    f0 = src.frame(0)
    tracker = Tracker.start(f0, f0.truth.box, st)
    tracker.step(f0)
    r = tracker.reacquirer
    r.lost, r.last_held, r.last_theta = True, (300.0, 200.0), 15.0
    if outside:
        tracker.filter.particles[:, 0] -= 1000.0  # world unit: the target's length; far to the left
    f1 = src.frame(1)
    s = tracker.step(f1)
    xy = (s.map_estimate.image_x, s.map_estimate.image_y)
    if outside:
        assert xy == pytest.approx((300.0, 200.0), abs=0.5)
        assert s.mmse_estimate == s.map_estimate and s.speed == 0.0 and s.orientation == 15.0
    else:
        assert np.hypot(xy[0] - f1.truth.centre[0], xy[1] - f1.truth.centre[1]) < 3.0


def test_last_held_point_is_carried_with_the_camera_and_kept_in_the_frame():
    r = Reacquirer(ReacquisitionSettings(enabled=True, lost_after_s=0.0), (0.25, 8.08), (640, 480))
    r.carry(np.eye(3))
    assert r.last_held is None  # nothing held yet: nothing to carry
    r.observe(0.0, _state(0.0, 1.0, x=100.0, y=200.0), 1.0)
    assert r.last_held == (100.0, 200.0)
    shift = np.array([[1.0, 0, 30], [0, 1, -50], [0, 0, 1]])
    r.carry(shift)
    assert r.last_held == pytest.approx((130.0, 150.0))
    r.carry(None)  # the camera did not move
    assert r.last_held == pytest.approx((130.0, 150.0))
    r.carry(np.array([[2.0, 0, 0], [0, 2, 0], [0, 0, 1]]))  # zoom in about the corner
    assert r.last_held == pytest.approx((260.0, 300.0))
    r.carry(np.array([[1.0, 0, 1000], [0, 1, -1000], [0, 0, 1]]))  # the camera turns away: the edge
    assert r.last_held == pytest.approx((639.0, 0.0))
    r.carry(np.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 0]]))  # to infinity: stays
    assert r.last_held == pytest.approx((639.0, 0.0))
    # a frame that is not held does not move it
    r.observe(0.1, _state(0.1, 0.1, x=10.0, y=10.0), 1.0)
    assert r.lost and r.last_held == pytest.approx((639.0, 0.0))


def test_tail_probability_of_the_strongest_box():
    """Known answers: 180 boxes at z = 0 and 20 at 1.5: the 0.9 quantile u interpolates to 0.15,
    the mean excess over it is 1.35, so P(z >= 5) = 0.1 exp(-(5 - 0.15) / 1.35); below u the
    empirical fraction; with fewer than 20 boxes beyond u, no tail to fit (1); a frame of few
    boxes fits from a lower quantile."""
    z = np.concatenate([np.zeros(180), np.full(20, 1.5), [5.0]])
    far = np.ones(len(z), bool)
    far[-1] = False
    assert tail_probability(z, len(z) - 1, far, 0.9) == pytest.approx(0.1 * np.exp(-(5 - 0.15) / 1.35))
    z[-1] = 0.1  # below u: the share of the background at or above it
    assert tail_probability(z, len(z) - 1, far, 0.9) == pytest.approx(20 / 200)
    z2 = np.concatenate([np.zeros(190), np.full(10, 1.5), [5.0]])
    assert tail_probability(z2, len(z2) - 1, np.r_[np.ones(200, bool), False], 0.9) == 1.0
    # few boxes (a large target): 30 at 0 and 20 at 1: the quantile falls to 1 - 20/50 = 0.6, u
    # interpolates to 0.4, the mean excess is 0.6; below 40 boxes, not even the median leaves 20
    z3 = np.concatenate([np.zeros(30), np.ones(20), [5.0]])
    far3 = np.r_[np.ones(50, bool), False]
    assert tail_probability(z3, 50, far3, 0.9) == pytest.approx(0.4 * np.exp(-(5 - 0.4) / 0.6))
    assert tail_probability(z3[11:], 39, far3[11:], 0.9) == 1.0


class _Movers:
    """A stand-in motion cue: a grid of boxes with one mover at ``at`` (z 30) over a Gaussian
    background (or none), its blob at scale 1."""

    def __init__(self, at):
        self.at = at
        gx, gy = np.meshgrid(np.arange(10.0, 630, 5), np.arange(10.0, 470, 5))
        self.xy = np.stack([gx.ravel(), gy.ravel()], axis=1)
        self.rng = np.random.default_rng(0)

    def movers(self, s):
        z = self.rng.standard_normal(len(self.xy))
        if self.at is not None:
            z[np.argmin(np.hypot(*(self.xy - self.at).T))] = 30.0
        return self.xy, z

    box_size = (20.0, 13.0)
    """The first box the cue was made for (``_Scale``'s 20 px target)."""

    def blob_scale(self, xy):
        return 1.0

    def blob_box(self, xy):
        return None  # no blob to leave out of the background (the tail as with boxes alone)


class _Scale:
    """A stand-in scale tracker: a 20 px target, factor 1 / s."""

    length_px = 20.0
    target_length_px = 20.0
    """The target's length at its current scale (1)."""
    s = 1.0
    """The held scale."""

    class cfg:
        steps_per_octave = 12

    @staticmethod
    def scale_range():
        return (0.25, 16.0)

    @staticmethod
    def raw_factor(s):
        return 1.0 / s

    @classmethod
    def factor(cls, s):
        return quantise_factor(cls.raw_factor(s), cls.cfg.steps_per_octave)


def _grid_peaked_at(x0, y0, k0=1.0):
    """Scores peaked at (x0, y0), at 45 degrees, and at factor ``k0`` (scale 1 / k0)."""
    def grid_at(k, xy, crop=None):
        d = np.hypot(xy[:, 0] - x0, xy[:, 1] - y0)
        scores = np.tile(np.exp(-d / 10.0 - abs(np.log(k / k0)))[:, None], (1, 48))
        scores[:, 6] += 0.1  # the best angle: 45 degrees
        return scores, np.ones(len(xy), bool)
    return grid_at


def test_the_strongest_mover_restarts_the_filter_once_confirmed():
    """A mover far beyond the background's tail: pending on the first searched frame, a detection
    on the second at the matcher's best position and angle; a mover that jumps more than a target
    length between the two frames starts over (negative control), and a frame of background alone
    detects nothing."""
    cfg = ReacquisitionSettings(enabled=True, lost_after_s=0.0)
    r = Reacquirer(cfg, (0.25, 8.08), (640, 480))
    r.observe(0.0, _state(0.0, 0.1), 1.0)
    assert r.lost
    grid = _grid_peaked_at(302.0, 201.0)
    assert r.search(0.1, grid, _Scale, _Movers((300.0, 200.0))) is None
    det = r.search(0.2, grid, _Scale, _Movers((305.0, 200.0)))
    assert det is not None and r.mover_detections == 1
    # refined from the quarter-length grid about the mover to the matcher's peak (5 px apart: the
    # grid alone lands up to 2.5 px off either way)
    assert (det.x, det.y) == pytest.approx((302.0, 201.0), abs=0.4) and det.theta_deg == 45.0 and det.scale == 1.0

    flat = lambda k, xy, crop=None: (np.zeros((len(xy), 48)), np.ones(len(xy), bool))  # nothing for the tiles
    r2 = Reacquirer(cfg, (0.25, 8.08), (640, 480))
    r2.observe(0.0, _state(0.0, 0.1), 1.0)
    assert r2.search(0.1, flat, _Scale, _Movers((300.0, 200.0))) is None
    assert r2.search(0.2, flat, _Scale, _Movers((400.0, 300.0))) is None  # jumped: pending again
    assert r2.mover_detections == 0 and (r2._pending_mover.x, r2._pending_mover.y) == (400.0, 300.0)
    assert r2.search(0.3, flat, _Scale, _Movers((405.0, 300.0))) is not None and r2.mover_detections == 1
    r3 = Reacquirer(cfg, (0.25, 8.08), (640, 480))
    r3.observe(0.0, _state(0.0, 0.1), 1.0)
    for t in (0.1, 0.2, 0.3):
        assert r3.search(t, flat, _Scale, _Movers(None)) is None
    assert r3.mover_detections == 0 and r3._pending_mover is None


class _WeakMover(_Movers):
    """The stand-in cue with its mover at z 5: within the reach of the background's tail."""

    def movers(self, s):
        xy, z = super().movers(s)
        z[np.argmin(np.hypot(*(self.xy - self.at).T))] = 5.0
        return xy, z


class _NoMovers:
    """A stand-in cue with no boxes to score (its history too short)."""

    def movers(self, s):
        return np.zeros((0, 2)), np.zeros(0)

    def blob_scale(self, xy):
        return None


def test_the_movers_test_reports_what_it_decided():
    """``mover_gate`` holds the test's figures for the searched frame: the strongest mover, its z,
    n P from the tail model (computed here from the same boxes) and what the frame allows. A mover
    at z 30 passes by orders of magnitude and is pending; the same mover at z 5 over the same
    background fails (of some 11,000 background boxes, about 0.4 are expected that strong, 0.005
    allowed): nothing pending."""
    cfg = ReacquisitionSettings(enabled=True, lost_after_s=0.0)
    flat = lambda k, xy, crop=None: (np.zeros((len(xy), 48)), np.ones(len(xy), bool))  # noqa: E731
    for cue, z_top, passes in ((_Movers((300.0, 200.0)), 30.0, True), (_WeakMover((300.0, 200.0)), 5.0, False)):
        r = Reacquirer(cfg, (0.25, 8.08), (640, 480))
        r.observe(0.0, _state(0.0, 0.1), 1.0)
        assert r.mover_gate is None
        twin = type(cue)(cue.at)  # the same draws, to compute the expected figures independently
        xy, z = twin.movers(1.0)
        top = int(np.argmax(z))
        far = np.hypot(*(xy - xy[top]).T) > _Scale.length_px
        assert r.search(0.1, flat, _Scale, cue) is None
        g = r.mover_gate
        assert isinstance(g, MoverGate) and (g.x, g.y, g.z, g.scale) == (300.0, 200.0, z_top, 1.0)
        assert g.false_alarms == pytest.approx(len(z) * tail_probability(z, top, far, cfg.mover_tail_quantile))
        assert g.allowed == pytest.approx(cfg.false_alarms_per_s * cfg.assumed_interval_s)
        assert (r._pending_mover is not None) is passes
        if passes:
            assert g.false_alarms < 1e-6 * g.allowed
        else:
            assert g.false_alarms > 10 * g.allowed
        # a searched frame without movers (no history yet, say) leaves no gate of an earlier frame
        assert r.search(0.2, flat, _Scale, _NoMovers()) is None and r.mover_gate is None


def test_a_mover_the_matcher_cannot_score_yet_stays_pending():
    """A mover entering at the frame's left edge, where the matcher scores only hypotheses whose
    footprint (here 50 px) lies in the frame: on the confirming frame the mover itself is not
    scorable, so the filter is not restarted at the grid's inner points (off the target, towards
    the frame's inside) but waits, pending at the mover's new position; the next frame, with the
    mover scorable, restarts it at the matcher's peak on the mover."""
    cfg = ReacquisitionSettings(enabled=True, lost_after_s=0.0)

    def grid_on(x0):
        peaked = _grid_peaked_at(x0, 200.0)

        def grid_at(k, xy, crop=None):
            scores, _ = peaked(k, xy)
            return scores, xy[:, 0] >= 50.0  # the footprint's support
        return grid_at

    r = Reacquirer(cfg, (0.25, 8.08), (640, 480))
    r.observe(0.0, _state(0.0, 0.1), 1.0)
    assert r.search(0.1, grid_on(40.0), _Scale, _Movers((40.0, 200.0))) is None
    assert r.search(0.2, grid_on(45.0), _Scale, _Movers((45.0, 200.0))) is None  # within a length, not scorable
    assert r.mover_detections == 0 and (r._pending_mover.x, r._pending_mover.y) == (45.0, 200.0)
    det = r.search(0.3, grid_on(60.0), _Scale, _Movers((60.0, 200.0)))
    assert det is not None and r.mover_detections == 1
    assert (det.x, det.y) == pytest.approx((60.0, 200.0), abs=0.4)
    # negative control: a restart on the confirming frame would have been at the nearest
    # scorable point, off the mover
    best, on_mover = r._match_mover(grid_on(45.0), _Scale, 45.0, 200.0, [1.0])
    assert not on_mover and best.x == pytest.approx(50.0)
    # the mover's own box centre scorable but not the quarter length (5 px) about it towards the
    # edge, where the target's centre may lie (its boxes are half a box apart): still pending
    # (the synthetic car's centre lay 14 px nearer the edge than its box's, and a restart there
    # was 44 px off it); scorable all round, it restarts
    def support_from_52(x0):
        peaked = _grid_peaked_at(x0, 200.0)
        return lambda k, xy, crop=None: (peaked(k, xy)[0], xy[:, 0] >= 52.0)

    r3 = Reacquirer(cfg, (0.25, 8.08), (640, 480))
    r3.observe(0.0, _state(0.0, 0.1), 1.0)
    assert r3.search(0.1, support_from_52(45.0), _Scale, _Movers((45.0, 200.0))) is None
    assert r3._match_mover(support_from_52(55.0), _Scale, 55.0, 200.0, [1.0])[1] is False  # 50 px is not
    assert r3.search(0.2, support_from_52(55.0), _Scale, _Movers((55.0, 200.0))) is None
    assert r3.mover_detections == 0 and r3._pending_mover.x == 55.0
    det = r3.search(0.3, support_from_52(60.0), _Scale, _Movers((60.0, 200.0)))
    assert det is not None and (det.x, det.y) == pytest.approx((60.0, 200.0), abs=0.4)


class _Blob(_Movers):
    """The stand-in cue whose mover's blob reads ``blob`` times the first box."""

    def __init__(self, at, blob):
        super().__init__(at)
        self.blob = blob

    def blob_scale(self, xy):
        return self.blob


def test_a_mover_whose_blob_no_footprint_in_the_frame_could_match_is_matched_at_its_boxes_scale():
    """The blob reads 16x the first box: matched at it or one or two ratios below (8x, 11x, 16x),
    the template's footprint (64 px at factor 1 / s here) would be wider than the 640x480 frame,
    so no hypothesis anywhere in it could be scored: the blob is not the target's extent (on
    uavdt-S1001-away it had merged with half the frame where the camera's jump was not followed,
    docs/real-footage.md, stop 40). The mover is matched at the scale whose boxes found it (the
    sweep's, 1x), pending there with a score, and restarts the filter on the next frame. Before,
    it was pending at 8x with no score: the matcher could not score it there on the next frame either.
    Negative control: a blob of 4x (2x, 2.8x, 4x: a 2.8x footprint fits the frame) at a mover the
    matcher can score only at 1x (a target entering at the frame's edge: only a small footprint is
    in) keeps the blob's scale and waits, as before: matched at 1x it would restart the filter on
    it at the wrong size."""
    cfg = ReacquisitionSettings(enabled=True, lost_after_s=0.0)
    peaked = _grid_peaked_at(302.0, 201.0)

    def up_to_4x(k, xy, crop=None):
        scores, _ = peaked(k, xy)
        return scores, np.full(len(xy), k >= 0.25)  # _Scale: k = 1 / s

    r = Reacquirer(cfg, (0.25, 8.08), (640, 480))
    r.observe(0.0, _state(0.0, 0.1), 1.0)
    assert r.search(0.1, up_to_4x, _Scale, _Blob((300.0, 200.0), 16.0)) is None
    assert r._pending_mover.scale == 1.0 and np.isfinite(r._pending_mover.score)
    det = r.search(0.2, up_to_4x, _Scale, _Blob((305.0, 200.0), 16.0))
    assert det is not None and r.mover_detections == 1
    assert (det.x, det.y) == pytest.approx((302.0, 201.0), abs=0.4)

    def small_only(k, xy, crop=None):  # a target entering at the edge: only a small footprint is in
        scores, _ = peaked(k, xy)
        return scores, np.full(len(xy), k >= 0.9)

    r2 = Reacquirer(cfg, (0.25, 8.08), (640, 480))
    r2.observe(0.0, _state(0.0, 0.1), 1.0)
    assert r2.search(0.1, small_only, _Scale, _Blob((300.0, 200.0), 4.0)) is None
    assert r2._pending_mover.scale == pytest.approx(2.0) and np.isnan(r2._pending_mover.score)


class _MoverAtScale(_Blob):
    """The stand-in cue whose mover stands out (z 30) only in boxes of scale ``box_scale``; in boxes
    of any other size it is background (a box of another size takes in the target's uniform middle or
    the ground about it); its blob reads 2x the first box."""

    def __init__(self, at, box_scale):
        super().__init__(at, 2.0)
        self.box_scale = box_scale

    def movers(self, s):
        xy, z = super().movers(s)
        if abs(s - self.box_scale) > 1e-9:
            z[np.argmin(np.hypot(*(self.xy - self.at).T))] = 0.0
        return xy, z


def test_a_pending_mover_is_confirmed_in_boxes_of_the_size_that_found_it():
    """The movers' boxes find a mover at the sweep's scale (1x); the matcher, offered the blob's 2x
    and the ratios below, matches it best at 2x (its peak at factor 1/2). The next frame confirms it
    by the same test in boxes of the same size, 1x, and the filter restarts at the matcher's 2x:
    the boxes measure where the motion is, the matcher the target's size, and the two need not
    agree (uavdt-S0310-away: a bus found in boxes of half its size, whose whole-bus boxes take in
    its uniform roof, docs/real-footage.md, stop 42). Before, the confirming frame tested boxes of
    the matcher's scale, and a mover that stands out only in boxes of the size that found it was
    never confirmed. Negative control: a mover that, on the confirming frame, stands out only in
    boxes of the matcher's 2x, not of 1x, is not confirmed."""
    cfg = ReacquisitionSettings(enabled=True, lost_after_s=0.0)

    peaked_at_half = _grid_peaked_at(302.0, 201.0, k0=0.5)
    r = Reacquirer(cfg, (0.25, 8.08), (640, 480))
    r.observe(0.0, _state(0.0, 0.1), 1.0)
    assert r.search(0.1, peaked_at_half, _Scale, _MoverAtScale((300.0, 200.0), 1.0)) is None
    assert r.mover_gate.scale == 1.0 and r._pending_mover.scale == pytest.approx(2.0)
    det = r.search(0.2, peaked_at_half, _Scale, _MoverAtScale((305.0, 200.0), 1.0))
    assert det is not None and r.mover_detections == 1
    assert r.mover_gate.scale == 1.0 and det.scale == pytest.approx(2.0)
    assert (det.x, det.y) == pytest.approx((302.0, 201.0), abs=0.8)

    r2 = Reacquirer(cfg, (0.25, 8.08), (640, 480))
    r2.observe(0.0, _state(0.0, 0.1), 1.0)
    assert r2.search(0.1, peaked_at_half, _Scale, _MoverAtScale((300.0, 200.0), 1.0)) is None
    assert r2.search(0.2, peaked_at_half, _Scale, _MoverAtScale((305.0, 200.0), 2.0)) is None
    assert r2.mover_detections == 0 and r2.mover_gate.false_alarms > r2.mover_gate.allowed


def _part_and_whole(part_xy, whole_xy, whole_k0):
    """Scores of a target whose part scores 0.6 at factor 1 (scale 1) at ``part_xy`` and whose whole
    scores 0.9 at factor ``whole_k0`` at ``whole_xy`` (the matcher's peaks: narrower than a quarter
    of the target's length), best at 45 degrees."""
    part, whole = _grid_peaked_at(*part_xy), _grid_peaked_at(*whole_xy, k0=whole_k0)

    def grid_at(k, xy, crop=None):
        return np.maximum(0.6 * part(k, xy)[0], 0.9 * whole(k, xy)[0]), np.ones(len(xy), bool)
    return grid_at


def _lost_after_held(cfg, held_xy, scale=3.0) -> Reacquirer:
    """A re-acquisition that held a 3x target (a 60 x 39 px box) at ``held_xy`` and then lost it."""
    r = Reacquirer(cfg, (0.25, 8.08), (640, 480))
    r.observe(0.0, replace(_state(0.0, 0.9, *held_xy), size=(20.0 * scale, 13.0 * scale)), scale)
    r.observe(0.05, _state(0.05, 0.1, *held_xy), scale)
    assert r.lost and r.last_scale == scale
    return r


def test_a_target_that_left_the_view_found_by_a_part_is_matched_at_the_scale_it_was_last_held_at():
    """A target last held at 3x within its length of the frame's edge (it left the view), whose
    movers' boxes find a part when it comes back (a bus whose uniform roof shows no motion: its blob
    is its front half, uavdt-S0310-away, docs/real-footage.md, stop 44); the blob reads 1x. The
    matcher is offered the blob's scale and the ratios below it and, as well, the scale the target
    was last held at; and each scale's grid about the mover is refined to its peak before the
    scales are compared (the whole target's peak, 10.6 px from the nearest point of the 3x grid,
    scores 0.31 there against the part's 0.6 on the 1x grid, which falls on it). The filter restarts
    on the whole target at 3x, at its centre. Without either (the last held scale not offered, or
    the grids compared unrefined), it restarted on the part at 1x. Negative controls: a target held
    at 3x that now shows only the part (its size has changed) restarts at 1x on it (the last held
    scale is offered, not imposed); and a target lost inside the view, far from the edge (it may
    have been lost because its scale was no longer its own), is not offered its last held scale."""
    cfg = ReacquisitionSettings(enabled=True, lost_after_s=0.0)
    both = _part_and_whole((300.0, 200.0), (307.5, 207.5), 1 / 3)
    r = _lost_after_held(cfg, (30.0, 200.0))  # 30 px from the left edge, 60 px long
    assert r.left_the_view
    assert r.search(0.1, both, _Scale, _Blob((300.0, 200.0), 1.0)) is None
    assert r._pending_mover.scale == 3.0
    det = r.search(0.2, both, _Scale, _Blob((305.0, 200.0), 1.0))
    assert det is not None and r.mover_detections == 1
    assert det.scale == pytest.approx(3.0) and (det.x, det.y) == pytest.approx((307.5, 207.5), abs=1.0)
    assert det.score > 0.9  # the whole (at most 0.99) where the part gives at most 0.66

    part_only = _part_and_whole((300.0, 200.0), (900.0, 900.0), 1 / 3)
    r2 = _lost_after_held(cfg, (30.0, 200.0))
    assert r2.search(0.1, part_only, _Scale, _Blob((300.0, 200.0), 1.0)) is None
    det = r2.search(0.2, part_only, _Scale, _Blob((305.0, 200.0), 1.0))
    assert det is not None and det.scale == pytest.approx(1.0)
    assert (det.x, det.y) == pytest.approx((300.0, 200.0), abs=1.0)

    r3 = _lost_after_held(cfg, (320.0, 240.0))  # 240 px from every edge
    assert not r3.left_the_view
    assert r3.search(0.1, both, _Scale, _Blob((300.0, 200.0), 1.0)) is None
    det = r3.search(0.2, both, _Scale, _Blob((305.0, 200.0), 1.0))
    assert det is not None and det.scale == pytest.approx(1.0)


def test_background_boxes_are_beyond_a_box_length_and_off_the_blob():
    """Known answers on a 5 px grid: the boxes beyond 10 px of the strongest one; with its blob
    (x 20-40, y 0-10) grown by half a box (2 x 1 px), those off it too."""
    gx, gy = np.meshgrid(np.arange(0.0, 60, 5), np.arange(0.0, 30, 5))
    xy = np.stack([gx.ravel(), gy.ravel()], axis=1)
    top = int(np.flatnonzero((xy[:, 0] == 25) & (xy[:, 1] == 5))[0])
    far = background_boxes(xy, top, 10.0)
    assert far.tolist() == (np.hypot(xy[:, 0] - 25, xy[:, 1] - 5) > 10).tolist()
    off = background_boxes(xy, top, 10.0, (20.0, 0.0, 20.0, 10.0), (2.0, 1.0))
    on_blob = (xy[:, 0] >= 18) & (xy[:, 0] <= 42) & (xy[:, 1] <= 11)
    assert off.tolist() == (far & ~on_blob).tolist()
    # beyond 10 px and on the blob: (35, 5) is exactly 10 px off, not beyond
    assert {tuple(p) for p in xy[far & ~off].tolist()} == {(35.0, 0.0), (35.0, 10.0), (40.0, 0.0), (40.0, 5.0),
                                                          (40.0, 10.0)}


class _LargeMover(_Movers):
    """The stand-in cue with a 100 x 60 px target about ``at`` seen in boxes of a 20 px one: its
    strongest box at z 30, the boxes on its other parts at z 20 (a car in boxes a fifth of its size:
    on uav123-car16 at frames 410-428 the twelve strongest boxes lay within a car length of the
    car, at z 10-60, docs/real-footage.md, stop 46); its blob the target's box, or ``blob``."""

    def __init__(self, at, blob=None):
        super().__init__(at)
        self.target = (at[0] - 50.0, at[1] - 30.0, 100.0, 60.0)
        self.blob = self.target if blob is None else blob

    def movers(self, s):
        xy, z = super().movers(s)
        x0, y0, w, h = self.target
        parts = (xy[:, 0] >= x0) & (xy[:, 0] <= x0 + w) & (xy[:, 1] >= y0) & (xy[:, 1] <= y0 + h) & (z < 30)
        z[parts] = 20.0
        return xy, z

    def blob_box(self, xy):
        return self.blob


def test_a_large_mover_in_small_boxes_is_not_explained_away_by_its_own_parts(monkeypatch):
    """A target five box lengths long: with the boxes of its other parts counted as background, the
    tail makes its strongest box unremarkable (hundreds of times what the frame allows) and it is
    never a candidate; fitted without its blob, it passes by orders of magnitude and is pending.
    Negative controls: a blob larger than any target the frame could show (400 x 300 px, 23x the
    first box: the template's footprint at that scale fits nowhere in the 1280 x 720 frame, where
    the target's blob at 4.6x does; a blob merged with its surroundings, as after a camera jump,
    stop 40) is not left out, and the test fails as before (left out, it would pass: it holds the
    target and a good share of the background's strongest boxes); without the setting, it fails too."""
    on = ReacquisitionSettings(enabled=True, lost_after_s=0.0, mover_tail_without_blob=True)
    off = ReacquisitionSettings(enabled=True, lost_after_s=0.0, mover_tail_without_blob=False)
    flat = lambda k, xy, crop=None: (np.zeros((len(xy), 48)), np.ones(len(xy), bool))  # noqa: E731
    figures = {}
    for name, cfg, cue in (("without blob", on, _LargeMover((300.0, 200.0))),
                           ("merged blob", on, _LargeMover((300.0, 200.0), blob=(100.0, 50.0, 400.0, 300.0))),
                           ("with blob", off, _LargeMover((300.0, 200.0)))):
        r = Reacquirer(cfg, (0.25, 8.08), (1280, 720))
        r.observe(0.0, _state(0.0, 0.1), 1.0)
        assert r.search(0.1, flat, _Scale, cue) is None
        g = r.mover_gate
        assert (g.x, g.y, g.z) == (300.0, 200.0, 30.0)
        figures[name] = (g.false_alarms / g.allowed, r._pending_mover is not None)
    assert figures["without blob"][0] < 1e-6 and figures["without blob"][1], figures
    for name in ("merged blob", "with blob"):
        assert figures[name][0] > 10 and not figures[name][1], figures
    # the guard is what keeps the merged blob: with every scale taken to fit the frame, it passes
    monkeypatch.setattr(Reacquirer, "_fits_the_frame", lambda self, scale_tracker, s: True)
    r = Reacquirer(on, (0.25, 8.08), (1280, 720))
    r.observe(0.0, _state(0.0, 0.1), 1.0)
    assert r.search(0.1, flat, _Scale, _LargeMover((300.0, 200.0), blob=(100.0, 50.0, 400.0, 300.0))) is None
    assert r.mover_gate.false_alarms < r.mover_gate.allowed and r._pending_mover is not None


def test_a_pending_mover_is_confirmed_anywhere_on_the_target_it_was_matched_at():
    """A mover matched at 3x (a 60 px target) whose strongest 20 px box lies 40 px on on the next
    frame (another part of it, or where it drove): confirmed, the filter restarting at the matcher's
    peak there. Within one box length only (the rule before), it was pending again on every frame
    while the strongest box wandered over the target (uav123-car16 seed 3, frames 430-450: a car
    176 px long at z 64-175 in boxes of 14 px, never confirmed, docs/real-footage.md, stop 47).
    Negative controls: 100 px on (beyond the target's length) it is pending again; without the
    setting, 40 px on is too."""
    def run(cfg, dx):
        r = Reacquirer(cfg, (0.25, 8.08), (640, 480))
        r.observe(0.0, _state(0.0, 0.1), 1.0)
        assert r.search(0.1, _grid_peaked_at(302.0, 201.0, k0=1 / 3), _Scale, _Blob((300.0, 200.0), 3.0)) is None
        assert r._pending_mover.scale == pytest.approx(3.0)
        det = r.search(0.2, _grid_peaked_at(302.0 + dx, 201.0, k0=1 / 3), _Scale, _Blob((300.0 + dx, 200.0), 3.0))
        return r, det

    on = ReacquisitionSettings(enabled=True, lost_after_s=0.0, mover_confirm_within_target=True)
    r, det = run(on, 40.0)
    assert det is not None and r.mover_detections == 1
    assert det.scale == pytest.approx(3.0) and (det.x, det.y) == pytest.approx((342.0, 201.0), abs=1.0)
    r, det = run(on, 100.0)
    assert det is None and r.mover_detections == 0 and r._pending_mover.x == pytest.approx(402.0, abs=1.0)
    off = ReacquisitionSettings(enabled=True, lost_after_s=0.0, mover_confirm_within_target=False)
    r, det = run(off, 40.0)
    assert det is None and r.mover_detections == 0 and r._pending_mover.x == pytest.approx(342.0, abs=1.0)


class _MoverOfZ(_Movers):
    """The stand-in cue with its mover at ``at`` scored ``z_top``."""

    def __init__(self, at, z_top):
        super().__init__(at)
        self.z_top = z_top

    def movers(self, s):
        xy, z = super().movers(s)
        z[np.argmin(np.hypot(*(self.xy - self.at).T))] = self.z_top
        return xy, z


def test_a_pending_mover_is_confirmed_against_the_boxes_within_its_reach():
    """The confirming frame tests one hypothesis, the pending mover's: the strongest box within its
    reach, its expected false alarms counted over the boxes there (50 of the frame's 11,408).
    A mover found at z 30 (pending at the matcher's peak), seen again at z 6 on the next frame:
    confirmed, where over the whole
    frame z 6 is within the background's tail (more expected than allowed, the frame's own test).
    Negative controls: the frame's test (the setting off) leaves it unconfirmed and nothing pending;
    with the mover gone from the pending place and a z 6 box elsewhere, nothing is confirmed."""
    def faint(x0, y0):  # a peak the matcher places the mover by, too faint for the tiles to detect
        peaked = _grid_peaked_at(x0, y0)
        return lambda k, xy, crop=None: (0.3 * peaked(k, xy)[0], np.ones(len(xy), bool))

    def run(cfg, second):
        r = Reacquirer(cfg, (0.25, 8.08), (640, 480))
        r.observe(0.0, _state(0.0, 0.1), 1.0)
        assert r.search(0.1, faint(302.0, 201.0), _Scale, _Movers((300.0, 200.0))) is None
        pending = r._pending_mover
        assert pending is not None and (pending.x, pending.y) == pytest.approx((302.0, 201.0), abs=0.5)
        return r, r.search(0.2, faint(307.0, 201.0), _Scale, second)

    on = ReacquisitionSettings(enabled=True, lost_after_s=0.0, mover_confirm_locally=True)
    r, det = run(on, _MoverOfZ((305.0, 200.0), 6.0))
    assert det is not None and r.mover_detections == 1 and (det.x, det.y) == pytest.approx((307.0, 201.0), abs=0.5)
    g = r.mover_gate
    xy, z = _MoverOfZ((305.0, 200.0), 6.0).movers(1.0)  # the same draws
    top = int(np.argmax(z))
    near = np.hypot(*(xy - (302.0, 201.0)).T) <= _Scale.length_px  # about the pending mover's matched peak
    p = tail_probability(z, top, np.hypot(*(xy - xy[top]).T) > _Scale.length_px, on.mover_tail_quantile)
    assert (g.x, g.y, g.z) == (305.0, 200.0, 6.0) and g.false_alarms == pytest.approx(near.sum() * p)
    assert 40 <= near.sum() <= 60 and g.false_alarms <= g.allowed < len(z) * p
    off = ReacquisitionSettings(enabled=True, lost_after_s=0.0, mover_confirm_locally=False)
    r, det = run(off, _MoverOfZ((305.0, 200.0), 6.0))
    assert det is None and r.mover_detections == 0 and r._pending_mover is None
    assert r.mover_gate.false_alarms == pytest.approx(len(z) * p) and r.mover_gate.false_alarms > r.mover_gate.allowed
    r, det = run(on, _MoverOfZ((450.0, 300.0), 6.0))
    assert det is None and r.mover_detections == 0 and r._pending_mover is None


class _TwoMovers(_MoverOfZ):
    """The stand-in cue with a mover at ``at`` scored ``z_top`` and another at ``strong_at`` at z 30."""

    def __init__(self, at, z_top, strong_at):
        super().__init__(at, z_top)
        self.strong_at = strong_at

    def movers(self, s):
        xy, z = super().movers(s)
        z[np.argmin(np.hypot(*(self.xy - self.strong_at).T))] = 30.0
        return xy, z


def test_a_mover_under_the_lost_cloud_is_tested_before_the_frames_strongest():
    """``mover_near_estimate``: with the filter's cloud at (302, 201), a z 6 mover there is tested
    against the background's tail over the boxes within a target length of the cloud (about 50 of
    the frame's 11,408), and becomes the pending mover, although another mover at z 30 is the
    frame's strongest (a truck whose template went stale under the cloud, another vehicle
    elsewhere: uav123-truck4, docs/real-footage.md, stop 52). Negative controls: the setting off,
    or no cloud to test about, the frame's strongest is pending; a cloud over background alone
    (its boxes within the tail) leaves the frame's strongest pending too."""
    flat = lambda k, xy, crop=None: (np.zeros((len(xy), 48)), np.ones(len(xy), bool))  # nothing for the tiles

    def pending(cfg, near, cue):
        r = Reacquirer(cfg, (0.25, 8.08), (640, 480))
        r.observe(0.0, _state(0.0, 0.1), 1.0)
        assert r.search(0.1, flat, _Scale, cue, near) is None
        return r._pending_mover, r.mover_gate

    on = ReacquisitionSettings(enabled=True, lost_after_s=0.0, mover_near_estimate=True)
    off = ReacquisitionSettings(enabled=True, lost_after_s=0.0, mover_near_estimate=False)
    det, gate = pending(on, (302.0, 201.0), _TwoMovers((300.0, 200.0), 6.0, (450.0, 300.0)))
    assert (det.x, det.y) == (300.0, 200.0) and gate.z == 6.0 and gate.false_alarms <= gate.allowed
    xy, z = _TwoMovers((300.0, 200.0), 6.0, (450.0, 300.0)).movers(1.0)  # the same draws
    near = np.hypot(*(xy - (302.0, 201.0)).T) <= _Scale.target_length_px
    top = int(np.argmin(np.hypot(*(xy - (300.0, 200.0)).T)))
    p = tail_probability(z, top, np.hypot(*(xy - xy[top]).T) > _Scale.length_px, on.mover_tail_quantile)
    assert gate.false_alarms == pytest.approx(near.sum() * p) and len(z) * p > gate.allowed  # the frame's test fails
    for cfg, at in ((off, (302.0, 201.0)), (on, None), (on, (150.0, 380.0))):
        det, gate = pending(cfg, at, _TwoMovers((300.0, 200.0), 6.0, (450.0, 300.0)))
        assert (det.x, det.y) == (450.0, 300.0) and gate.z == 30.0
    # a frame with a mover pending elsewhere that is not seen again: the cloud's mover is tested too
    for cfg, found in ((on, (300.0, 200.0)), (off, None)):
        r = Reacquirer(cfg, (0.25, 8.08), (640, 480))
        r.observe(0.0, _state(0.0, 0.1), 1.0)
        assert r.search(0.1, flat, _Scale, _Movers((450.0, 300.0))) is None and r._pending_mover is not None
        assert r.search(0.2, flat, _Scale, _MoverOfZ((300.0, 200.0), 6.0), (302.0, 201.0)) is None
        det = r._pending_mover
        assert (det is None and found is None) or (det.x, det.y) == found


def test_in_doubt_the_movers_under_the_cloud_restart_the_filter_and_no_other():
    """``movers_in_doubt``: held at (300, 200), then p(V=1|Z) 0.1 for less than ``lost_after_s``.
    A z 6 mover under the cloud is pending on the first frame of doubt (its false alarms counted
    over the boxes within a target length of the cloud, as once lost), confirmed on the next at the
    matcher's peak, and the track is not lost; its test allowed ``doubt_false_alarms_per_s`` over the
    frame interval. Negative controls: the frame's strongest mover (z 30, 150 px away) is not tested
    while in doubt (once lost it is the pending mover); a mover the doubt's rate does not admit is
    not pending, and is once lost, at ``false_alarms_per_s``; a mover within half a length of the
    cloud (on the target as the cloud holds it) is not pending, nor is one the next frame finds there
    after a pending mover it did not confirm; a mover pending from a frame of doubt is dropped when
    the filter holds the target again."""
    def faint(x0, y0):  # the matcher's peak, too faint for the tiles
        peaked = _grid_peaked_at(x0, y0)
        return lambda k, xy, crop=None: (0.3 * peaked(k, xy)[0], np.ones(len(xy), bool))

    cfg = ReacquisitionSettings(enabled=True, lost_after_s=0.5, movers_in_doubt=True)

    def in_doubt():
        r = Reacquirer(cfg, (0.25, 8.08), (640, 480))
        r.observe(0.0, _state(0.0, 1.0, 300.0, 200.0), 1.0)
        r.observe(0.1, _state(0.1, 0.1, 300.0, 200.0), 1.0)
        assert r.in_doubt and not r.lost
        return r

    r = in_doubt()
    cue = _TwoMovers((300.0, 200.0), 6.0, (450.0, 300.0))
    off = (314.0, 201.0)  # the cloud 0.7 target lengths from the mover: off the target as it moves
    assert r.search_in_doubt(0.2, faint(302.0, 201.0), _Scale, cue, off) is None
    assert (r._pending_mover.x, r._pending_mover.y) == pytest.approx((302.0, 201.0), abs=0.5)
    assert r.mover_gate.z == 6.0 and r.mover_gate.false_alarms <= r.mover_gate.allowed
    assert r.mover_gate.allowed == pytest.approx(cfg.doubt_false_alarms_per_s * 0.1)
    r.observe(0.2, _state(0.2, 0.1, 302.0, 201.0), 1.0)
    det = r.search_in_doubt(0.3, faint(307.0, 201.0), _Scale, _MoverOfZ((305.0, 200.0), 6.0), (304.0, 201.0))
    assert det is not None and (det.x, det.y) == pytest.approx((307.0, 201.0), abs=0.5)
    assert r.doubt_detections == 1 and not r.lost

    # the cloud on the mover (within doubt_mover_off_lengths, half a length): the mover passes its
    # test but is not pending (nothing to correct); 0.7 lengths off it is (above)
    r = in_doubt()
    assert r.search_in_doubt(0.2, faint(302.0, 201.0), _Scale, cue, (302.0, 201.0)) is None
    assert r._pending_mover is None and r.mover_gate.false_alarms <= r.mover_gate.allowed
    assert cfg.doubt_mover_off_lengths == 0.5

    # only the cloud's movers: background under the cloud, the frame's strongest mover elsewhere
    flat = lambda k, xy, crop=None: (np.zeros((len(xy), 48)), np.ones(len(xy), bool))  # noqa: E731
    r = in_doubt()
    for t in (0.2, 0.3):
        assert r.search_in_doubt(t, flat, _Scale, _Movers((450.0, 300.0)), (302.0, 201.0)) is None
        assert r._pending_mover is None
        r.observe(t, _state(t, 0.1, 302.0, 201.0), 1.0)
    lost = Reacquirer(ReacquisitionSettings(enabled=True, lost_after_s=0.0), (0.25, 8.08), (640, 480))
    lost.observe(0.0, _state(0.0, 0.1), 1.0)
    assert lost.search(0.1, flat, _Scale, _Movers((450.0, 300.0)), (302.0, 201.0)) is None
    assert (lost._pending_mover.x, lost._pending_mover.y) == (450.0, 300.0)

    # the doubt's own rate: the same z 6 mover under the cloud, allowed a billionth of a false alarm
    # a second in doubt, is not pending; once lost, at false_alarms_per_s, it is
    strict = ReacquisitionSettings(enabled=True, lost_after_s=0.5, movers_in_doubt=True,
                                   doubt_false_alarms_per_s=1e-9)
    r = Reacquirer(strict, (0.25, 8.08), (640, 480))
    r.observe(0.0, _state(0.0, 1.0, 300.0, 200.0), 1.0)
    r.observe(0.1, _state(0.1, 0.1, 300.0, 200.0), 1.0)
    assert r.search_in_doubt(0.2, faint(302.0, 201.0), _Scale, cue, (302.0, 201.0)) is None
    assert r._pending_mover is None and r.mover_gate.false_alarms > r.mover_gate.allowed == pytest.approx(1e-10)
    r.observe(0.6, _state(0.6, 0.1, 300.0, 200.0), 1.0)
    assert r.lost
    assert r.search(0.7, faint(302.0, 201.0), _Scale, _MoverOfZ((300.0, 200.0), 6.0), (302.0, 201.0)) is None
    assert r._pending_mover is not None and r.mover_gate.allowed == pytest.approx(0.05 * 0.1)

    # a mover pending from a frame of doubt, not seen again within its reach on the next: a new mover
    # there is held to the same rule, pending only half a length or more off the cloud
    for cloud, pends in (((329.0, 201.0), False), ((339.0, 201.0), True)):
        r = in_doubt()
        assert r.search_in_doubt(0.2, faint(302.0, 201.0), _Scale, cue, off) is None
        assert r._pending_mover is not None
        r.observe(0.2, _state(0.2, 0.1, *cloud), 1.0)
        assert r.search_in_doubt(0.3, faint(327.0, 201.0), _Scale, _MoverOfZ((325.0, 200.0), 6.0), cloud) is None
        assert r.mover_gate.false_alarms <= r.mover_gate.allowed and (r.mover_gate.x, r.mover_gate.y) == (325.0, 200.0)
        assert (r._pending_mover is not None) == pends, cloud
        if pends:
            assert (r._pending_mover.x, r._pending_mover.y) == pytest.approx((327.0, 201.0), abs=0.5)

    # held again: the mover pending from the frame of doubt is dropped
    r = in_doubt()
    assert r.search_in_doubt(0.2, faint(302.0, 201.0), _Scale, cue, off) is None
    assert r._pending_mover is not None
    r.observe(0.2, _state(0.2, 0.9, 302.0, 201.0), 1.0)
    assert r._pending_mover is None and not r.in_doubt


@pytest.mark.parametrize("on", [True, False])
def test_the_tracker_searches_in_doubt_only_with_movers_in_doubt(on):
    """The runner's rule: a lost track is searched; one in doubt only with ``movers_in_doubt`` (and the
    moving-target cue); a held one never."""
    from types import SimpleNamespace

    from common.single_target.runner import Tracker

    cfg = ReacquisitionSettings(enabled=True, lost_after_s=0.5, movers_in_doubt=on)
    fake = SimpleNamespace(settings=SimpleNamespace(reacquisition=cfg), motion_cue=object())
    r = Reacquirer(cfg, (0.25, 8.08), (640, 480))
    r.observe(0.0, _state(0.0, 1.0), 1.0)
    assert not Tracker._searches(fake, r)
    r.observe(0.1, _state(0.1, 0.1), 1.0)
    assert Tracker._searches(fake, r) is on
    fake.motion_cue = None
    assert not Tracker._searches(fake, r)
    r.observe(0.7, _state(0.7, 0.1), 1.0)
    assert r.lost and Tracker._searches(fake, r)


def test_sweep_scales_alternate_about_the_last_held_one():
    r = Reacquirer(ReacquisitionSettings(enabled=True, scale_steps=2, scale_ratio=2.0), (0.25, 8.08), (640, 480))
    r.last_scale = 1.0
    seen = []
    for _ in range(8):
        seen.append(r.sweep_scale())
        r._sweep += 1
    assert seen == [1.0, 0.5, 1.0, 2.0, 1.0, 0.25, 1.0, 4.0]
    r._sweep = 0
    seen = []
    for _ in range(4):
        seen.append(r.sweep_scale(lo=0.9, hi=2.5))
        r._sweep += 1
    assert seen == [1.0, 2.0, 1.0, 2.0]  # 0.5, 0.25 and 4 are outside the range, skipped


def test_acceptance_threshold_is_the_background_quantile():
    thr = acceptance_threshold(0.05, 0.1, 400, (0.25, 8.08))
    assert beta.sf(thr, 0.25, 8.08) == pytest.approx(0.05 * 0.1 / (400 * 12), rel=1e-6)
    assert acceptance_threshold(0.5, 0.1, 400, (0.25, 8.08)) < thr  # more false alarms allowed: lower
    # a tile whose own candidates score high (a structured real background) raises the threshold
    r = Reacquirer(ReacquisitionSettings(enabled=True, false_alarms_per_s=0.05), (0.25, 8.08), (640, 480))
    rng = np.random.default_rng(0)
    calm = rng.beta(0.25, 8.08, 500)
    busy = rng.beta(8.0, 6.0, 500)
    assert r._threshold(0.1, calm) == pytest.approx(acceptance_threshold(0.05, 0.1, 500, (0.25, 8.08)), rel=0.05)
    assert r._threshold(0.1, busy) > r._threshold(0.1, calm) + 0.05


def test_a_tile_with_too_few_candidates_to_measure_its_background_detects_nothing():
    """A tile's own candidates (less their top 5 percent) say how high this frame's background scores;
    fewer than 20 say nothing, and the calibration scene's Beta alone would pass a real background (a
    scale whose footprint fits only about the frame's middle: uav123-car16's 9-candidate tile at scale
    11 restarted the filter 370 px off the car). Known answers at the boundary: 22 candidates leave 20
    to fit, 21 leave 19."""
    r = Reacquirer(ReacquisitionSettings(enabled=True, false_alarms_per_s=0.05), (0.25, 8.08), (640, 480))
    maxima = np.random.default_rng(1).beta(0.25, 8.08, 22)
    maxima[0] = 0.75  # the target, or a road the calibration's Beta cannot explain
    calibration = acceptance_threshold(0.05, 0.1, 22, (0.25, 8.08))
    assert calibration < 0.75  # the calibration's Beta alone would accept it
    assert r._threshold(0.1, maxima) == pytest.approx(max(calibration, acceptance_threshold(
        0.05, 0.1, 22, beta_by_moments(np.sort(np.clip(maxima, 1e-6, 1 - 1e-6))[:20]), 1)))
    assert r._threshold(0.1, maxima) < 0.75  # measured, and the candidate passes
    assert r._threshold(0.1, maxima[:21]) == math.inf
    assert r._threshold(0.1, maxima[:9]) == math.inf
    fixed = Reacquirer(ReacquisitionSettings(enabled=True, min_score=0.6), (0.25, 8.08), (640, 480))
    assert fixed._threshold(0.1, maxima[:9]) == 0.6  # a fixed acceptance score is the user's own


def test_the_searches_refinements_are_matched_on_the_crop_of_their_coarse_query():
    """Every query of a search names a crop box that holds all its points (so the detector prepares
    the box once and the refinements reuse it: common.detector.client.one_off_grid): the tiles'
    refinements name their tile's box, the confirming frame's its grid's, a mover's its own at each
    scale; over a tile search and a confirmation, the queries name fewer boxes than they are
    (each box shared), and a detection is made at the peak (the crop changes nothing for this
    stand-in matcher)."""
    cfg = ReacquisitionSettings(enabled=True, lost_after_s=0.0)
    peaked = _grid_peaked_at(302.0, 201.0)
    queries = []

    def grid_at(k, xy, crop=None):
        queries.append((k, np.array(xy, float), crop))
        return peaked(k, xy)

    r = Reacquirer(cfg, (0.25, 8.08), (640, 480))
    r.observe(0.0, _state(0.0, 0.1, x=300.0, y=200.0), 1.0)
    det = None
    for i in range(1, 30):
        det = r.search(0.1 * i, grid_at, _Scale, None)
        if det is not None:
            break
    assert det is not None and (det.x, det.y) == pytest.approx((302.0, 201.0), abs=0.5)
    assert len(queries) > 3 and all(c is not None for _, _, c in queries)
    for k, xy, c in queries:
        assert np.all((xy[:, 0] >= c[0]) & (xy[:, 0] <= c[2]) & (xy[:, 1] >= c[1]) & (xy[:, 1] <= c[3])), c
    boxes = {(k, c) for k, _, c in queries}
    assert len(boxes) < len(queries)
    # the movers: the grid about the mover and the refinement at the confirming frame share a box
    queries.clear()
    r2 = Reacquirer(cfg, (0.25, 8.08), (640, 480))
    r2.observe(0.0, _state(0.0, 0.1), 1.0)
    r2.search(0.1, grid_at, _Scale, _Movers((300.0, 200.0)))
    n_first = len(queries)
    assert r2.search(0.2, grid_at, _Scale, _Movers((305.0, 200.0))) is not None
    confirm = queries[n_first:]
    for k, xy, c in confirm:
        assert np.all((xy[:, 0] >= c[0]) & (xy[:, 0] <= c[2]) & (xy[:, 1] >= c[1]) & (xy[:, 1] <= c[3])), c
    assert len({(k, c) for k, _, c in confirm}) < len(confirm)


def test_a_restart_off_the_target_by_half_its_length_converges_onto_it(exit_source):
    """A restart whose detection registers one end of the target (half a length off along its travel,
    as a view the template has not seen registers it on real footage) is pulled onto the target
    within two frames by the restart's spread (``restart_pos_lengths``, a quarter length); with a
    cloud a quarter of the search grid's step wide (0.075 lengths, the negative control) it stays on
    the displaced mode for frames. Median over five filter seeds of the error two to five frames on
    (measured: 1-2 px with the quarter length; the car 52 px long). The narrow cloud's, two and
    three frames on: 19-41 px; with the likelihood tempered to a half (stop 55) the narrow cloud
    ahead of the car reaches it four frames on (4.5 and 2.7 px), so only those two frames are the
    control."""
    src = exit_source
    frames = [src.frame(i) for i in range(12)]
    length = max(frames[0].truth.box[2:])

    def errors(spread: float, direction: float) -> np.ndarray:
        out = []
        for seed in range(5):
            st = profile_for(src, seed=seed)
            # the movers tested while the hold is in doubt would restart the narrow cloud on the car
            # (the control's point is the spread's pull alone)
            st = st.model_copy(update={"reacquisition": st.reacquisition.model_copy(
                update={"restart_pos_lengths": spread, "movers_in_doubt": False})})
            tracker = Tracker.start(frames[0], frames[0].truth.box, st)
            err = []
            for i, f in enumerate(frames):
                if i == 6:
                    cx, cy = f.truth.centre
                    det = Detection(cx + direction * 0.5 * length, cy, tracker.last_state.map_estimate.theta, 0.7,
                                    tracker.scale.s)
                    tracker._restart_on(det, f.time, tracker.homography)
                s = tracker.step(f)
                c = f.truth.centre
                err.append(float(np.hypot(s.map_estimate.image_x - c[0], s.map_estimate.image_y - c[1])))
            out.append(err[8:12])
        return np.median(np.array(out), axis=0)

    assert profile_for(src).reacquisition.restart_pos_lengths == 0.25
    for direction in (1.0, -1.0):  # ahead of the car, behind it
        assert np.all(errors(0.25, direction) < 0.1 * length)
        assert np.all(errors(0.075, direction)[:2] > 0.3 * length)
