"""Windowed maximum-likelihood search: the baseline of Nelson 2008 §III-A and Pang 2010 §8.

Works in image pixels (it uses no world dynamics; Pang §8 notes it does not use
the sensor positioning). Exact behaviour, per frame t with an observation:

1. Search window. ``locked`` (the previous frame's maximum reached the threshold,
   or the first frame): centred on the previous position P_{t-1}, side
   ``window_px``. Otherwise (lost): centred on the extrapolation
   P_{t-1} + v (t - t_{t-1}), where v is the image velocity from the last two
   positions before the loss (held constant while lost), and its side is the
   previous side times ``growth`` (doubled), capped at ``max_window_px``.
2. The window is every integer pixel (cx + i, cy + j), i, j in
   [-(side // 2), side - side // 2 - 1], about the rounded centre, cut to the
   image. One ``score_grid`` call scores all of them at the 48 angles.
   If ``angle_window_deg`` is set and the tracker is locked, only angles within
   that distance of the previous theta count (Nelson's Theta_t); when lost all do.
3. The arg-max (x, y, theta) over the window gives the best score s*.
   If s* >= ``threshold``: the new position is the arg-max, theta its angle,
   v is updated to (P_t - P_{t-1}) / T, and the next window returns to
   ``window_px`` about P_t ("locked"). Otherwise the target is taken as lost:
   the reported position is the extrapolation (the window centre of step 1 when
   already lost), theta is kept, v is kept, and the next window grows.

With no observation (``step(t, None)``) the position is extrapolated as when
lost, but the window size and the locked/lost mode are left unchanged.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from ._frames import FrameClock
from .camera import image_to_world, world_to_image
from .motion import wrap_degrees
from .observation import FrameObservation, ObservationUnavailable
from .state import Estimate, InitialState, TrackState


class WindowedMLConfig(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", use_attribute_docstrings=True)

    window_px: int = Field(25, ge=1)
    """Side of the search window when locked, pixels. Pang 2010 §8: 25x25."""
    threshold: float = 0.6
    """Minimum max-score to accept a detection. Pang 2010 §8: 0.6 (Nelson 2008 §IV: 0.7)."""
    growth: float = Field(2.0, gt=1.0)
    """Window side multiplier per lost frame (both papers: doubled)."""
    window_points: int | None = Field(25, ge=1)
    """Grid points per window side: a doubled window keeps 25 x 25 points at twice the spacing
    (Pang 2010 Fig. 10 counts the ML search's cost in points). None: every pixel of the window."""
    max_window_px: int = Field(200, ge=1)
    """Cap on the window side, pixels (ours; the papers give none)."""
    angle_window_deg: float | None = Field(None, ge=0.0)
    """If set, when locked only angles within this many degrees of the previous theta are searched
    (Nelson 2008 Theta_t 'small neighbourhood'); None searches all 48 angles (Pang 2010 §8)."""


class WindowedMaximumLikelihood:
    """The windowed ML baseline. ``step(frame_time, observation)`` -> :class:`TrackState`. Deterministic."""

    def __init__(self, config: WindowedMLConfig | None, initial: InitialState) -> None:
        """``config`` None means :class:`WindowedMLConfig` defaults; ``initial`` gives the start (world frame,
        converted to pixels through the first frame's homography); only x, y, theta and time are used."""
        self.config = config if config is not None else WindowedMLConfig()
        self.initial = initial
        self.clock = FrameClock(initial.time)
        self.position: np.ndarray | None = None
        """Last reported image position P_{t-1}, pixels (set from the prior on the first step)."""
        self.velocity = np.zeros(2)
        """Image velocity used to extrapolate, px/s."""
        self.theta = float(initial.theta)
        self.window_size = self.config.window_px
        """Side of the next search window, pixels."""
        self.locked = True

    @classmethod
    def from_image_box(
        cls,
        config: WindowedMLConfig | None,
        box_xyxy: tuple[float, float, float, float],
        first_observation: FrameObservation,
        **initial_kwargs,
    ) -> "WindowedMaximumLikelihood":
        initial = InitialState.from_image_box(box_xyxy, first_observation.homography, **initial_kwargs)
        return cls(config, initial)

    @staticmethod
    def window_grid(centre: np.ndarray, side: int, image_size: tuple[int, int], points: int | None = None) -> np.ndarray:
        """(M, 2) integer pixel positions of a ``side`` x ``side`` window about the rounded ``centre``,
        restricted to the image [0, width-1] x [0, height-1]. With ``points``, a window wider than
        ``points`` pixels is sampled on a ``points`` x ``points`` grid (stride ``side / points``),
        so the search costs the same number of scores whatever its size."""
        c = np.rint(centre)
        off = np.arange(side) - side // 2
        if points is not None and side > points:
            off = np.unique(np.rint((np.arange(points) - (points - 1) / 2.0) * (side / points)))
        gx, gy = np.meshgrid(c[0] + off, c[1] + off, indexing="xy")
        pts = np.column_stack([gx.ravel(), gy.ravel()])
        w, h = image_size
        inside = (pts[:, 0] >= 0) & (pts[:, 0] <= w - 1) & (pts[:, 1] >= 0) & (pts[:, 1] <= h - 1)
        return pts[inside]

    def step(self, frame_time: float, observation: FrameObservation | None) -> TrackState:
        cfg = self.config
        dt = self.clock.advance(frame_time)
        h = self.clock.see(observation)
        if self.position is None:
            self.position = world_to_image(h, np.array([self.initial.x, self.initial.y]))
        previous = self.position
        extrapolated = previous + self.velocity * dt
        centre = previous if self.locked else extrapolated

        score = None
        window = None
        detected = False
        new_position, new_theta = extrapolated, self.theta
        grid = None
        if observation is not None:
            side = self.window_size
            pts = self.window_grid(centre, side, observation.image_size, cfg.window_points)
            try:
                grid = observation.score_grid(pts) if len(pts) else None
            except ObservationUnavailable:
                observation = None  # the detector did not answer: as step(t, None)
        if observation is not None:
            window = (float(np.rint(centre[0])), float(np.rint(centre[1])), int(side))
            best = -np.inf
            if grid is not None:
                scores, valid = grid
                scores = np.asarray(scores, dtype=float)
                n_ang = scores.shape[1]
                angles = wrap_degrees(np.arange(n_ang) * (360.0 / n_ang))
                ok = np.asarray(valid, dtype=bool)[:, None] & np.isfinite(scores)
                if self.locked and cfg.angle_window_deg is not None:
                    ok &= (np.abs(wrap_degrees(angles - self.theta)) <= cfg.angle_window_deg)[None, :]
                masked = np.where(ok, scores, -np.inf)
                k = int(np.argmax(masked))
                best = float(masked.flat[k])
                i, j = divmod(k, n_ang)
            score = best if np.isfinite(best) else None
            detected = np.isfinite(best) and best >= cfg.threshold
            if detected:
                new_position, new_theta = pts[i].astype(float), float(angles[j])
                if dt > 0:
                    self.velocity = (new_position - previous) / dt
                self.locked = True
                self.window_size = cfg.window_px
            else:
                self.locked = False
                self.window_size = int(min(round(side * cfg.growth), cfg.max_window_px))

        self.position, self.theta = new_position, new_theta
        world_now, world_prev = image_to_world(h, np.stack([new_position, previous]))
        world_v = (world_now - world_prev) / dt if dt > 0 else np.zeros(2)
        est = Estimate(
            x=float(world_now[0]), y=float(world_now[1]), vx=float(world_v[0]), vy=float(world_v[1]),
            theta=float(new_theta), image_x=float(new_position[0]), image_y=float(new_position[1]),
        )  # fmt: skip
        return TrackState(
            time=float(frame_time),
            observed=observation is not None,
            map_estimate=est,
            mmse_estimate=est,
            p_visible=1.0 if detected else 0.0,
            n_eff=float("nan"),
            speed=est.speed,
            orientation=est.theta,
            score=score,
            search_window=window,
        )


WindowedML = WindowedMaximumLikelihood
