"""Nelson et al. (2008) SIR particle filter (§III-B..E).

Same state and dynamics as the RBPF, but the visibility V_t is *sampled* per
particle from the Markov chain instead of being marginalised:

    X_{t,p} ~ N(F X_{t-1,p}, Q_w),  theta_{t,p} ~ N(theta_{t-1,p}, S_theta),  V_{t,p} ~ p(V_t | V_{t-1,p})
    w_{t,p} ∝ w_{t-1,p} p(z_t | X_{t,p})                                       (eq. 18, prior proposal)
    p(z_t | X_t) = exp(k * Pi(H(x_t, y_t), theta_t)) if V_t = 1, exp(NV_c) otherwise   (eq. 15)

with resampling (systematic) when N_eff < N_thr and p(V_t = 1 | Z_1:t) ≈ sum_p w_{t,p} V_{t,p}.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from . import resampling
from ._frames import FrameClock, ParticleFilter, ParticleFilterConfig, ResamplingScheme, make_rng
from .likelihood import ExponentialScoreLikelihood, LikelihoodModel
from .motion import NearConstantVelocity, OrientationRandomWalk, VisibilityMarkovChain
from .observation import FrameObservation, ObservationUnavailable, cue_log_ratio, sanitise_scores
from .state import InitialState, TrackState


class SIRConfig(ParticleFilterConfig):
    """Parameters of the SIR filter; defaults are Nelson 2008 Table I where it gives them."""

    n_particles: int = Field(300, ge=1)
    """Number of particles. Nelson 2008 Table I: 300."""
    ess_threshold_fraction: float = Field(0.9, ge=0.0, le=1.0)
    """Resample when N_eff < fraction * N. Nelson 2008 §III-E resamples below an unstated N_thr; 0.9
    is Pang 2010 Table 1's 180/200. 1.0 resamples after every informative frame (classic SIR)."""
    motion: NearConstantVelocity = Field(default_factory=lambda: NearConstantVelocity(q_x=1600.0, q_y=1600.0))
    """S_t dynamics (Nelson eqs. 10-12). Nelson 2008 Table I: S_x = S_y = 1600 (units unstated; taken
    as world-units^2/s^3)."""
    orientation: OrientationRandomWalk = Field(default_factory=OrientationRandomWalk)
    """theta random walk. Nelson 2008 gives no S_theta; default Pang 2010 Table 1, 16 deg^2 per
    frame."""
    visibility: VisibilityMarkovChain = Field(default_factory=lambda: VisibilityMarkovChain(p_nv=0.1, p_v=0.25))
    """V_t Markov chain (Nelson eqs. 13-14). Nelson 2008 Table I: P_NV = 0.1, P_V = 0.25."""
    likelihood: LikelihoodModel = Field(default_factory=ExponentialScoreLikelihood)
    """p(z_t | X_t) (Nelson eq. 15; Table I: k = 5, NV_c = 0.2)."""
    resampling: ResamplingScheme = "systematic"
    """Resampling scheme (Nelson 2008 §III-E: systematic)."""


class SIRParticleFilter(ParticleFilter):
    """Nelson 2008 SIR filter with sampled visibility. ``step(frame_time, observation)`` -> :class:`TrackState`.

    All randomness comes from ``self.rng``, made from ``seed``. One ``score_at`` call per observed frame.
    ``SIR(config, initial, seed)``: ``config`` None means :class:`SIRConfig` defaults.
    """

    config_class = SIRConfig

    def restart(self, initial: InitialState) -> None:
        """Start again from the prior ``initial`` (a re-acquisition), drawn with this filter's own generator."""
        n = self.config.n_particles
        self.particles = initial.sample_particles(n, self.rng)
        self.visible = (self.rng.random(n) < initial.p_visible).astype(np.int8)  # V_0 ~ Bernoulli(p_visible)
        self.log_w = np.full(n, -np.log(n))
        self.clock = FrameClock(initial.time)
        self._resample = resampling.get_scheme(self.config.resampling)

    def predict(self, dt: float) -> None:
        """Draw order: 4N normals (X), N normals (theta), N uniforms (V)."""
        cfg = self.config
        self.particles[:, :4] = cfg.motion.sample(self.particles[:, :4], dt, self.rng)
        self.particles[:, 4] = cfg.orientation.sample(self.particles[:, 4], dt, self.rng)
        self.visible = cfg.visibility.sample(self.visible, self.rng)

    def step(self, frame_time: float, observation: FrameObservation | None) -> TrackState:
        cfg = self.config
        _dt, image_xy = self._advance(frame_time, observation)

        log_lik = 0.0
        scored = None
        if observation is not None:
            hyps = np.column_stack([image_xy, self.particles[:, 4]])
            try:
                scored = sanitise_scores(*observation.score_at(hyps), self.n_particles)
            except ObservationUnavailable:
                observation = None  # the detector did not answer: predict only
        if scored is not None:
            scores, _valid = scored
            ll = cfg.likelihood.log_likelihood(scores)  # (N, 2), columns V = 0, 1
            cue = cue_log_ratio(observation, image_xy)  # an independent cue on the position (both V)
            if cue is not None:
                ll = ll + cue[:, None]
            log_lik = self._normalise(self.log_w + ll[np.arange(self.n_particles), self.visible], image_xy, observation)

        return self._finish(frame_time, observation is not None, image_xy, self.visible.astype(float), log_lik,
                            scores if scored is not None else None)

    def _take(self, idx: np.ndarray) -> None:
        self.particles = self.particles[idx]
        self.visible = self.visible[idx]


SIR = SIRParticleFilter
