"""Smooth vehicle paths: a heading-rate and speed profile integrated over time.

A path is sampled once per frame. Turns are smooth bumps of heading rate (cosine ramps in and
out, constant in the middle), so heading, position and the car's image rotation are all smooth.
The manoeuvres sit at fixed fractions of the run (``SCHEDULE``), with the straight stretches the
events need in between.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .config import SceneConfig


@dataclass(frozen=True)
class Turn:
    """A smooth turn: starts at ``start`` (fraction of the run), lasts ``duration`` (fraction)."""

    start: float
    duration: float
    angle_deg: float  # + = left (anticlockwise seen from above)


@dataclass(frozen=True)
class Schedule:
    """Where the manoeuvres and events sit in the run, as fractions of the run length."""

    turns: tuple[Turn, ...]
    smoke_centre: float  # time of the smoke's centre (middle of a straight)
    decoy_closest: float  # time of the decoy's closest approach (middle of a straight)
    wall: tuple[float, float]  # the wall runs along the path driven between these times (a straight)
    slow_turn: int  # index of the turn the car slows down for
    slow_fraction: float  # speed reduction at the slowest point of that turn


# Default manoeuvres: a gentle ~95 deg turn, a straight with the smoke, a straight with the decoy
# pass, a sharp ~75 deg turn the other way, a straight along the wall, a medium ~45 deg turn.
# The gentle turn ends about 1 s before the smoke starts to thin the car and 2 s before it hides
# it completely, so the car crosses the smoke on a straight (as in Pang et al. Fig. 6-7): what
# happens inside the smoke is predictable from the motion before it. The smoke and the decoy
# pass are ~2.5 s apart so that the smoke's rim is clear of the pass.
# Each seed scales the angles by 0.85..1.15 and may mirror them all.
SCHEDULE = Schedule(
    turns=(
        Turn(0.02, 0.15, 95.0),  # gentle
        Turn(0.66, 0.08, -75.0),  # sharp
        Turn(0.905, 0.09, 45.0),  # medium
    ),
    smoke_centre=0.345,
    decoy_closest=0.60,
    wall=(0.755, 0.895),
    slow_turn=1,
    slow_fraction=0.35,
)

# The decoy's own turns: it comes round a corner before the pass and turns off after it (their
# signs are chosen per scene so that it keeps clear of the smoke and the wall; see scene.py).
DECOY_TURNS = (Turn(0.38, 0.12, 55.0), Turn(0.65, 0.10, 65.0))

_SUBSTEPS = 8  # integration steps per frame


def _turn_rate_shape(u: np.ndarray) -> np.ndarray:
    """Heading-rate shape on u in [0, 1]: cosine ramp in over 25%, flat, cosine ramp out; 0 outside."""
    r = 0.25
    g = np.zeros_like(u)
    inside = (u >= 0) & (u <= 1)
    up = inside & (u < r)
    down = inside & (u > 1 - r)
    mid = inside & ~up & ~down
    g[up] = 0.5 - 0.5 * np.cos(np.pi * u[up] / r)
    g[down] = 0.5 - 0.5 * np.cos(np.pi * (1 - u[down]) / r)
    g[mid] = 1.0
    return g


_SHAPE_MEAN = 0.75  # integral of _turn_rate_shape over [0, 1]


@dataclass(frozen=True)
class VehiclePath:
    """A vehicle's pose at every frame time."""

    t: np.ndarray  # (n,) seconds
    xy: np.ndarray  # (n, 2) metres, world frame (x east, y north)
    heading: np.ndarray  # (n,) radians, anticlockwise from east
    speed: np.ndarray  # (n,) m/s

    @property
    def forward(self) -> np.ndarray:
        """(n, 2) unit forward vectors."""
        return np.stack([np.cos(self.heading), np.sin(self.heading)], axis=1)

    @property
    def left(self) -> np.ndarray:
        """(n, 2) unit vectors to the vehicle's left."""
        return np.stack([-np.sin(self.heading), np.cos(self.heading)], axis=1)

    def rigidly_moved(self, frame: int, xy: np.ndarray, heading: float) -> VehiclePath:
        """The same path, rotated and translated so that at ``frame`` it is at ``xy`` with ``heading``."""
        dth = heading - self.heading[frame]
        c, s = np.cos(dth), np.sin(dth)
        rot = np.array([[c, -s], [s, c]])
        new_xy = (self.xy - self.xy[frame]) @ rot.T + np.asarray(xy, float)
        return VehiclePath(self.t, new_xy, self.heading + dth, self.speed)

    def extended_polyline(self, extra_m: float, step_m: float = 0.5) -> np.ndarray:
        """The path's centre line with straight extensions of ``extra_m`` at both ends (for roads)."""
        n_ext = max(1, int(np.ceil(extra_m / step_m)))
        d = np.linspace(extra_m, step_m, n_ext)[:, None]
        head = self.xy[0] - d * self.forward[0]
        tail = self.xy[-1] + d[::-1] * self.forward[-1]
        # thin the per-frame samples so consecutive points are at least ~step_m apart
        keep = [0]
        for i in range(1, len(self.xy)):
            if np.hypot(*(self.xy[i] - self.xy[keep[-1]])) >= step_m:
                keep.append(i)
        if keep[-1] != len(self.xy) - 1:
            keep.append(len(self.xy) - 1)
        return np.concatenate([head, self.xy[keep], tail])


