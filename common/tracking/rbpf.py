"""Pang et al. (2010) Rao-Blackwellised particle filter (§7 and appendix).

State S_t = [X_t, theta_t, V_t] with X_t = [x, vx, y, vy] (world) and the
visibility V_t in {0, 1}. The non-linear part S^N_t = {X_t, theta_t} is
carried by N particles; the visibility is marginalised exactly, each particle p
carrying the discrete distribution pi_p(v) = p(V_t = v | S^N_{1:t,p}, Z_1:t).

One step, from t-1 to t with T = t - (t-1) from the timestamps (prior proposal):

    X_{t,p}     ~ N(F X_{t-1,p}, Q_w)                              (eqs. 7-9)
    theta_{t,p} ~ N(theta_{t-1,p}, q_theta)                        (eq. 10)
    pi^-_p(j)   = sum_i A[i, j] pi_p(i)                            (eq. 25 / A.3)
    l_p(v)      = p(Z_t | S^N_{t,p}, V_t = v)                      (eqs. 15-16, or Nelson eq. 15)
    m_p         = sum_v l_p(v) pi^-_p(v)                           (eq. 25 / A.4)
    pi_p(v)     = l_p(v) pi^-_p(v) / m_p                           (A.3)
    w_{t,p}     ∝ w_{t-1,p} m_p                                    (eq. 24 with q = prior)
    p(V_t=1 | Z_1:t) = sum_p w_{t,p} pi_p(1)                       (A.5)

then systematic resampling when N_eff = 1 / sum w^2 < N_thr (§6). Everything is
in the log domain: log w, log pi.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from . import resampling
from ._frames import FrameClock, make_rng
from .camera import world_to_image
from .likelihood import BetaRatioLikelihood, LikelihoodModel
from .motion import NearConstantVelocity, OrientationRandomWalk, VisibilityMarkovChain
from .observation import FrameObservation, ObservationUnavailable, inside_image_log_prior, sanitise_scores
from .state import InitialState, TrackState, summarise_particles


class RBPFConfig(BaseModel):
    """Parameters of the RBPF; defaults are Pang 2010 Table 1 (world units: m, or px without homography)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    n_particles: int = Field(200, ge=1, description="N_p, number of particles. Pang 2010 Table 1: 200.")
    ess_threshold_fraction: float = Field(
        0.9,
        ge=0.0,
        le=1.0,
        description="Resample when N_eff < fraction * N. Pang 2010 Table 1: N_thr = 180 with N_p = 200, i.e. 0.9. "
        "0 never resamples.",
    )
    motion: NearConstantVelocity = Field(
        default_factory=NearConstantVelocity, description="X_t dynamics (Pang eqs. 7-9)."
    )
    orientation: OrientationRandomWalk = Field(
        default_factory=OrientationRandomWalk, description="theta_t dynamics (Pang eq. 10)."
    )
    visibility: VisibilityMarkovChain = Field(
        default_factory=VisibilityMarkovChain, description="V_t Markov chain (Pang eq. 11)."
    )
    likelihood: LikelihoodModel = Field(
        default_factory=BetaRatioLikelihood, description="p(Z_t | S_t, V_t) (Pang eqs. 15-19)."
    )
    confine_to_image: bool = Field(
        True,
        description="Pang 2010 §3 assumes the target always lies within the video frame: a particle whose image "
        "position is outside [0, W-1] x [0, H-1] gets zero weight (skipped for a frame where every particle is "
        "outside, and on frames without an observation). False: such particles are only scored (0 there).",
    )
    resampling: Literal["systematic", "stratified", "multinomial", "residual"] = Field(
        "systematic", description="Resampling scheme (Pang 2010 §6: systematic)."
    )
    jump_probability: float = Field(
        0.0, ge=0.0, le=1.0,
        description="Not in the paper: per step, a particle believed visible (probability pi_p(V=1)) jumps "
        "with probability jump_probability * pi_p(1) by N(0, jump_std^2) in position. A heavy-tailed motion "
        "model that lets a cloud locked on a secondary peak of the score surface (e.g. a half-visible car "
        "emerging from smoke) find the true one; occluded particles do not jump, so the cloud does not "
        "spread faster during an occlusion. 0 (default) is Pang's model.",
    )
    jump_std: float = Field(2.0, gt=0.0, description="Std of a jump, world units (m, or px without homography).")


