"""The target's apparent scale ``s_t`` and the resampling factor the frame is matched at.

Settings: :class:`common.settings.ScaleSettings`. The frame is matched resampled by
``k_t = quantise(clip(u / s_t))`` (:mod:`common.detector.resample`):

- ``u``, chosen once from the initial box: a target whose long side ``L`` is shorter than
  ``target_size_px`` is enlarged by ``target_size_px / L`` (at most ``max_initial_upsample``), so
  the template's fixed footprint sees a target of about the size its layout was designed for; one
  longer than the footprint itself (``2 * SUPPORT_RADIUS_PX``) is reduced to that size too; ``k``
  is never more than ``max_upsample`` or ``u``, whichever is larger (a target is followed as it
  shrinks down to ``target_size_px / max_upsample``, or its own first size where that is smaller);
- ``s_t``, the target's size relative to the first frame:

  * from a metric (ground-plane) homography: ``sqrt(det J_t(w_t)) / sqrt(det J_0(w_0))`` with
    ``J`` the homography's Jacobian at the target's world position (an object of fixed size on
    the ground looks that much bigger);
  * otherwise predicted from frame to frame by the same Jacobian ratio at the same world point
    (with a stabilised source that is the camera's own zoom or approach at the target), fused by
    inverse variance with the target's own change of size where its pixels give one
    (:mod:`common.single_target.target_flow`), and corrected every ``search_interval_s`` by a
    search: the best match over a small neighbourhood of the MAP position and all angles is measured at scales ``s / r, s, s * r``
    and a parabola through the three (in log scale) gives the correction, clipped to one step
    (moved on along the scales while the best is at an end, never to one that cannot be scored).
    Where the template's footprint at ``s`` or ``s * r`` is not whole in the frame about the MAP,
    only smaller scales can be compared: the largest that can be scored and those below it say
    whether the target is smaller (``search_below_footprint``), never that it is larger.
"""

from __future__ import annotations

import math

import numpy as np

from common.detector.layout import SUPPORT_RADIUS_PX
from common.detector.resample import quantise_factor
from common.single_target.target_flow import FlowMeasurement
from common.tracking.camera import homography_jacobian


def initial_factor(box: tuple[float, float, float, float], target_size_px: float | None,
                   max_upsample: float) -> float:
    """``u``: how much to resample the initial box's target. Shorter than ``target_size_px``: enlarged
    to it (at most ``max_upsample``). Longer than the template's footprint (``2 * SUPPORT_RADIUS_PX``
    matched pixels): reduced to it as well, since matched at full resolution the footprint would
    lie wholly inside the target, a template of its interior with none of the context its outer
    columns are for (uav123-car16 from frame 440, a 176 px first box: docs/real-footage.md, stop
    38). Between the two, matched as it is (1.0), as before."""
    long_side = max(float(box[2]), float(box[3]))
    if target_size_px is None or long_side <= 0:
        return 1.0
    if long_side > 2 * SUPPORT_RADIUS_PX:
        return float(target_size_px / long_side)
    if long_side >= target_size_px:
        return 1.0
    return float(min(max_upsample, target_size_px / long_side))


def first_box_factor(box: tuple[float, float, float, float], cfg) -> float:
    """``u`` for the first box under the settings ``cfg`` (:class:`common.settings.ScaleSettings`): the
    first box may be enlarged up to the larger of the two caps."""
    return initial_factor(box, cfg.target_size_px, max(cfg.max_upsample, cfg.max_initial_upsample))


def fuse_with_zoom(log_zoom: float, own_dlog: float, own_var: float, departure_q: float, dt: float,
                   time_constant_s: float) -> tuple[float, float]:
    """(change of log size, updated departure variance rate): the camera's zoom ``log_zoom`` and the
    target's own measurement (``own_dlog``, variance ``own_var``) fused by inverse variance, the zoom's
    variance being ``departure_q * dt`` with ``departure_q`` first updated from this innovation
    nu = own_dlog - log_zoom: max(0, (1 - a) q + a (nu^2 - r) / dt), a = dt / ``time_constant_s``."""
    nu = own_dlog - log_zoom
    a = min(1.0, dt / time_constant_s)
    departure_q = max(0.0, (1 - a) * departure_q + a * (nu * nu - own_var) / dt)
    q = departure_q * dt
    return log_zoom + q / (q + own_var) * nu, departure_q


def _sqrt_det(h: np.ndarray | None, world_xy: np.ndarray) -> float:
    j = homography_jacobian(h, np.asarray(world_xy, float))
    d = float(abs(np.linalg.det(j)))
    return math.sqrt(d) if d > 0 and math.isfinite(d) else float("nan")


