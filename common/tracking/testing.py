"""Synthetic observations for tests and demos: a Gaussian score bump over a static clutter field.

:class:`GaussianBumpObservation` implements :class:`~common.tracking.observation.FrameObservation`
without any image: the "detector" score at image position (x, y) and angle theta is

    score = peak * exp(-d^2 / (2 sigma^2)) * exp((cos(theta - theta*) - 1) / sigma_theta^2) + clutter(x, y, theta)

(d: distance to the target's image position; sigma_theta in radians; the angular
factor is a von Mises-like "cos" falloff, 1 at theta = theta*), clipped to [-1, 1].
With ``occluded=True`` the bump is absent and only the low-level clutter remains.
The clutter field is a fixed, smooth sum of plane waves in (x, y, theta) drawn from
``clutter_seed``, scaled to standard deviation ``clutter``: the same hypothesis always
gets the same score within one frame, as with a real image. A hypothesis whose support
(a disc of radius ``support_radius_px``) leaves the image is invalid: score 0.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .camera import world_to_image
from .observation import GRID_ANGLES_DEG

_N_WAVES = 12


def _clutter_waves(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Plane waves of the clutter field: wave vectors (K, 2) in rad/px, angular harmonics (K,), phases (K,)."""
    g = np.random.default_rng(seed)
    wavelength = g.uniform(6.0, 30.0, _N_WAVES)
    direction = g.uniform(0.0, 2.0 * np.pi, _N_WAVES)
    k = (2.0 * np.pi / wavelength)[:, None] * np.stack([np.cos(direction), np.sin(direction)], axis=1)
    return k, g.integers(0, 4, _N_WAVES), g.uniform(0.0, 2.0 * np.pi, _N_WAVES)


def _clutter_spatial(seed: int, xy: np.ndarray) -> np.ndarray:
    """exp(i (k . xy + phase)) * sqrt(2 / K): (N, K)."""
    k, _, phase = _clutter_waves(seed)
    return np.exp(1j * (xy @ k.T + phase)) * np.sqrt(2.0 / _N_WAVES)


def _clutter_angular(seed: int, theta_deg: np.ndarray) -> np.ndarray:
    """exp(i m theta): (..., K)."""
    _, harmonic, _ = _clutter_waves(seed)
    return np.exp(1j * np.deg2rad(np.asarray(theta_deg, dtype=float))[..., None] * harmonic)


@dataclass(frozen=True)
class GaussianBumpObservation:
    time: float
    target_xy: tuple[float, float]
    """Target image position, pixels."""
    target_theta: float = 0.0
    """Target orientation relative to the template, degrees."""
    image_size: tuple[int, int] = (320, 240)
    homography: np.ndarray | None = None
    peak: float = 0.9
    sigma_px: float = 4.0
    sigma_theta_deg: float = 20.0
    occluded: bool = False
    clutter: float = 0.05
    clutter_seed: int = 0
    support_radius_px: float = 8.0

    def _valid(self, xy: np.ndarray) -> np.ndarray:
        w, h = self.image_size
        r = self.support_radius_px
        return (
            np.isfinite(xy).all(axis=1)
            & (xy[:, 0] - r >= 0) & (xy[:, 0] + r <= w - 1)
            & (xy[:, 1] - r >= 0) & (xy[:, 1] + r <= h - 1)
        )  # fmt: skip

    def _spatial_bump(self, xy: np.ndarray) -> np.ndarray:
        if self.occluded:
            return np.zeros(len(xy))
        d2 = np.sum((xy - np.asarray(self.target_xy, dtype=float)) ** 2, axis=1)
        return self.peak * np.exp(-d2 / (2.0 * self.sigma_px**2))

    def _angular_bump(self, theta: np.ndarray) -> np.ndarray:
        s_th = np.deg2rad(self.sigma_theta_deg)
        return np.exp((np.cos(np.deg2rad(theta - self.target_theta)) - 1.0) / s_th**2)

    def score_at(self, hyps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        hyps = np.asarray(hyps, dtype=float)
        xy, theta = hyps[:, :2], hyps[:, 2]
        valid = self._valid(xy)
        xy0 = np.nan_to_num(xy)
        waves = _clutter_spatial(self.clutter_seed, xy0) * _clutter_angular(self.clutter_seed, theta)
        score = self.clutter * waves.sum(axis=1).real + self._spatial_bump(xy0) * self._angular_bump(theta)
        return np.where(valid, np.clip(score, -1.0, 1.0), 0.0), valid

    def score_grid(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Same field as :meth:`score_at` at the 48 grid angles, computed separably (fast for big windows)."""
        xy = np.asarray(xy, dtype=float)
        valid = self._valid(xy)
        xy0 = np.nan_to_num(xy)
        spatial = _clutter_spatial(self.clutter_seed, xy0)  # (N, K)
        clutter = (spatial @ _clutter_angular(self.clutter_seed, GRID_ANGLES_DEG).T).real  # (N, 48)
        score = self.clutter * clutter + np.outer(self._spatial_bump(xy0), self._angular_bump(GRID_ANGLES_DEG))
        return np.where(valid[:, None], np.clip(score, -1.0, 1.0), 0.0), valid


@dataclass
class RecordingObservation:
    """Wraps an observation and records the shape of every ``score_at`` / ``score_grid`` call."""

    inner: object
    calls: list[tuple[str, tuple[int, ...]]] = field(default_factory=list)

    @property
    def time(self) -> float:
        return self.inner.time

    @property
    def homography(self):
        return self.inner.homography

    @property
    def image_size(self) -> tuple[int, int]:
        return self.inner.image_size

    def score_at(self, hyps):
        self.calls.append(("score_at", np.shape(hyps)))
        return self.inner.score_at(hyps)

    def score_grid(self, xy):
        self.calls.append(("score_grid", np.shape(xy), np.array(xy, dtype=float)))
        return self.inner.score_grid(xy)


@dataclass(frozen=True)
class SceneFrame:
    time: float
    world: np.ndarray
    """True world state [x, vx, y, vy]."""
    image_xy: np.ndarray
    """True image position, pixels."""
    theta: float
    """True orientation, degrees."""
    occluded: bool
    observation: GaussianBumpObservation


def constant_velocity_scene(
    n_frames: int,
    dt: float,
    start_xy: tuple[float, float],
    velocity_xy: tuple[float, float],
    *,
    theta0: float = 0.0,
    turn_rate_deg_s: float = 0.0,
    occluded_frames: range | set[int] | tuple[int, ...] = (),
    homography: np.ndarray | None = None,
    t0: float = 0.0,
    **bump_kwargs,
) -> list[SceneFrame]:
    """A target moving at constant world velocity, seen through ``homography`` (None: world = image)."""
    frames = []
    occ = set(occluded_frames)
    for i in range(n_frames):
        t = t0 + i * dt
        x = start_xy[0] + velocity_xy[0] * i * dt
        y = start_xy[1] + velocity_xy[1] * i * dt
        img = world_to_image(homography, np.array([x, y]))
        theta = float((theta0 + turn_rate_deg_s * i * dt + 180.0) % 360.0 - 180.0)
        obs = GaussianBumpObservation(
            time=t, target_xy=(float(img[0]), float(img[1])), target_theta=theta,
            homography=homography, occluded=i in occ, **bump_kwargs,
        )  # fmt: skip
        frames.append(SceneFrame(t, np.array([x, velocity_xy[0], y, velocity_xy[1]]), img, theta, i in occ, obs))
    return frames