class RaoBlackwellisedParticleFilter:
    """Pang 2010 RBPF. ``step(frame_time, observation)`` -> :class:`TrackState`.

    All randomness comes from ``self.rng``, made from ``seed`` (same inputs + seed -> bit-identical output).
    Per step with an observation: exactly one ``observation.score_at`` call with all N particles.
    """

    def __init__(
        self,
        config: RBPFConfig | None,
        initial: InitialState,
        seed: int | np.random.SeedSequence | np.random.Generator = 0,
    ) -> None:
        """``config`` None means :class:`RBPFConfig` defaults; ``initial`` is the prior (world frame)."""
        self.config = config if config is not None else RBPFConfig()
        self.rng = make_rng(seed)
        particles = initial.sample_particles(self.config.n_particles, self.rng)
        self._setup(particles, np.full(len(particles), initial.p_visible), None, initial.time)

    @classmethod
    def from_image_box(
        cls,
        config: RBPFConfig | None,
        box_xyxy: tuple[float, float, float, float],
        first_observation: FrameObservation,
        seed: int | np.random.SeedSequence | np.random.Generator = 0,
        **initial_kwargs,
    ) -> "RaoBlackwellisedParticleFilter":
        """Start on the centre of an image box of the first frame (through its homography).

        The prior's time defaults to None, so the first ``step`` (normally on that same frame) does not predict.
        """
        initial = InitialState.from_image_box(box_xyxy, first_observation.homography, **initial_kwargs)
        return cls(config, initial, seed)

    @classmethod
    def from_particles(
        cls,
        config: RBPFConfig | None,
        particles: np.ndarray,
        p_visible: np.ndarray | float = 1.0,
        log_weights: np.ndarray | None = None,
        time: float | None = None,
        seed: int | np.random.SeedSequence | np.random.Generator = 0,
    ) -> "RaoBlackwellisedParticleFilter":
        """Start from explicit particles (M, 5) [x, vx, y, vy, theta], per-particle p(V=1) and
        (unnormalised) log weights. M need not equal ``config.n_particles``."""
        self = cls.__new__(cls)
        self.config = config if config is not None else RBPFConfig()
        self.rng = make_rng(seed)
        particles = np.array(particles, dtype=float)
        if particles.ndim != 2 or particles.shape[1] != 5:
            raise ValueError(f"particles must be (M, 5), got {particles.shape}")
        p_vis = np.broadcast_to(np.asarray(p_visible, dtype=float), (len(particles),))
        self._setup(particles, p_vis, log_weights, time)
        return self

    def _setup(self, particles, p_visible, log_weights, t0) -> None:
        n = len(particles)
        self.particles = np.array(particles, dtype=float)
        p_visible = np.clip(np.asarray(p_visible, dtype=float), 0.0, 1.0)
        with np.errstate(divide="ignore"):
            # log pi_p(v), columns v = 0 (occluded), 1 (visible)
            self.log_pv = np.log(np.stack([1.0 - p_visible, p_visible], axis=1))
        lw = np.zeros(n) if log_weights is None else np.asarray(log_weights, dtype=float)
        self.log_w = resampling.normalise_log_weights(lw)
        self.clock = FrameClock(t0)
        self._resample = resampling.get_scheme(self.config.resampling)

    @property
    def n_particles(self) -> int:
        return len(self.particles)

    @property
    def weights(self) -> np.ndarray:
        return resampling.weights_from_log(self.log_w)

    @property
    def p_visible_per_particle(self) -> np.ndarray:
        """pi_p(1) = p(V_t = 1 | S^N_{1:t,p}, Z_1:t)."""
        return np.exp(self.log_pv[:, 1])

    def predict(self, dt: float) -> None:
        """Propagate every particle through p(S^N_t | S^N_{t-1}) and pi through the Markov chain.

        Draw order (fixed, for reproducibility): 4N normals (X), N normals (theta), and with
        ``jump_probability > 0`` N uniforms and 2N normals (jumps).
        """
        cfg = self.config
        self.particles[:, :4] = cfg.motion.sample(self.particles[:, :4], dt, self.rng)
        self.particles[:, 4] = cfg.orientation.sample(self.particles[:, 4], dt, self.rng)
        if cfg.jump_probability > 0:
            n = self.n_particles
            jump = self.rng.uniform(size=n) < cfg.jump_probability * np.exp(self.log_pv[:, 1])
            offsets = self.rng.normal(0.0, cfg.jump_std, size=(n, 2))
            self.particles[jump, 0] += offsets[jump, 0]
            self.particles[jump, 2] += offsets[jump, 1]
        self.log_pv = cfg.visibility.predict_log(self.log_pv)

    def step(self, frame_time: float, observation: FrameObservation | None) -> TrackState:
        cfg = self.config
        dt = self.clock.advance(frame_time)
        if dt > 0:
            self.predict(dt)
        h = self.clock.see(observation)
        image_xy = world_to_image(h, self.particles[:, [0, 2]])

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
            joint = self.log_pv + cfg.likelihood.log_likelihood(scores)  # log l_p(v) + log pi^-_p(v)
            log_m = np.logaddexp(joint[:, 0], joint[:, 1])  # log m_p
            self.log_pv = joint - log_m[:, None]  # log pi_p(v)
            log_w = self.log_w + log_m  # log w_{t-1} is normalised, so ...
            if cfg.confine_to_image:
                log_w = log_w + inside_image_log_prior(image_xy, observation.image_size)
            log_lik = resampling.logsumexp(log_w)  # ... this is log sum_p w_{t-1,p} m_p
            self.log_w = log_w - log_lik

        w = self.weights
        n_eff = resampling.ess(w)
        pi1 = self.p_visible_per_particle
        p_visible = float(np.clip(w @ pi1, 0.0, 1.0))
        i_map, map_est, mmse_est = summarise_particles(self.particles, image_xy, w)
        do_resample = n_eff < cfg.ess_threshold_fraction * self.n_particles
        state = TrackState(
            time=float(frame_time),
            observed=observation is not None,
            map_estimate=map_est,
            mmse_estimate=mmse_est,
            p_visible=p_visible,
            n_eff=n_eff,
            speed=map_est.speed,
            orientation=map_est.theta,
            particles=self.particles,
            particles_image=image_xy,
            particle_visibility=pi1,
            weights=w,
            resampled=do_resample,
            log_likelihood=float(log_lik),
            score=None if observation is None else float(scores[i_map]),
        )
        if do_resample:
            idx = self._resample(w, self.rng)
            self.particles = self.particles[idx]
            self.log_pv = self.log_pv[idx]
            self.log_w = np.full(self.n_particles, -np.log(self.n_particles))
        return state


RBPF = RaoBlackwellisedParticleFilter
