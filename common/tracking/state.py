"""Filter inputs and outputs: :class:`InitialState` (the prior) and :class:`TrackState` (per frame).

Particle arrays use the column order of Pang's state S_t without V:
``[x, vx, y, vy, theta]`` (world units, world units/s, degrees); see
:data:`PARTICLE_COLUMNS`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from .camera import image_to_world
from .kernel_density import kernel_density
from .motion import wrap_degrees
from .resampling import ess


class InitError(ValueError):
    """The first box (or person boxes) cannot start a track; the message says why and how to fix it.
    One error for the single-target tracker and the multi-target filters."""

PARTICLE_COLUMNS = ("x", "vx", "y", "vy", "theta")
"""Columns of a particle array: world position/velocity (Pang's X_t) and image-plane orientation (degrees)."""


@dataclass(frozen=True)
class InitialState:
    """The prior at ``time``: independent Gaussians about a world-frame state.

    World units are metres when the observations carry a homography, pixels otherwise.
    A std of 0 puts every particle exactly at the mean.
    """

    x: float
    y: float
    vx: float = 0.0
    vy: float = 0.0
    theta: float = 0.0
    """Orientation relative to the template, degrees (0: the template's own orientation)."""
    p_visible: float = 1.0
    """p(V_0 = 1); Pang's filter starts on a visible, hand-marked target."""
    time: float | None = None
    """Time of the prior, seconds; None: the time of the first step (which then does not predict)."""
    pos_std: float = 0.0
    vel_std: float = 0.0
    theta_std: float = 0.0

    @classmethod
    def from_image_point(
        cls, image_xy: tuple[float, float], homography: np.ndarray | None, **kwargs
    ) -> "InitialState":
        """Prior centred on the ground point seen at image pixel ``image_xy`` through ``homography``
        (world -> image, e.g. the first frame's; None = identity). Other fields by keyword."""
        wx, wy = image_to_world(homography, np.asarray(image_xy, dtype=float))
        return cls(x=float(wx), y=float(wy), **kwargs)

    @classmethod
    def from_image_box(
        cls, box_xyxy: tuple[float, float, float, float], homography: np.ndarray | None, **kwargs
    ) -> "InitialState":
        """Prior centred on the centre of the image box ``(x_min, y_min, x_max, y_max)`` (pixels)."""
        x0, y0, x1, y1 = box_xyxy
        return cls.from_image_point((0.5 * (x0 + x1), 0.5 * (y0 + y1)), homography, **kwargs)

    def sample_particles(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """n particles (n, 5) [x, vx, y, vy, theta] drawn from the prior (5n standard normals)."""
        mean = np.array([self.x, self.vx, self.y, self.vy, self.theta], dtype=float)
        std = np.array([self.pos_std, self.vel_std, self.pos_std, self.vel_std, self.theta_std], dtype=float)
        particles = mean + std * rng.standard_normal((n, 5))
        particles[:, 4] = wrap_degrees(particles[:, 4])
        return particles


@dataclass(frozen=True)
class Estimate:
    """One point estimate of the target state."""

    x: float
    """World x (m, or px with no homography)."""
    y: float
    vx: float
    """World velocity (world units / s)."""
    vy: float
    theta: float
    """Image-plane orientation relative to the template, degrees in [-180, 180), anticlockwise as displayed."""
    image_x: float
    """Image position, pixels."""
    image_y: float

    @property
    def speed(self) -> float:
        """|v| in world units / s."""
        return math.hypot(self.vx, self.vy)

    @property
    def world_xy(self) -> np.ndarray:
        return np.array([self.x, self.y])

    @property
    def image_xy(self) -> np.ndarray:
        return np.array([self.image_x, self.image_y])


def _readonly(a: np.ndarray | None) -> np.ndarray | None:
    if a is None:
        return None
    if isinstance(a, np.ndarray) and not a.flags.writeable and a.flags.owndata:
        return a  # already a state's own read-only copy (dataclasses.replace of a state): no second copy
    a = np.array(a, copy=True)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class TrackState:
    """What a tracker reports for one frame.

    For the particle filters the estimates, ``n_eff`` and the particle arrays are
    those of the weighted posterior *before* any resampling of this step (the
    ``resampled`` flag says whether resampling followed).
    """

    time: float
    """Frame time, seconds."""
    observed: bool
    """False when the step had no observation (prediction only)."""
    map_estimate: Estimate
    """MAP estimate: the highest-weight particle (Pang §8 'RBPF MAP estimate'); for windowed ML the arg-max."""
    mmse_estimate: Estimate
    """MMSE estimate: weighted mean (circular mean for theta; image position = weighted mean of the
    particles' image positions)."""
    p_visible: float
    """p(V_t = 1 | Z_1:t) (Pang eq. A.5); windowed ML: 1.0 if its max score reached the threshold, else 0.0."""
    n_eff: float
    """Effective sample size 1 / sum W^2 (Pang eq. 23); NaN for windowed ML."""
    speed: float
    """|v| of the MAP estimate, world units / s (Pang Fig. 6d)."""
    orientation: float
    """theta of the MAP estimate, degrees (Pang Fig. 6e)."""
    particles: np.ndarray | None = None
    """(N, 5) [x, vx, y, vy, theta] world-frame particles; None for windowed ML."""
    particles_image: np.ndarray | None = None
    """(N, 2) image positions of the particles, pixels."""
    particle_visibility: np.ndarray | None = None
    """(N,) RBPF: p(V_t = 1 | particle history, Z_1:t); SIR: the sampled V_t (0.0 / 1.0)."""
    weights: np.ndarray | None = None
    """(N,) normalised weights, summing to 1."""
    resampled: bool = False
    """Whether the particles were resampled after this frame's estimates."""
    log_likelihood: float = float("nan")
    """log p(Z_t | Z_1:t-1) estimated by the particles, up to a frame constant (Pang's Omega); 0 if unobserved."""
    score: float | None = None
    """Raw detector score at the MAP: the best of the particles' scores within the kernel's bandwidth
    of the MAP particle (:func:`neighbourhood_score`; windowed ML: the window maximum); None if
    unobserved."""
    search_window: tuple[float, float, int] | None = None
    """Windowed ML only: (centre x, centre y, side) of this frame's search window, pixels."""
    size: tuple[float, float] | None = None
    """(w, h) of the target's box in image pixels, before the rotation by ``orientation``: the first
    box's sides times the apparent scale, or the target's segment's extent (``segment.centre_box``; set by
    :class:`common.single_target.runner.Tracker`; None from a bare filter)."""
    reacquired: bool = False
    """Whether this frame's estimate comes from a re-acquisition (the filter re-locked on a detection)."""
    box_offset: tuple[float, float] | None = None
    """(dx, dy) image pixels from the MAP estimate to the box's centre, where the target's centre was
    measured apart from the point the template holds (set by :class:`common.single_target.runner.Tracker`,
    ``segment.centre_box``); None: the box is centred on the MAP."""

    @property
    def centre(self) -> tuple[float, float]:
        """The target's centre in the image, as scored against a ground-truth box's centre: the MAP
        estimate moved by ``box_offset`` (the MAP itself where none was measured)."""
        m = self.map_estimate
        dx, dy = self.box_offset or (0.0, 0.0)
        return (m.image_x + dx, m.image_y + dy)

    def oriented_box(self) -> tuple[float, float, float, float, float] | None:
        """(cx, cy, w, h, theta_deg) of the target's oriented box, about :attr:`centre`; None without
        a size."""
        if self.size is None:
            return None
        return (*self.centre, self.size[0], self.size[1], self.map_estimate.theta)

    def axis_aligned_box(self) -> tuple[float, float, float, float] | None:
        """(x, y, w, h) of the axis-aligned box with :meth:`oriented_box`'s extent (the benchmarks' box):
        :func:`oriented_to_moment_box`, not the envelope :func:`oriented_to_axis_aligned`. The size is
        the first box's, itself the axis-aligned envelope of the target as it stood on the first frame,
        not the target's outline; the envelope of that box turned by the target's rotation counts the
        turn twice (a 2:1 box turned 45 degrees doubles in area) and grows with every error of the
        angle (7.5 degrees, one step of the matcher's angle grid, makes a 2:1 box's short side 25 %
        longer). Turned as an extent, the box swaps its sides over a quarter turn and grows little on
        the way (a 2:1 box by a quarter in area at 45 degrees; by 2.5 % on its short side at 7.5)."""
        ob = self.oriented_box()
        return None if ob is None else oriented_to_moment_box(*ob)

    def __post_init__(self) -> None:
        for name in ("particles", "particles_image", "particle_visibility", "weights"):
            object.__setattr__(self, name, _readonly(getattr(self, name)))

    def identical(self, other: "TrackState") -> bool:
        """Bit-for-bit equality of every field (NaN equals NaN)."""
        for f in fields(self):
            a, b = getattr(self, f.name), getattr(other, f.name)
            if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
                if not (isinstance(a, np.ndarray) and isinstance(b, np.ndarray)):
                    return False
                if a.shape != b.shape or a.dtype != b.dtype:
                    return False
                if not np.array_equal(a, b, equal_nan=a.dtype.kind == "f"):
                    return False
            elif isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
                continue
            elif a != b:
                return False
        return True


def oriented_to_axis_aligned(cx: float, cy: float, w: float, h: float, theta_deg: float
                             ) -> tuple[float, float, float, float]:
    """(x, y, w, h) of the smallest axis-aligned box holding a w x h box centred on (cx, cy) and
    turned by ``theta_deg``."""
    c, s = abs(math.cos(math.radians(theta_deg))), abs(math.sin(math.radians(theta_deg)))
    bw, bh = w * c + h * s, w * s + h * c
    return (cx - bw / 2.0, cy - bh / 2.0, bw, bh)


def oriented_to_moment_box(cx: float, cy: float, w: float, h: float, theta_deg: float
                           ) -> tuple[float, float, float, float]:
    """(x, y, w, h) of the axis-aligned box with the same second moments along the image axes as a
    w x h box centred on (cx, cy) and turned by ``theta_deg``: the box's extent E = diag(w^2, h^2)
    turned as R E R^T (as extended-object trackers turn an extent), its sides the square roots of
    the diagonal. w x h at 0 degrees, h x w at 90, sqrt((w^2 + h^2) / 2) square at 45."""
    c2, s2 = math.cos(math.radians(theta_deg)) ** 2, math.sin(math.radians(theta_deg)) ** 2
    bw, bh = math.sqrt(w * w * c2 + h * h * s2), math.sqrt(w * w * s2 + h * h * c2)
    return (cx - bw / 2.0, cy - bh / 2.0, bw, bh)


def box_axes(theta_deg: float) -> np.ndarray:
    """The 2 x 2 map from a box's own axes to the image's for a box turned by ``theta_deg``
    anticlockwise as displayed (image y down), as :func:`oriented_box_corners` turns its corners:
    an offset (u, v) along the box's sides is ``box_axes(theta) @ (u, v)`` in image pixels, and
    ``box_axes(theta).T`` maps back."""
    a = math.radians(theta_deg)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, s], [-s, c]])


