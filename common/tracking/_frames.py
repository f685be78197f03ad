"""Bookkeeping shared by the trackers: elapsed time between frames and the latest homography."""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict

from . import resampling
from .camera import world_to_image
from .observation import inside_image_log_prior
from .state import InitialState, filter_state


def make_rng(seed: int | np.random.SeedSequence | np.random.Generator) -> np.random.Generator:
    """The tracker's own generator: a Generator is used as given (its state is then shared with the
    caller); an int or SeedSequence seeds a fresh PCG64."""
    if isinstance(seed, np.random.Generator):
        return seed
    return np.random.default_rng(seed)


class FrameClock:
    """Elapsed time T between successive steps (Pang §3: T is the frame interval, here from timestamps)."""

    def __init__(self, t0: float | None) -> None:
        self.last_time = t0
        self.homography: np.ndarray | None = None
        """The most recent observation's world->image homography (None: identity / none seen yet)."""

    def advance(self, frame_time: float) -> float:
        """Move to ``frame_time`` and return T = frame_time - previous time (0 on the first step of a
        tracker whose prior had no time). Time must not run backwards."""
        frame_time = float(frame_time)
        if not np.isfinite(frame_time):
            raise ValueError(f"frame time must be finite, got {frame_time}")
        dt = 0.0 if self.last_time is None else frame_time - self.last_time
        if dt < 0:
            raise ValueError(f"frame time {frame_time} is before the previous step's {self.last_time}")
        self.last_time = frame_time
        return dt

    def see(self, observation) -> np.ndarray | None:
        """Record and return the observation's homography (or the last one when ``observation`` is None)."""
        if observation is not None:
            h = observation.homography
            self.homography = None if h is None else np.asarray(h, dtype=float)
        return self.homography


ResamplingScheme = Literal["systematic", "stratified", "multinomial", "residual"]
"""The schemes of :data:`common.tracking.resampling.SCHEMES` a config may name."""


class ParticleFilterConfig(BaseModel):
    """What the particle filters' configs (RBPF, SIR) declare alike; each adds its own paper's
    settings. Every field is documented by the docstring under it."""

    model_config = ConfigDict(frozen=True, extra="forbid", use_attribute_docstrings=True)

    confine_to_image: bool = True
    """Pang 2010 §3 assumes the target always lies within the video frame: a particle whose image
    position is outside [0, W-1] x [0, H-1] gets zero weight (skipped for a frame where no particle
    inside carries weight, and on frames without an observation). False: such particles are only scored (0 there)."""


class ParticleFilter:
    """What the particle filters (RBPF, SIR) share: the cloud ``particles`` (N, 5) [x, vx, y, vy,
    theta] with normalised log weights ``log_w``, the weight update's normalisation and the
    resampling after the summary. Each filter keeps its own maths (prediction, likelihood) in
    ``step`` and names its per-particle arrays in :meth:`_take`."""

    config_class: type = ParticleFilterConfig
    """The filter's config model (its defaults stand in for ``config=None``)."""
    config: object
    particles: np.ndarray
    log_w: np.ndarray

    def __init__(self, config, initial: InitialState,
                 seed: int | np.random.SeedSequence | np.random.Generator = 0) -> None:
        """``config`` None means :attr:`config_class`'s defaults; ``initial`` is the prior (world
        frame), drawn with the filter's own generator (made from ``seed``) as by :meth:`restart`."""
        self.config = config if config is not None else self.config_class()
        self.rng = make_rng(seed)
        self.restart(initial)

    def restart(self, initial: InitialState) -> None:
        """Start again from the prior ``initial`` (a re-acquisition), drawn with this filter's own generator."""
        raise NotImplementedError

    @classmethod
    def from_image_box(cls, config, box_xyxy: tuple[float, float, float, float], first_observation,
                       seed: int | np.random.SeedSequence | np.random.Generator = 0, **initial_kwargs):
        """Start on the centre of an image box of the first frame (through its homography). The
        prior's time defaults to None, so the first ``step`` (normally on that same frame) does
        not predict."""
        initial = InitialState.from_image_box(box_xyxy, first_observation.homography, **initial_kwargs)
        return cls(config, initial, seed)

    @property
    def n_particles(self) -> int:
        return len(self.particles)

    @property
    def weights(self) -> np.ndarray:
        return resampling.weights_from_log(self.log_w)

    def _advance(self, frame_time: float, observation) -> tuple[float, np.ndarray]:
        """Move to ``frame_time``: predict over the elapsed T (none on a first step), take the
        observation's homography; returns T and the particles' image positions."""
        dt = self.clock.advance(frame_time)
        if dt > 0:
            self.predict(dt)
        h = self.clock.see(observation)
        return dt, world_to_image(h, self.particles[:, [0, 2]])

    def _finish(self, frame_time: float, observed: bool, image_xy: np.ndarray, p_visible: np.ndarray,
                log_lik: float, scores: np.ndarray | None):
        """The step's summary (:func:`common.tracking.state.filter_state`, before resampling), then
        the resampling it calls for."""
        w = self.weights
        state = filter_state(frame_time, observed, self.particles, image_xy, w, p_visible, log_lik, scores,
                             self.config.ess_threshold_fraction)
        self._resample_after(state, w)
        return state

    def _normalise(self, log_w: np.ndarray, image_xy: np.ndarray, observation) -> float:
        """Set the log weights to ``log_w`` (times the inside-the-image prior when the config
        confines the target to the image), normalised; returns the log of their sum, the step's
        log likelihood."""
        log_lik = None
        if self.config.confine_to_image:
            confined = log_w + inside_image_log_prior(image_xy, observation.image_size)
            # dropped for this frame when no particle inside the image carries weight (none inside,
            # or the inside ones all at -inf already): -inf - (-inf) would make every weight NaN
            lse = resampling.logsumexp(confined)
            if np.isfinite(lse):
                log_w, log_lik = confined, lse
        if log_lik is None:
            log_lik = resampling.logsumexp(log_w)
        self.log_w = log_w - log_lik
        return log_lik

    def _resample_after(self, state, w: np.ndarray) -> None:
        """Resample (the config's scheme, this filter's generator) when the summary ``state`` says
        so, after it was taken: weights equal again."""
        if state.resampled:
            idx = self._resample(w, self.rng)
            self._take(idx)
            self.log_w = np.full(self.n_particles, -np.log(self.n_particles))

    def _take(self, idx: np.ndarray) -> None:
        """Keep the particles ``idx`` (and each filter's per-particle arrays)."""
        self.particles = self.particles[idx]
