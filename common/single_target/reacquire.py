"""Loss and re-acquisition: when the posterior says the target is gone, search the frame for it.

Settings: :class:`common.settings.ReacquisitionSettings`. The filters track locally: once the
target has left the frame, or the filter has lost it, no motion model brings the cloud to where
it comes back. :class:`Reacquirer` watches the posterior and, while the target is lost, scans
the frame with the polar matcher (the same template, every angle) and hands the tracker a
confident detection to restart the filter on.

- **Lost** when, for ``lost_after_s`` seconds in a row, ``p(V=1|Z)`` stays below
  ``lost_p_visible`` or the estimate lies outside the frame. Seconds, not frames: the same at
  10 fps and at 30 fps. While the target is held nothing is searched, so a look-alike elsewhere
  in the frame cannot capture the track.
- **Where it was last held** (``last_held``, with its scale and orientation) is carried with the
  camera from frame to frame (:meth:`Reacquirer.carry`): the ground point where the target was
  last seen, in this frame's pixels (at the frame's edge once the camera has turned away from
  it). The search starts from it, and once the filter's cloud has left the frame (nothing holds
  it there: it drifts on at its last velocity) the tracker reports it as the estimate.
- **Search** (only while lost): the frame is cut into square tiles of ``tile_px`` matched pixels
  (the resampled image the template is matched on), overlapping by a target length, visited
  nearest-first from where the target was last held, then in a stride that does not chase a
  moving target, ``tiles_per_frame`` a frame at most every ``tile_interval_s`` of footage (every
  third frame at 30 fps); each tile is scored on a grid of candidate centres
  ``grid_lengths`` target lengths apart at all 48 angles, at one scale per sweep of the frame
  (every other sweep at the last held scale, the others ``scale_ratio`` smaller and larger, ...
  to ``scale_steps`` ratios either way, within the range the matching can follow). The CPU per frame is
  bounded by the tile size: one prepared ``tile_px`` square crop and its candidates (the
  refinement of the tile's best candidates is matched on the same crop, prepared once); the CPU
  per second of footage by ``tile_interval_s``. A frame that ends a sweep searches no tile and
  leaves the budget to the next.
- **Movers** (where the tracker has the moving-target cue, :mod:`common.single_target.motion_cue`):
  before the tiles, every searched frame, the whole frame's target-sized boxes are scored by their
  motion energy (cheap: box sums of one difference image), at one scale of the sweep per frame.
  The strongest mover is a candidate when the background could not produce it: the boxes away
  from it (beyond a box length, and off its moving blob, :func:`background_boxes`: in boxes
  smaller than the target, the target's other parts are not background) give the background's
  upper tail, modelled beyond their ``mover_tail_quantile`` u as
  exponential (peaks over a threshold: the excess over u has mean ``beta``), so P(a background
  box >= z) = (1 - q) exp(-(z - u) / beta); over the n boxes searched the expected false alarms
  n P must stay within ``false_alarms_per_s`` times the frame interval. Its scale: the moving
  blob spans the target and its smear along the travel, so the blob's scale
  (:meth:`~common.single_target.motion_cue.MotionCue.blob_scale`) is the largest its moving
  parts can have; the polar matcher picks the scale among it, one and two ``scale_ratio``
  below, and, for a target that left the view (``left_the_view``), the scale it was last held at
  (a bus whose uniform roof shows no motion moves as a blob of its front half), and the position
  and angle about the mover, each scale's grid refined to its peak before the scales are
  compared (a blob so large that the template's footprint at none of these fits in the frame
  is not the target's extent: then the scale the boxes found it at). It must be the strongest
  mover again on the next frame, in boxes of the size that found it (the boxes say where the
  motion is, the matcher what size the target is: a bus whose uniform roof shows no motion is
  found in boxes of half its size and matched whole), within the length of the target as matched
  (its strongest box may lie on any of its parts from frame to frame), before the filter restarts
  there, at the matcher's refined peak. That second frame tests one hypothesis, the pending
  mover's: the strongest box within its reach, its false alarms counted over the boxes there
  (``mover_confirm_locally``), the tail still the frame's. While the matcher cannot score the
  mover itself (a target entering at the frame's edge, its footprint not yet in the frame) the mover stays
  pending: the grid's scorable points there lie towards the frame's inside, off the target (the
  synthetic exit sequence's restart was 16 px ahead of the car, and the filter lost it).
  With ``mover_near_estimate`` the strongest mover within a target length of the filter's cloud is
  tested first, its false alarms counted over the boxes there: a target lost because its template
  no longer matches (its scale gone stale while it grew, uav123-truck4) is often still under the
  cloud, while the frame's strongest mover is another vehicle.
  On real footage the template often no longer matches a target that comes back (another view,
  another size: uav123-car16's car scores 0.5 where the road scores 0.75, docs/real-footage.md),
  but a car that drives still moves over the ground.
- **In doubt** (``movers_in_doubt``): while p(V=1|Z) is under ``lost_p_visible`` but the track is
  not yet lost, the strongest mover within a target length of the cloud is tested on every frame
  as above, in boxes of the held scale, and a confirmed one restarts the filter at once: a car that
  turned while its cloud carried on is in plain view (uav123-car16's slalom lost the car for the
  half second before the lost state). Nothing else is searched then, and the test allows
  ``doubt_false_alarms_per_s``, a tenth of the lost state's: a cloud in doubt may still be on a
  target hidden for a moment, beside another car that moves (uavdt-S1001 under the trees). A mover
  within ``doubt_mover_off_lengths`` of the cloud lies on the target as the cloud holds it and is
  not pending: a restart there would only trade the cloud for the matcher's peak at the blob's
  scale.
- **Detection**: the best candidate of a tile is refined on a finer grid around it; it passes
  when its score reaches the threshold at which the background's score distribution gives
  ``false_alarms_per_s`` false detections a second over all the hypotheses searched (Bonferroni
  over the candidates), the background being the higher of the likelihood's Beta fit for "no
  target" (over the 12 independent orientations of the P-matrix rows) and a Beta fitted to
  the tile's own candidates (see ``Reacquirer._threshold``; a tile with too few candidates to
  fit detects nothing). It must pass again on the next frame, within a target length, before the
  filter is restarted on it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.stats import beta

from common.detector.layout import N_ROWS
from common.detector.resample import footprint_inside
from common.tracking.camera import apply_homography
from common.tracking.likelihood import beta_by_moments
from common.tracking.observation import GRID_ANGLES_DEG


@dataclass(frozen=True)
class Detection:
    """A confident match found by the search, original pixels."""

    x: float
    y: float
    theta_deg: float
    score: float
    scale: float
    """The target's apparent scale s (relative to the first box) the detection was matched at."""