def oriented_box_corners(cx: float, cy: float, w: float, h: float, theta_deg: float) -> list[tuple[float, float]]:
    """The four corners of a w x h box centred on (cx, cy) and turned by ``theta_deg``
    anticlockwise as displayed (image y down), in outline order."""
    offsets = np.array([[-w / 2, -h / 2], [w / 2, -h / 2], [w / 2, h / 2], [-w / 2, h / 2]])
    return [(cx + float(x), cy + float(y)) for x, y in offsets @ box_axes(theta_deg).T]


def summarise_particles(
    particles: np.ndarray, image_xy: np.ndarray, weights: np.ndarray
) -> tuple[int, Estimate, Estimate, float]:
    """(index of the MAP particle, MAP estimate, MMSE estimate, the kernel's squared bandwidth) of a
    weighted particle set.

    MAP: the particle at the highest point of the posterior density of the position, estimated
    with a Gaussian kernel over the weighted particles (Pang Fig. 8 shows this kernel
    estimate): ``argmax_i sum_j w_j exp(-|x_i - x_j|^2 / 2h^2)`` in world coordinates, with
    Scott's bandwidth ``h = sigma * N_eff^(-1/6)``. With a peaked posterior this is the particle
    of highest weight; with a flat one (an occluded target, where every weight is about
    equal) it is the centre of the cloud's densest part rather than an arbitrary particle.
    Ties go to the lowest index. MMSE: weighted means, theta as the circular mean.
    """
    w = np.asarray(weights, dtype=float)
    mean = w @ particles
    ang = np.deg2rad(particles[:, 4])
    mean_theta = float(wrap_degrees(np.rad2deg(np.arctan2(w @ np.sin(ang), w @ np.cos(ang)))))
    mean_img = w @ image_xy
    mmse = Estimate(
        x=float(mean[0]), y=float(mean[2]), vx=float(mean[1]), vy=float(mean[3]), theta=mean_theta,
        image_x=float(mean_img[0]), image_y=float(mean_img[1]),
    )  # fmt: skip
    i, h2 = kernel_mode(particles[:, [0, 2]], w)
    p = particles[i]
    map_ = Estimate(
        x=float(p[0]), y=float(p[2]), vx=float(p[1]), vy=float(p[3]), theta=float(p[4]),
        image_x=float(image_xy[i, 0]), image_y=float(image_xy[i, 1]),
    )  # fmt: skip
    return i, map_, mmse, h2