def integrate_path(
    n_frames: int,
    fps: float,
    turns: tuple[Turn, ...],
    base_speed: float,
    slow: tuple[float, float, float] | None = None,
    start_xy: tuple[float, float] = (0.0, 0.0),
    start_heading: float = 0.0,
) -> VehiclePath:
    """Integrate heading rate and speed over the run; sample at the frame times.

    ``turns`` are in fractions of the run; ``slow = (start, duration, fraction)`` slows the vehicle
    by ``fraction`` at the middle of that window (smooth raised cosine).
    """
    t_last = (n_frames - 1) / fps
    run = n_frames / fps
    n_fine = (n_frames - 1) * _SUBSTEPS + 1
    tf = np.linspace(0.0, t_last, n_fine)
    omega = np.zeros(n_fine)
    for turn in turns:
        t0, dur = turn.start * run, turn.duration * run
        omega += np.deg2rad(turn.angle_deg) / (dur * _SHAPE_MEAN) * _turn_rate_shape((tf - t0) / dur)
    speed = np.full(n_fine, float(base_speed))
    if slow is not None:
        s0, sd, frac = slow
        u = (tf - s0 * run) / (sd * run)
        bump = np.where((u >= 0) & (u <= 1), 0.5 - 0.5 * np.cos(2 * np.pi * np.clip(u, 0, 1)), 0.0)
        speed *= 1.0 - frac * bump
    dt = np.diff(tf)
    heading = start_heading + np.concatenate([[0.0], np.cumsum(0.5 * (omega[1:] + omega[:-1]) * dt)])
    vel = speed[:, None] * np.stack([np.cos(heading), np.sin(heading)], axis=1)
    xy = np.asarray(start_xy, float) + np.concatenate(
        [np.zeros((1, 2)), np.cumsum(0.5 * (vel[1:] + vel[:-1]) * dt[:, None], axis=0)]
    )
    sl = slice(None, None, _SUBSTEPS)
    return VehiclePath(tf[sl].copy(), xy[sl].copy(), heading[sl].copy(), speed[sl].copy())


@dataclass(frozen=True)
class Paths:
    """The target's path, the candidate decoy paths, and the seed's other random choices."""

    target: VehiclePath
    decoy_candidates: tuple[tuple[int, VehiclePath], ...]  # (side, path), in the seed's preference order
    decoy_frame: int  # frame of the designed closest approach
    mirror: bool  # turns mirrored (right instead of left first)
    wall_side: int  # preferred side for the wall: +1 the target's left, -1 its right


def frame_at(fraction: float, cfg: SceneConfig) -> int:
    """The frame closest to ``fraction`` of the run."""
    return int(np.clip(round(fraction * cfg.n_frames), 0, cfg.n_frames - 1))


def build_paths(cfg: SceneConfig, rng: np.random.Generator) -> Paths:
    """The target's path and the decoy's candidate paths for one seed.

    Every candidate decoy drives the opposite way to the target and is, at ``decoy_frame``, exactly
    ``decoy_distance_m`` to one side of it, parallel; candidates differ in that side and in the
    directions of the decoy's two turns.
    """
    sched = SCHEDULE
    mirror = bool(rng.random() < 0.5)
    sign = -1.0 if mirror else 1.0
    scales = rng.uniform(0.85, 1.15, size=len(sched.turns))
    turns = tuple(
        Turn(tr.start, tr.duration, sign * tr.angle_deg * k) for tr, k in zip(sched.turns, scales)
    )
    v0 = cfg.speed_mps * rng.uniform(0.9, 1.1)
    slow_turn = sched.turns[sched.slow_turn]
    slow = (slow_turn.start - 0.03, slow_turn.duration + 0.06, sched.slow_fraction)
    heading0 = rng.uniform(-np.pi, np.pi)
    target = integrate_path(cfg.n_frames, cfg.fps, turns, v0, slow, (0.0, 0.0), heading0)

    wall_side = 1 if rng.random() < 0.5 else -1
    decoy_frame = frame_at(sched.decoy_closest, cfg)
    dscale = rng.uniform(0.8, 1.2, size=len(DECOY_TURNS))
    v_decoy = v0 * rng.uniform(0.9, 1.1)
    combos = [(side, s1, s2) for side in (1, -1) for s1 in (1.0, -1.0) for s2 in (1.0, -1.0)]
    order = rng.permutation(len(combos))
    candidates = []
    if cfg.decoy:
        for k in order:
            side, s1, s2 = combos[k]
            dturns = tuple(Turn(tr.start, tr.duration, sg * tr.angle_deg * sc)
                           for tr, sg, sc in zip(DECOY_TURNS, (s1, s2), dscale))
            raw = integrate_path(cfg.n_frames, cfg.fps, dturns, v_decoy)
            at = target.xy[decoy_frame] + side * cfg.decoy_distance_m * target.left[decoy_frame]
            candidates.append((side, raw.rigidly_moved(decoy_frame, at, target.heading[decoy_frame] + np.pi)))
    return Paths(target, tuple(candidates), decoy_frame, mirror, wall_side)


def total_rotation_deg(path: VehiclePath) -> float:
    """Sum of absolute heading changes between frames, in degrees."""
    return float(np.rad2deg(np.abs(np.diff(path.heading)).sum()))