@dataclass(frozen=True)
class MoverGate:
    """The movers' test on one searched frame, as decided (a diagnostic, ``tools/trace_track.py``)."""

    x: float
    y: float
    """The frame's strongest mover (image pixels)."""
    z: float
    """Its motion z-score."""
    scale: float
    """The scale its boxes were scored at."""
    false_alarms: float
    """Background boxes expected as strong over the frame's boxes, n P (the tail model)."""
    allowed: float
    """What the test allows on this frame: ``false_alarms_per_s`` times the frame interval."""


_MIN_EXCESSES = 20
"""Boxes beyond the threshold needed to fit the tail's scale (its standard error about a fifth)."""


def tail_probability(z: np.ndarray, top: int, far: np.ndarray, quantile: float) -> float:
    """P(a background box's z-score >= ``z[top]``), the background being the boxes ``far`` (bool,
    away from the top one): beyond their ``quantile`` u the tail is exponential with the mean excess
    over u as its scale (peaks over a threshold, a generalised Pareto tail of shape 0). A frame of
    few boxes (a large target) lowers the quantile until 20 boxes lie beyond it, down to the
    median; 1.0 when even that leaves fewer than 20 (no tail to fit)."""
    bg = np.asarray(z, float)[np.asarray(far, bool)]
    if len(bg) == 0:
        return 1.0
    quantile = min(quantile, 1.0 - _MIN_EXCESSES / len(bg))
    if quantile < 0.5:
        return 1.0
    u = float(np.quantile(bg, quantile))
    excess = bg[bg > u] - u
    if len(excess) < _MIN_EXCESSES:
        return 1.0
    zt = float(z[top])
    if zt <= u:
        return float(np.mean(bg >= zt))
    beta_ = float(excess.mean())
    return float((1.0 - quantile) * math.exp(-(zt - u) / beta_)) if beta_ > 0 else 0.0


def background_boxes(xy: np.ndarray, top: int, length: float, blob=None, half_box=(0.0, 0.0)) -> np.ndarray:
    """Which of the movers' boxes ``xy`` (n, 2) the background's tail is fitted on (bool, n): those
    farther than ``length`` from the strongest box ``top`` and, given its moving ``blob`` (x0, y0,
    w, h, image pixels), not overlapping it (centres beyond the blob grown by ``half_box``, the
    boxes' half width and height). In boxes smaller than the target (a sweep's small scale) the
    target's other parts lie beyond a box length of its strongest one, and counted as background
    they make the target explain itself away."""
    xy = np.asarray(xy, float)
    far = np.hypot(xy[:, 0] - xy[top, 0], xy[:, 1] - xy[top, 1]) > length
    if blob is not None:
        x0, y0, w, h = blob
        bw, bh = half_box
        far &= ~((xy[:, 0] >= x0 - bw) & (xy[:, 0] <= x0 + w + bw)
                 & (xy[:, 1] >= y0 - bh) & (xy[:, 1] <= y0 + h + bh))
    return far


def expected_false_alarms(xy: np.ndarray, z: np.ndarray, top: int, length: float, hypotheses: int,
                          quantile: float, blob=None, half_box=(0.0, 0.0)) -> float:
    """The movers' test of box ``top``: the background boxes expected as strong among ``hypotheses``
    boxes searched, n P, the tail fitted beyond ``quantile`` on :func:`background_boxes` (``length``,
    ``blob``, ``half_box`` as there)."""
    far = background_boxes(xy, top, length, blob, half_box)
    return hypotheses * tail_probability(z, top, far, quantile)