def kernel_bandwidth2(xy: np.ndarray, w: np.ndarray) -> float:
    """Scott's squared bandwidth per axis of the weighted cloud ``xy`` (n, 2): the weighted variance
    per axis times N_eff^(-1/3) (not finite, or 0, for a cloud on one point)."""
    d = xy - w @ xy
    var = float(w @ np.sum(d * d, axis=1)) / 2.0
    n_eff = 1.0 / float(np.sum(w * w))
    return var * n_eff ** (-1.0 / 3.0)


def kernel_mode(xy: np.ndarray, w: np.ndarray, max_points: int = 2000) -> tuple[int, float]:
    """(index of the point of highest weighted Gaussian-kernel density, Scott's squared bandwidth
    it used; 0 for a single point).

    Above ``max_points`` points only the ``max_points`` of highest weight are candidates (the
    density is still summed over all), keeping the cost bounded.
    """
    n = len(w)
    if n == 1:
        return 0, 0.0
    h2 = kernel_bandwidth2(xy, w)
    if not np.isfinite(h2) or h2 <= 0.0:
        return int(np.argmax(w)), h2
    if n <= max_points:
        return int(np.argmax(kernel_density(xy, w, h2))), h2
    cand = np.argsort(-w, kind="stable")[:max_points]
    dens = kernel_density(xy, w, h2, cand)
    return int(cand[np.argmax(dens)]), h2