class ScaleTracker:
    """``s_t`` and the matching factor; see the module docstring."""

    def __init__(self, cfg, init_box: tuple[float, float, float, float], metric_homography: bool,
                 first_homography: np.ndarray | None, first_world_xy: np.ndarray, t0: float):
        self.cfg = cfg
        self.mode = cfg.mode
        if self.mode == "auto":
            self.mode = "homography" if metric_homography else "search"
        if self.mode == "homography" and not metric_homography:
            self.mode = "off"  # nothing to take the scale from
        self.u = first_box_factor(init_box, cfg)
        self.length_px = max(float(init_box[2]), float(init_box[3]))
        self.s = 1.0
        self._j0 = _sqrt_det(first_homography, first_world_xy) if self.mode == "homography" else 1.0
        self._last_search = float(t0)
        self._last_time = float(t0)
        self.rate = 0.0
        """d log(s) / dt from the searches (1/s), extrapolated between them (alpha-beta filter)."""
        self._prev_search: float | None = None
        self.searches = 0
        self.corrections = 0
        self.flow_measurements = 0
        """Frames whose prediction took in the target's own change of size."""
        self.departure_q = cfg.flow.departure_per_sqrt_s ** 2
        """Variance rate (1/s) of the target's size departing from the camera's zoom, estimated on line."""
        self._owed = 0
        """Searches still to make whatever the score (after a restart)."""

    # -- the factor -------------------------------------------------------------------------
    @property
    def max_k(self) -> float:
        """The largest factor k: ``max_upsample``, or ``u`` where the first box needed more."""
        return max(self.cfg.max_upsample, self.u, 1.0)

    def raw_factor(self, s: float | None = None) -> float:
        s = self.s if s is None else s
        return float(np.clip(self.u / s, self.cfg.min_factor, self.max_k))

    def factor(self, s: float | None = None) -> float:
        """k_t (at scale ``s``, default s_t), quantised (1.0 exactly when no resampling is needed)."""
        return quantise_factor(self.raw_factor(s), self.cfg.steps_per_octave)

    @property
    def target_length_px(self) -> float:
        """The target's current long side in image pixels (initial length times s_t)."""
        return self.length_px * self.s

    # -- per frame --------------------------------------------------------------------------
    def predict(self, prev_h: np.ndarray | None, h: np.ndarray | None, world_xy: np.ndarray | None,
                time: float | None = None, own: FlowMeasurement | None = None) -> None:
        """Update s_t for a new frame with homography ``h`` (previous ``prev_h``) at ``time`` before
        matching; ``world_xy`` is the previous estimate's world position, ``own`` the target's own
        change of size measured from its pixels (search mode only).

        The camera's zoom z at the target's ground point predicts the change of log size with a
        variance q = d^2 dt (the target leaving its ground point's scale); the target's own
        measurement m has variance r; the change applied is log z + q / (q + r) (m - log z). d^2
        follows the innovations nu = m - log z: d^2 <- max(0, (1 - a) d^2 + a (nu^2 - r) / dt),
        a = dt / departure_time_constant_s."""
        dt = 0.0
        if self.mode == "search" and time is not None:
            dt = max(0.0, float(time) - self._last_time)
            self._last_time = float(time)
            if self.rate != 0.0 and dt > 0:
                self.s *= math.exp(self.rate * dt)
                self._clip()
        if self.mode == "off" or world_xy is None:
            return
        if self.mode == "homography":
            s = _sqrt_det(h, world_xy) / self._j0
        else:
            if h is None and prev_h is None:
                return
            zoom = _sqrt_det(h, world_xy) / _sqrt_det(prev_h, world_xy)
            if own is not None and dt > 0 and math.isfinite(zoom) and zoom > 0:
                dlog, self.departure_q = fuse_with_zoom(math.log(zoom), own.dlog, own.var, self.departure_q, dt,
                                                        self.cfg.flow.departure_time_constant_s)
                zoom = math.exp(dlog)
                self.flow_measurements += 1
            s = self.s * zoom
        if math.isfinite(s) and s > 0:
            self.s = s
        self._clip()

    def scale_range(self) -> tuple[float, float]:
        """(lo, hi): the scales s_t whose factor is not clipped (beyond, the matching cannot follow)."""
        return self.u / self.max_k, self.u / self.cfg.min_factor

    def restart(self, s: float, swept: bool = True) -> None:
        """Start again at scale ``s``: no growth rate, no previous search. ``swept``: ``s`` is a
        re-acquisition's sweep step, not a measurement, so the next ``searches_after_restart``
        searches are made whatever the score; a measured scale (the template's registration on the
        target's segment) owes none: the score gate goes on deciding."""
        self.s = float(s)
        self.rate = 0.0
        self._prev_search = None
        self._owed = self.cfg.searches_after_restart if swept else 0
        self._clip()

    def _clip(self) -> None:
        """Keep s_t where the factor is not clipped (beyond, the matching scale cannot follow)."""
        lo, hi = self.scale_range()
        self.s = float(np.clip(self.s, lo, hi))
        if self.s in (lo, hi):
            self.rate = 0.0

    def maybe_search(self, time: float, grid_at, state) -> bool:
        """Correct s_t by the scale search when due and the target is seen well; True if searched.

        ``grid_at(k, xy)`` -> (scores (N, 48), valid (N,)): the frame's scores at ``xy`` matched at
        factor ``k``, each call on its own resampled crop
        (:meth:`common.detector.client.LocalDetector.scale_grid`)."""
        cfg = self.cfg
        if self.mode != "search" or state is None or state.score is None:
            return False
        if time - self._last_search < cfg.search_interval_s - 1e-9:
            return False
        if self._owed <= 0 and (state.p_visible < cfg.search_min_p_visible or state.score < cfg.search_min_score):
            self.rate = 0.0  # no measurement: assume no growth rather than extrapolate a stale one
            self._prev_search = None
            return False
        self._owed = max(0, self._owed - 1)
        self._last_search = float(time)
        x, y = state.map_estimate.image_x, state.map_estimate.image_y
        r = cfg.search_ratio
        d = self.target_length_px / 8.0
        off = np.array([(dx, dy) for dy in (-d, 0.0, d) for dx in (-d, 0.0, d)])
        xy = np.array([x, y]) + off
        cache: dict[int, float] = {}

        def best_at(n: int) -> float | None:
            """Best score over the positions and all angles at scale s * r^n (None: unusable)."""
            if n not in cache:
                k = self.raw_factor(self.s * r ** n)
                if n != 0 and k == self.raw_factor(self.s * r ** (n - np.sign(n))):
                    cache[n] = None  # clipped: same factor as the neighbour
                else:
                    g, ok = grid_at(k, xy)
                    cache[n] = float(np.max(g[ok])) if ok[4] else None
            return cache[n]

        centre = 0
        b = [best_at(-1), best_at(0), best_at(1)]
        one_sided = cfg.search_below_footprint and (b[1] is None or b[2] is None)
        if one_sided:
            # the footprint at this scale or the next larger is not whole in the frame about the
            # estimate (a target as large as the frame shows, or a scale run too large): the scales
            # that can be scored say only whether the target is smaller than the largest of them
            # (looked for up to search_max_steps below), the parabola through it and the two below
            # saying by how much (no further: far below the held scale the footprint is wholly in
            # the frame only where the target is not, at its edge)
            top = 0
            while best_at(top) is None and top > -cfg.search_max_steps:
                top -= 1
            upper, lower = best_at(top), best_at(top - 1)
            if upper is None or lower is None or lower <= upper:
                return False
            centre = top - 1
            below = best_at(centre - 1)
            b = [-math.inf if below is None else below, lower, upper]
        elif any(v is None for v in b):
            return False
        # line search: while the best is at an end, move the bracket that way (up to max steps),
        # not beyond the scales that can be scored
        while not one_sided and not (b[1] >= b[0] and b[1] >= b[2]) and abs(centre) < cfg.search_max_steps:
            move = -1 if b[0] > b[2] else 1
            nxt = best_at(centre + 2 * move)
            if nxt is None:
                break
            centre += move
            b = [b[1], b[2], nxt] if move > 0 else [nxt, b[0], b[1]]
        self.searches += 1
        b0, b1, b2 = b
        den = b0 - 2 * b1 + b2
        if b0 == -math.inf:
            step = 0.0  # the least scale scored: no parabola through it
        elif b1 >= b0 and b1 >= b2:
            step = 0.5 * (b0 - b2) / den if den < 0 else 0.0
        else:
            step = -1.0 if b0 > b2 else 1.0
        step = centre + float(np.clip(step, -1.0, 1.0))
        if step != 0.0:
            self.s *= r ** (cfg.search_gain * step)
            self.corrections += 1
        if cfg.search_rate_gain > 0:
            elapsed = float(time) - self._prev_search if self._prev_search is not None else None
            if elapsed is not None and elapsed > 0:
                self.rate += cfg.search_rate_gain * step * math.log(r) / elapsed
                self.rate = float(np.clip(self.rate, -cfg.max_rate, cfg.max_rate))
        self._prev_search = float(time)
        self._clip()
        return True