def acceptance_threshold(false_alarms_per_s: float, dt: float, hypotheses: int, background,
                         orientations: int = N_ROWS) -> float:
    """The score the background exceeds with probability ``false_alarms_per_s * dt / (hypotheses *
    orientations)``: ``background`` is a (a, b) Beta of the scores where there is no target (of one
    orientation; ``orientations=1`` for a Beta of the best score over all angles)."""
    p = false_alarms_per_s * max(dt, 1e-3) / max(1, hypotheses * orientations)
    return float(beta.isf(min(max(p, 1e-15), 0.5), *background))


_REFINE_STAGES = (0.25, 0.0625)
""":meth:`Reacquirer._refine`'s two 5x5 grids, their spacing in coarse grid steps."""
_REFINE_REACH = 2 * sum(_REFINE_STAGES)
"""How far the refinement reaches beyond a coarse candidate, in coarse grid steps: a coarse query
matched on its points' box grown by this much leaves the refinement inside the same crop, so the
three queries share one preparation."""


_MIN_BACKGROUND = 20
"""Fewest candidates of a tile (less its top 5 percent) that measure the frame's own background
(:meth:`Reacquirer._threshold`): a tile with fewer detects nothing."""


def _grid_5x5() -> np.ndarray:
    g = np.stack(np.meshgrid(np.arange(-2.0, 3.0), np.arange(-2.0, 3.0)), axis=-1).reshape(-1, 2)
    return g[np.argsort(np.hypot(g[:, 0], g[:, 1]), kind="stable")]


_GRID_5X5 = _grid_5x5()
"""Offsets of a 5x5 grid in units of its spacing, nearest the centre first: of points that score
alike, the one nearest the centre is kept (a flat or clipped score grid does not move a candidate)."""


def _crop_about(xy: np.ndarray, reach: float) -> tuple[float, float, float, float]:
    """The box (x0, y0, x1, y1) of the points ``xy`` (N, 2) grown by ``reach`` on every side."""
    return (float(xy[:, 0].min() - reach), float(xy[:, 1].min() - reach),
            float(xy[:, 0].max() + reach), float(xy[:, 1].max() + reach))


_MOVER_GRID_LENGTHS = 0.25
"""Spacing of the grid about a mover (and of its refinement), in target lengths: the movers' boxes
are half a box apart, the matcher's peak narrower."""


def _mover_crop(x: float, y: float, length: float) -> tuple[float, float, float, float]:
    """The box a mover at (x, y) is matched on at a target length ``length``: the 5x5 grid of
    :meth:`Reacquirer._match_mover` (half a length either way) and the refinement about its best
    point (a quarter-length step: :data:`_REFINE_REACH` of it beyond), so both share one crop."""
    return _crop_about(np.array([[x, y]]), (2 * _MOVER_GRID_LENGTHS + _REFINE_REACH * _MOVER_GRID_LENGTHS) * length)