def kernel_mode_index(xy: np.ndarray, w: np.ndarray, max_points: int = 2000) -> int:
    """Index of the point of highest weighted Gaussian-kernel density (Scott's bandwidth; :func:`kernel_mode`)."""
    return kernel_mode(xy, w, max_points)[0]


def neighbourhood_score(xy: np.ndarray, w: np.ndarray, i: int, scores: np.ndarray, h2: float | None = None) -> float:
    """The best of ``scores`` among the points of ``xy`` within one kernel bandwidth (Scott's, as
    :func:`kernel_mode_index`) of point ``i``: how well the template matches at the MAP, read at the
    MAP's own resolution rather than at the one angle and offset its particle drew. The particle
    at the mode is one draw of the cloud's orientation and position there; the more the posterior
    is spread (a tempered likelihood, an uncertain frame), the further that draw lies from where
    the match peaks, and the gates that ask how well the target is matched would read the draw's
    spread as the target's. Non-finite scores are skipped (the MAP's own score if none is finite).
    ``h2``: the bandwidth :func:`kernel_mode` already computed for this cloud (None: computed here)."""
    s = np.asarray(scores, dtype=float)
    if h2 is None:
        h2 = kernel_bandwidth2(xy, w) if len(w) > 1 else 0.0
    d2 = np.sum((xy - xy[i]) ** 2, axis=1)
    near = (d2 <= h2) if np.isfinite(h2) and h2 > 0.0 else (np.arange(len(s)) == i)
    near &= np.isfinite(s)
    return float(np.max(s[near])) if near.any() else float(s[i])


def filter_state(frame_time: float, observed: bool, particles: np.ndarray, image_xy: np.ndarray,
                 weights: np.ndarray, visibility: np.ndarray, log_likelihood: float, scores: np.ndarray | None,
                 ess_threshold_fraction: float) -> TrackState:
    """The :class:`TrackState` a particle filter reports after weighting: MAP and MMSE estimates,
    p(V=1|Z) = sum_p w_p v_p (``visibility``: each particle's V or p(V=1)), N_eff and whether it
    falls below ``ess_threshold_fraction * N`` (the filter then resamples)."""
    n_eff = ess(weights)
    i_map, map_est, mmse_est, h2 = summarise_particles(particles, image_xy, weights)
    return TrackState(
        time=float(frame_time),
        observed=observed,
        map_estimate=map_est,
        mmse_estimate=mmse_est,
        p_visible=float(np.clip(weights @ visibility, 0.0, 1.0)),
        n_eff=n_eff,
        speed=map_est.speed,
        orientation=map_est.theta,
        particles=particles,
        particles_image=image_xy,
        particle_visibility=visibility,
        weights=weights,
        resampled=n_eff < ess_threshold_fraction * len(particles),
        log_likelihood=float(log_likelihood),
        score=(None if not observed or scores is None
               else neighbourhood_score(particles[:, [0, 2]], weights, i_map, scores, h2)),
    )