class Reacquirer:
    """The lost state and the tiled search (see the module docstring)."""

    def __init__(self, cfg, background: tuple[float, float], frame_size: tuple[int, int]):
        self.cfg = cfg
        self.background = background
        self.size = frame_size
        self.lost = False
        self.held = False
        """Whether the latest posterior :meth:`observe` saw held the target (:meth:`holds`)."""
        self._below_since: float | None = None
        self.last_held: tuple[float, float] | None = None
        """Where the target was last held for good, this frame's pixels (carried with the camera)."""
        self.last_scale = 1.0
        self.last_theta = 0.0
        self.left_the_view = False
        """Whether the target was last held (for good) within its own length of the frame's edge: a
        target lost that way left the view, and its size when it comes back is the one it was held at
        (up to the camera's zoom); one lost inside the view may have been lost because its scale was
        no longer its own."""
        self._tile = 0
        self._sweep = 0
        self._last_time: float | None = None
        self._last_tile_time: float | None = None
        self._pending: tuple[Detection, float] | None = None
        self._held_since: float | None = None
        self._searching = False
        self._mover_sweep = 0
        self._pending_mover: Detection | None = None
        self._pending_box_scale = 1.0
        """The scale of the movers' boxes that found the pending mover (its Detection's scale is the
        matcher's): the confirming frame repeats the same test, in boxes of the same size."""
        self.mover_gate: MoverGate | None = None
        """The movers' test on the latest searched frame (None: not searched by the movers, or no mover)."""
        self.searches = 0
        self._observed_time: float | None = None
        """The time of the frame :meth:`observe` saw last (the frame before the one being searched)."""
        self.doubt_searches = 0
        """Frames searched while the hold was in doubt (``movers_in_doubt``)."""
        self.doubt_detections = 0
        """Restarts on a mover found while the hold was in doubt."""
        self.mover_detections = 0
        self.tiles = 0
        self.detections = 0
        self.seconds = 0.0
        """Wall time spent searching (a statistic for the benchmarks)."""

    def stats(self) -> dict:
        """Searched frames, tiles, restarts and the search's milliseconds per searched frame."""
        return {"searched_frames": self.searches, "tiles": self.tiles, "restarts": self.detections,
                "restarts_on_movers": self.mover_detections, "frames_searched_in_doubt": self.doubt_searches,
                "restarts_in_doubt": self.doubt_detections,
                "ms_per_searched_frame": round(1e3 * self.seconds / n, 2) if (n := self.searches + self.doubt_searches)
                else 0.0}

    # -- the lost state -------------------------------------------------------------------------
    def carry(self, m: np.ndarray | None) -> None:
        """Carry ``last_held`` into the next frame by ``m`` (previous image pixels -> this frame's; None:
        the camera did not move), kept inside the frame: a homography fitted to the frame's own
        features says little of points beyond it (its perspective terms grow without bound there), and
        the frame's edge is the nearest place the target can be seen again. A point the map sends to
        infinity stays where it was."""
        if self.last_held is not None:
            self.last_held = self.carried(m, self.last_held)

    def carried(self, m: np.ndarray | None, xy: tuple[float, float]) -> tuple[float, float]:
        """The point ``xy`` carried into the next frame by ``m``, kept inside the frame (see :meth:`carry`)."""
        if m is None:
            return xy
        with np.errstate(divide="ignore", invalid="ignore"):
            x, y = apply_homography(m, np.array(xy, float))
        if not (np.isfinite(x) and np.isfinite(y)):
            return xy
        w, h = self.size
        return float(np.clip(x, 0, w - 1)), float(np.clip(y, 0, h - 1))

    def holds(self, state) -> bool:
        """Whether the posterior ``state`` holds the target: p(V=1|Z) at least ``lost_p_visible`` and
        the estimate inside the frame."""
        m = state.map_estimate
        w, h = self.size
        return state.p_visible >= self.cfg.lost_p_visible and 0 <= m.image_x < w and 0 <= m.image_y < h

    def observe(self, time: float, state, scale: float) -> None:
        """Update the lost state from this frame's posterior ``state`` (after the filter step).

        A search goes on across a restart that the filter does not keep (held for less than
        ``lost_after_s``): it continues its sweep from where the target was last held for good,
        instead of starting over at the false detection."""
        cfg = self.cfg
        m = state.map_estimate
        self.held = self.holds(state)
        self._observed_time = float(time)
        if self.held:
            self._pending_mover = None  # a mover pending from a frame of doubt: the filter holds again
            if self._held_since is None:
                self._held_since = float(time)
            self._below_since = None
            self.lost = False
            if not self._searching or time - self._held_since >= cfg.lost_after_s - 1e-9:
                self._searching = False
                self.last_held = (float(m.image_x), float(m.image_y))
                self.last_scale = float(scale)
                self.last_theta = float(m.theta)
                w, h = self.size
                length = max(state.size) if state.size is not None else 0.0
                self.left_the_view = min(m.image_x, m.image_y, w - 1 - m.image_x, h - 1 - m.image_y) < length
            return
        self._held_since = None
        if self._below_since is None:
            self._below_since = float(time)
        if not self.lost and time - self._below_since >= cfg.lost_after_s - 1e-9:
            self.lost = True
            self._pending = None
            self._pending_mover = None
            if not self._searching:
                self._tile, self._sweep, self._searching = 0, 0, True
                self._mover_sweep = 0

    @property
    def in_doubt(self) -> bool:
        """The target was held, the latest posterior does not hold it, and it is not yet lost."""
        return not self.held and not self.lost and self.last_held is not None

    def search_in_doubt(self, time: float, grid_at, scale_tracker, movers, cloud) -> Detection | None:
        """While the hold is in doubt: the movers near the cloud only (``mover_near_estimate``'s test,
        in boxes of the held scale, at ``doubt_false_alarms_per_s``), confirmed on the next frame as
        when lost; a confirmed detection, or None."""
        prev = self._observed_time
        dt = self.cfg.assumed_interval_s if prev is None else max(time - prev, 1e-3)  # one frame's allowance
        self.mover_gate = None
        if cloud is None or movers is None:
            return None
        self.doubt_searches += 1
        det = self._search_movers(dt, grid_at, scale_tracker, movers, cloud, near_only=True)
        if det is None:
            return None
        self.doubt_detections += 1
        return self._at_best_scale(det, grid_at, scale_tracker)

    def relocked(self, det: Detection) -> None:
        """The tracker restarted the filter on ``det``."""
        self.lost = False
        self._below_since = None
        self._held_since = None
        self.detections += 1

    # -- the search -------------------------------------------------------------------------------
    def sweep_scale(self, lo: float = 0.0, hi: float = math.inf) -> float:
        """The scale this sweep of the frame searches at: every other sweep at s0, the scale the
        target was last held at (the likeliest), the sweeps between at s0/r, s0*r, s0/r^2, ... up
        to ``scale_steps`` ratios either way, skipping scales outside [lo, hi] (the scales the
        matching can follow; a skipped ratio advances the sweep)."""
        s, self._sweep = self._scale_of_sweep(self._sweep, lo, hi)
        return s

    def _scale_of_sweep(self, n: int, lo: float, hi: float) -> tuple[float, int]:
        """(scale, sweep) of sweep ``n`` (see :meth:`sweep_scale`): the sweep moves on past ratios
        outside [lo, hi]."""
        count = 4 * self.cfg.scale_steps
        for _ in range(max(count, 1)):
            i = n % count if count else 0
            if i % 2 == 0:
                return float(np.clip(self.last_scale, lo, hi)), n
            m = i // 2  # 0, 1, 2, ...: ratios -1, +1, -2, +2, ...
            j = (m // 2 + 1) * (-1 if m % 2 == 0 else 1)
            s = self.last_scale * self.cfg.scale_ratio ** j
            if lo * (1 - 1e-9) <= s <= hi * (1 + 1e-9):
                return s, n
            n += 2  # the next ratio
        return float(np.clip(self.last_scale, lo, hi)), n

    def _tiles(self, side: float, margin: float) -> list[tuple[float, float, float, float]]:
        """The frame's tiles (x0, y0, x1, y1), each grown by ``margin`` on every side (a target on a
        tile's edge is whole in one of them), in this sweep's order: nearest-first from where the
        target was last held on the first sweep after the loss, then in a golden-ratio stride (a
        target moving across the frame is not chased tile after tile)."""
        w, h = self.size
        nx, ny = max(1, math.ceil(w / side)), max(1, math.ceil(h / side))
        tw, th = w / nx, h / ny
        tiles = [(max(0.0, i * tw - margin), max(0.0, j * th - margin), min(w, (i + 1) * tw + margin),
                  min(h, (j + 1) * th + margin)) for j in range(ny) for i in range(nx)]
        cx, cy = self.last_held if self.last_held is not None else (w / 2, h / 2)
        tiles.sort(key=lambda t: (math.hypot((t[0] + t[2]) / 2 - cx, (t[1] + t[3]) / 2 - cy), t[1], t[0]))
        n = len(tiles)
        if self._sweep == 0 or n < 3:
            return tiles
        stride = max(1, round(n * 0.618))
        while math.gcd(stride, n) != 1:
            stride += 1
        return [tiles[(i * stride) % n] for i in range(n)]

    def search(self, time: float, grid_at, scale_tracker, movers=None, cloud=None) -> Detection | None:
        """Search this frame; a detection confirmed on two frames in a row, or None.

        ``grid_at(k, xy, crop)`` -> (scores (N, 48), valid (N,)) at factor ``k`` (the scale search's
        one-off grids; the queries of a frame naming the same ``crop`` box share its preparation);
        ``scale_tracker`` gives the matching factor and the target's length;
        ``movers`` is the tracker's moving-target cue with this frame pushed
        (:class:`common.single_target.motion_cue.MotionCue`: ``movers(s)`` -> the frame's boxes and
        their motion z-scores at scale s, ``blob_box(xy)``, ``blob_scale(xy)`` and ``box_size``, the
        first box's; None: no cue, the tiles only); ``cloud`` is where the filter's cloud is now (its
        MAP carried into this frame's pixels; None: unknown), whose movers are tested first
        (``mover_near_estimate``).

        A candidate that passes the threshold on one frame is only pending: the next frame looks
        for it again within a target length of it (at its scale) and confirms it if it passes
        again there (a one-frame coincidence of the background does not restart the filter)."""
        cfg = self.cfg
        dt = cfg.assumed_interval_s if self._last_time is None else max(time - self._last_time, 1e-3)
        self._last_time = float(time)
        self.searches += 1
        self.mover_gate = None
        if movers is not None and cfg.motion_search:
            det = self._search_movers(dt, grid_at, scale_tracker, movers, cloud)
            if det is not None:
                self._pending = None
                return self._at_best_scale(det, grid_at, scale_tracker)
        pending, self._pending = self._pending, None
        if pending is not None:
            det, thr = pending
            k = scale_tracker.factor(det.scale)
            step = max(cfg.grid_lengths * scale_tracker.length_px * det.scale, 1.0)
            off = np.arange(-3, 4) * (step / 1.5)
            gx, gy = np.meshgrid(det.x + off, det.y + off)
            xy = np.stack([gx.ravel(), gy.ravel()], axis=1)
            crop = _crop_about(xy, _REFINE_REACH * step / 1.5)
            again, maxima = self._best(grid_at, k, xy, det.scale, crop)
            if again is not None:
                again = self._refine(grid_at, k, xy, maxima, step / 1.5, det.scale, crop)
                if again.score >= thr:
                    return self._at_best_scale(again, grid_at, scale_tracker)
        best: tuple[Detection, float] | None = None
        # the tiles' CPU budget: a frame's tiles at most every tile_interval_s of footage, each
        # tile's threshold allowing the false alarms of the time since the tiles searched before
        since = None if self._last_tile_time is None else time - self._last_tile_time
        if since is not None and since < cfg.tile_interval_s - 1e-6:
            return None
        dt_tiles = dt if since is None or cfg.tile_interval_s <= 0 else max(since, 1e-3)
        for _ in range(cfg.tiles_per_frame):
            s = self.sweep_scale(*scale_tracker.scale_range())
            k = scale_tracker.factor(s)
            length = scale_tracker.length_px * s
            tiles = self._tiles(cfg.tile_px / k, 0.5 * length)
            if self._tile >= len(tiles):
                self._tile, self._sweep = 0, self._sweep + 1
                continue
            x0, y0, x1, y1 = tiles[self._tile]
            self._tile += 1
            self.tiles += 1
            self._last_tile_time = float(time)
            step = max(cfg.grid_lengths * length, 1.0)
            xs = np.arange(x0 + step / 2, x1, step)
            ys = np.arange(y0 + step / 2, y1, step)
            if len(xs) == 0 or len(ys) == 0:
                continue
            gx, gy = np.meshgrid(xs, ys)
            xy = np.stack([gx.ravel(), gy.ravel()], axis=1)
            crop = _crop_about(xy, _REFINE_REACH * step)  # the refinement reuses the tile's crop
            det, maxima = self._best(grid_at, k, xy, s, crop)
            if det is None:
                continue
            det = self._refine(grid_at, k, xy, maxima, step, s, crop)
            thr = self._threshold(dt_tiles, maxima)
            if det.score >= thr and (best is None or det.score > best[0].score):
                best = (det, thr)
        self._pending = best
        return None

    def _search_movers(self, dt: float, grid_at, scale_tracker, movers, cloud=None,
                       near_only: bool = False) -> Detection | None:
        """The strongest mover of the frame, when the background's tail cannot explain it and it was
        the strongest on the frame before too, within the length of the target as matched then (at
        least a box length; see the module docstring). With ``mover_confirm_locally`` the confirming
        frame tests the pending mover's own hypothesis: the strongest box within that reach, against
        the boxes there, not the frame's."""
        cfg = self.cfg
        rate = cfg.doubt_false_alarms_per_s if near_only else cfg.false_alarms_per_s
        pending, self._pending_mover = self._pending_mover, None
        if pending is not None:
            s = self._pending_box_scale  # the same test again: boxes of the size that found it
        elif near_only:
            s = float(scale_tracker.s)  # in doubt: the target is where and as large as it was held
        else:
            s, n = self._scale_of_sweep(self._mover_sweep, *scale_tracker.scale_range())
            self._mover_sweep = n + 1  # one scale a frame: the movers cover the frame at once
        xy, z = movers.movers(s)
        if len(z) == 0:
            return None
        length = scale_tracker.length_px * s
        reach = length  # the same mover: within the target's length as matched (its strongest box may lie on any part)
        if pending is not None and cfg.mover_confirm_within_target:
            reach = max(length, scale_tracker.length_px * pending.scale)
        if pending is not None and cfg.mover_confirm_locally:
            within = np.flatnonzero(np.hypot(xy[:, 0] - pending.x, xy[:, 1] - pending.y) <= reach)
            if len(within):
                top = int(within[np.argmax(z[within])])
                gate = self._gate(scale_tracker, movers, xy, z, top, s, len(within), dt, rate)
                if gate.false_alarms <= gate.allowed:
                    return self._confirm(grid_at, scale_tracker, pending, gate.x, gate.y)
        gate = None
        if cloud is not None and cfg.mover_near_estimate:
            around = np.flatnonzero(np.hypot(xy[:, 0] - cloud[0], xy[:, 1] - cloud[1])
                                    <= max(length, scale_tracker.target_length_px))
            if len(around):
                top = int(around[np.argmax(z[around])])
                gate = self._gate(scale_tracker, movers, xy, z, top, s, len(around), dt, rate)
                if gate.false_alarms > gate.allowed:
                    gate = None
        if gate is None and near_only:
            return None  # in doubt the frame's other movers are not tested
        if gate is None:
            top = int(np.argmax(z))
            gate = self._gate(scale_tracker, movers, xy, z, top, s, len(z), dt, rate)
            if gate.false_alarms > gate.allowed:
                return None
        x, y = gate.x, gate.y
        if pending is not None and math.hypot(x - pending.x, y - pending.y) <= reach:
            return self._confirm(grid_at, scale_tracker, pending, x, y)
        if near_only and (math.hypot(x - cloud[0], y - cloud[1])
                          < cfg.doubt_mover_off_lengths * scale_tracker.target_length_px):
            return None  # a new mover on the target as the cloud holds it: nothing to correct
        # the scale: the blob spans the target and its motion smear (and blur), so at most the
        # blob's, the matcher picking among the ratios below it; unless the blob is a part of the
        # target (the motion of its uniform middle unseen): a target that left the view comes back
        # at the size it was held at, so that scale as well
        blob = movers.blob_scale((x, y))
        top_s = s if blob is None else blob
        lo, hi = scale_tracker.scale_range()
        scales = {float(np.clip(top_s / cfg.scale_ratio ** j, lo, hi)) for j in range(3)}
        if self.left_the_view:
            scales.add(float(np.clip(self.last_scale, lo, hi)))
        scales = sorted(scales)
        if not any(self._fits_the_frame(scale_tracker, v) for v in scales):
            # a target this large could not be matched anywhere in this frame, so the blob is not the
            # target's extent (a blob merged with its surroundings): the scale whose boxes found the
            # mover is the one to match it at, where a pending mover can be confirmed
            scales = [s]
        self._pending_mover, _ = self._match_mover(grid_at, scale_tracker, x, y, scales)
        self._pending_box_scale = s
        return None

    def _gate(self, scale_tracker, movers, xy: np.ndarray, z: np.ndarray, top: int, s: float, hypotheses: int,
              dt: float, rate: float) -> MoverGate:
        """The movers' test of box ``top`` among ``hypotheses`` boxes searched: the background's tail,
        fitted to the frame's boxes beyond a box length of it and off its moving blob, gives the
        expected number of background boxes as strong among them, allowed ``rate`` a second over the
        frame interval ``dt`` (kept as :attr:`mover_gate`)."""
        cfg = self.cfg
        length = scale_tracker.length_px * s
        own = movers.blob_box((float(xy[top, 0]), float(xy[top, 1]))) if cfg.mover_tail_without_blob else None
        if own is not None and not self._fits_the_frame(scale_tracker, min(own[2], own[3]) / min(movers.box_size)):
            own = None  # larger than any target the frame could show: merged with its surroundings
        n_p = expected_false_alarms(xy, z, top, length, hypotheses, cfg.mover_tail_quantile, own,
                                    (movers.box_size[0] * s / 2, movers.box_size[1] * s / 2))
        gate = MoverGate(float(xy[top, 0]), float(xy[top, 1]), float(z[top]), float(s), n_p, rate * dt)
        self.mover_gate = gate
        return gate

    def _confirm(self, grid_at, scale_tracker, pending: Detection, x: float, y: float) -> Detection | None:
        """The pending mover, seen again at ``(x, y)``: matched there at its scale, the detection; None
        while the matcher cannot score it (it stays pending where it is now)."""
        det, on_mover = self._match_mover(grid_at, scale_tracker, x, y, [pending.scale])
        if not on_mover:
            # the matcher cannot score the mover itself (its footprint is not yet in the frame):
            # its best scorable point is displaced towards the frame's inside, off the target.
            # Wait for the frame on which it can (it stays pending where it is now)
            self._pending_mover = replace(pending, x=x, y=y)
            return None
        self.mover_detections += 1
        return det

    def _fits_the_frame(self, scale_tracker, s: float) -> bool:
        """Whether the template's footprint at scale ``s`` can lie wholly in the frame somewhere (at its
        centre): the one-off grids score only such hypotheses."""
        k = scale_tracker.factor(s)
        w, h = self.size
        return bool(footprint_inside(np.array([[(w - 1) / 2, (h - 1) / 2]]), k, (w, h))[0])

    def _match_mover(self, grid_at, scale_tracker, x: float, y: float,
                     scales: list[float]) -> tuple[Detection, bool]:
        """The matcher's best (position, angle, scale) about the mover at ``(x, y)`` over ``scales``:
        at each scale a 5x5 grid a quarter of a target length apart (the mover's box centre is only
        as fine as the boxes' half-box spacing) refined to the matcher's peak about its best points
        (:meth:`_refine`: the peak is narrower than the grid, and the scales are compared at their
        peaks, not at wherever their grids happen to fall); the mover itself at the first scale when
        the matcher cannot score there. And whether the matcher could score the mover's own position
        and the grid's points a quarter length about it (where the target's centre may lie, the boxes
        being half a box apart) at the best's scale: near the frame's edge only the grid's inner
        points may be scorable, and a target entering there lies towards the edge of its box."""
        best = Detection(x, y, self.last_theta, float("nan"), float(scales[0]))
        on_mover = False
        grid = _GRID_5X5 * _MOVER_GRID_LENGTHS
        for s in scales:
            step = scale_tracker.length_px * s
            pts = np.array([x, y]) + step * grid
            k = scale_tracker.factor(s)
            crop = _mover_crop(x, y, step)
            scores, ok = grid_at(k, pts, crop)
            per = np.where(np.asarray(ok, bool)[:, None], np.asarray(scores, float), -np.inf)
            if not np.isfinite(per).any():
                continue
            cand = self._refine(grid_at, k, pts, per.max(axis=1), _MOVER_GRID_LENGTHS * step, s, crop)
            if not (cand.score <= best.score):  # higher, or nothing scored yet (NaN)
                best = cand
                # grid[0] is the mover itself, grid[:9] the quarter length about it, as far as the
                # boxes' centre (half a box apart) may lie from the target's
                on_mover = bool(np.all(np.asarray(ok, bool)[:9]))
        return best, on_mover

    def _at_best_scale(self, det: Detection, grid_at, scale_tracker) -> Detection:
        """``det`` refined (position, angle) at its own scale and at one and two half ``scale_ratio``
        steps either way, the best of them: a detection is made at a sweep's scale (a mover: at one
        of its blob's), and a target matched at the wrong scale is matched off its centre and angle
        too, which a restart would keep."""
        lo, hi = scale_tracker.scale_range()
        r = math.sqrt(self.cfg.scale_ratio)
        best = det
        for j in (-2, -1, 1, 2):
            s = det.scale * r ** j
            if not lo <= s <= hi:
                continue
            k = scale_tracker.factor(s)
            step = max(0.25 * scale_tracker.length_px * s, 1.0)
            pt = np.array([[det.x, det.y]])
            cand = self._refine(grid_at, k, pt, np.array([det.score]), step, s, _crop_about(pt, _REFINE_REACH * step))
            if cand.score > best.score:
                best = cand
        return best

    def _refine(self, grid_at, k: float, xy: np.ndarray, maxima: np.ndarray, step: float, s: float,
                crop=None) -> Detection:
        """The best of the ``refine_candidates`` best coarse candidates, each refined twice on a
        5x5 grid (a quarter, then a sixteenth of the coarse spacing), every candidate's grid in one
        query per stage: the matcher's peak is narrower than the coarse grid, so a target between
        two candidates scores low there. ``crop``: the box both stages are matched on (the coarse
        query's, whose preparation they then share; see :data:`_REFINE_REACH`)."""
        centres = xy[np.argsort(-maxima, kind="stable")[: self.cfg.refine_candidates]]
        best: Detection | None = None
        for frac in _REFINE_STAGES:
            grid = _GRID_5X5 * (step * frac)
            pts = (centres[:, None, :] + grid[None, :, :]).reshape(-1, 2)
            scores, ok = grid_at(k, pts, crop)
            per = np.where(np.asarray(ok, bool)[:, None], np.asarray(scores, float), -np.inf)
            per = per.reshape(len(centres), len(grid), -1)
            flat = per.reshape(len(centres), -1)
            idx = np.argmax(flat, axis=1)
            pi, ai = np.unravel_index(idx, per.shape[1:])
            centres = pts.reshape(len(centres), len(grid), 2)[np.arange(len(centres)), pi]
            top = int(np.argmax(flat[np.arange(len(centres)), idx]))
            score = float(flat[top, idx[top]])
            if np.isfinite(score):
                best = Detection(float(centres[top, 0]), float(centres[top, 1]), float(GRID_ANGLES_DEG[ai[top]]),
                                 score, float(s))
        if best is None:
            i = int(np.argmax(maxima))
            best = Detection(float(xy[i, 0]), float(xy[i, 1]), 0.0, float(maxima[i]), float(s))
        return best

    @staticmethod
    def _best(grid_at, k: float, xy: np.ndarray, s: float, crop=None) -> tuple[Detection | None, np.ndarray]:
        """The best-scoring (position, angle) of ``xy`` at factor ``k`` (matched on ``crop``, see
        :meth:`_refine`), and each position's best score (-inf out of support)."""
        scores, ok = grid_at(k, xy, crop)
        ok = np.asarray(ok, bool)
        scores = np.where(ok[:, None], np.asarray(scores, float), -np.inf)
        if not np.isfinite(scores).any():
            return None, np.full(len(xy), -np.inf)
        i, a = np.unravel_index(int(np.argmax(scores)), scores.shape)
        det = Detection(float(xy[i, 0]), float(xy[i, 1]), float(GRID_ANGLES_DEG[a]), float(scores[i, a]), float(s))
        return det, scores.max(axis=1)

    def _threshold(self, dt: float, maxima: np.ndarray) -> float:
        """The acceptance score for a search whose candidates' best scores are ``maxima``: the
        higher of the likelihood's background Beta's and of a Beta fitted (by moments) to these
        candidates themselves, less their top 5 percent (the target, if it is there), each at
        ``false_alarms_per_s`` over the hypotheses searched. Real backgrounds (roads, kerbs,
        buildings) score far above the calibration scene's, and this frame's own candidates say by
        how much. With fewer than ``_MIN_BACKGROUND`` of them (at a scale whose footprint fits only
        about the frame's middle) they say nothing, and the calibration's Beta alone lets the real
        background through: no score is accepted (uav123-car16 after its close pass, seeds 0 and 1: a
        tile of 9 candidates at scale 11 restarted the filter 370 px off the car)."""
        cfg = self.cfg
        if cfg.min_score is not None:
            return float(cfg.min_score)
        maxima = maxima[np.isfinite(maxima)]
        n = max(len(maxima), 1)
        thr = acceptance_threshold(cfg.false_alarms_per_s, dt, n, self.background)
        bg = np.sort(np.clip(maxima, 1e-6, 1 - 1e-6))[: max(int(0.95 * len(maxima)), 0)]
        if len(bg) < _MIN_BACKGROUND:
            return math.inf  # too few to say how high this frame's background scores: no detection
        fit = beta_by_moments(bg)
        if fit is not None:
            thr = max(thr, acceptance_threshold(cfg.false_alarms_per_s, dt, n, fit, 1))
        return thr
