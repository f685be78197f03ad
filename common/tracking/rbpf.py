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
                  (times r_p for both v when the observation carries an independent cue on the
                  position: the moving-target cue of real footage, common.single_target.motion_cue;
                  l_p(v) raised to the power ``temper``, 1 in the paper)
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
from pydantic import Field
from scipy.special import logsumexp

from . import resampling
from ._frames import FrameClock, ParticleFilter, ParticleFilterConfig, ResamplingScheme, make_rng
from .likelihood import BetaRatioLikelihood, LikelihoodModel
from .motion import (NearConstantVelocity, OrientationRandomWalk, VisibilityMarkovChain, jump_mixture_log_weights,
                     wrap_degrees)
from .observation import N_ANGLES, FrameObservation, ObservationUnavailable, cue_log_ratio, sanitise_scores
from .orientation_proposal import sample_orientation
from .state import InitialState, TrackState


class RBPFConfig(ParticleFilterConfig):
    """Parameters of the RBPF; defaults are Pang 2010 Table 1 (world units: m, or px without homography)."""

    n_particles: int = Field(200, ge=1)
    """N_p, number of particles. Pang 2010 Table 1: 200."""
    ess_threshold_fraction: float = Field(0.9, ge=0.0, le=1.0)
    """Resample when N_eff < fraction * N. Pang 2010 Table 1: N_thr = 180 with N_p = 200, i.e. 0.9.
    0 never resamples."""
    motion: NearConstantVelocity = Field(default_factory=NearConstantVelocity)
    """X_t dynamics (Pang eqs. 7-9)."""
    orientation: OrientationRandomWalk = Field(default_factory=OrientationRandomWalk)
    """theta_t dynamics (Pang eq. 10)."""
    visibility: VisibilityMarkovChain = Field(default_factory=VisibilityMarkovChain)
    """V_t Markov chain (Pang eq. 11)."""
    likelihood: LikelihoodModel = Field(default_factory=BetaRatioLikelihood)
    """p(Z_t | S_t, V_t) (Pang eqs. 15-19)."""
    temper: float = Field(1.0, gt=0.0, le=1.0)
    """Not in the paper: the exponent on the matcher's likelihood in the update, p(Z_t | S_t, V_t)^temper
    (a power, or tempered, likelihood); an independent cue's ratio r_p is not tempered. 1 (default)
    is the model as fitted, bit for bit. Below 1 each frame's scores count as that fraction of an
    independent observation: the correction where a likelihood fitted hypothesis by hypothesis meets
    errors that persist from frame to frame (the same ground, the same look-alike, the same mismatch
    of the template), which the product over frames would count again on every frame (Bissiri,
    Holmes and Walker 2016). The real-footage profile's is ``REAL_LIKELIHOOD_TEMPER`` (common.settings)."""
    resampling: ResamplingScheme = "systematic"
    """Resampling scheme (Pang 2010 §6: systematic)."""
    jump_probability: float = Field(0.0, ge=0.0, le=1.0)
    """Not in the paper: the motion model's jump component. Per step, a target that was visible
    (weighted by the particle's pi_p(V=1)) moves with this probability by an extra N(0, jump_std^2) per
    axis: a heavy-tailed NCV that lets the cloud leave a secondary peak of the score surface it locked
    onto (e.g. the front half of a car emerging from smoke, matched half a car length ahead). Occluded
    particles do not jump: a hidden target's cloud is not drawn to look-alike clutter. 0 (default) is
    Pang's model."""
    jump_rate_per_s: float | None = Field(None, ge=0.0)
    """If set, replaces ``jump_probability`` by a rate: a step of dt seconds jumps with probability
    1 - exp(-rate dt), the same model whatever the frame rate."""
    jump_std: float = Field(2.0, gt=0.0)
    """Std of a jump per axis, world units (m, or px without homography)."""
    jump_candidates: int = Field(0, ge=0)
    """How many of each particle's K candidates are drawn from the jump component (the rest from the
    plain NCV), every candidate weighted by prior / proposal density: jumps are explored at K_j/K per
    candidate however rare the model says they are. 0: jumps are sampled from the prior itself."""
    candidates: int = Field(1, ge=1)
    """Not in the paper: K > 1 makes each particle propose K candidates from its transition (all N*K
    scored in the one batched query) and keep one, chosen in proportion to its weight, the particle
    taking the sum of its candidates' weights (an exact importance sampler: N*K particles followed by
    resampling within each particle's group). The filter still carries N particles; the scored
    hypotheses per frame are N*K. 1 (default) is Pang's filter."""
    orientation_proposal: Literal["prior", "grid"] = "prior"
    """'prior' (Pang): theta_t drawn from the random walk, each particle scored at that angle (one
    score_at query). 'grid' (ours): one score_grid query (48 angles per particle, the same cost) gives
    each particle's exact score curve; theta is integrated out on the random walk's nodes and sampled
    from its posterior (common.tracking.orientation_proposal), so a particle in the right place is not
    judged by an orientation a few degrees off."""


class RaoBlackwellisedParticleFilter(ParticleFilter):
    """Pang 2010 RBPF. ``step(frame_time, observation)`` -> :class:`TrackState`.

    All randomness comes from ``self.rng``, made from ``seed`` (same inputs + seed -> bit-identical output).
    Per step with an observation: exactly one ``observation.score_at`` call with all N particles.
    ``RBPF(config, initial, seed)``: ``config`` None means :class:`RBPFConfig` defaults; ``initial``
    is the prior (world frame).
    """

    config_class = RBPFConfig

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

    def restart(self, initial: InitialState) -> None:
        """Start again from the prior ``initial`` (a re-acquisition), drawn with this filter's own
        generator: the next ``step`` is then the first of a fresh track (no prediction if
        ``initial.time`` is None)."""
        particles = initial.sample_particles(self.config.n_particles, self.rng)
        self._setup(particles, np.full(len(particles), initial.p_visible), None, initial.time)

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
        self._n = n

    def _jump_probability(self, dt: float) -> float:
        """The probability that a visible target jumps in a step of ``dt`` seconds."""
        cfg = self.config
        if cfg.jump_rate_per_s is None:
            return cfg.jump_probability
        return float(-np.expm1(-cfg.jump_rate_per_s * max(dt, 0.0)))

    def _jump(self, parents: np.ndarray, dt: float) -> None:
        """Add the jump component to the sampled positions and weight each candidate by
        p(x' | x) / q(x' | x) (:func:`common.tracking.motion.jump_mixture_log_weights`).
        Draws M uniforms (prior sampling) or nothing, then 2M normals."""
        cfg = self.config
        m = self.n_particles
        eps = self._jump_probability(dt) * np.exp(self.log_pv[:, 1])  # pi_{t-1,p}(1): only visible targets jump
        if cfg.jump_candidates == 0:
            jumped = self.rng.uniform(size=m) < eps
        else:
            k = m // self._n
            jumped = np.tile(np.arange(k) >= k - min(cfg.jump_candidates, k), self._n)
        offsets = self.rng.normal(0.0, cfg.jump_std, size=(m, 2))
        self.particles[jumped, 0] += offsets[jumped, 0]
        self.particles[jumped, 2] += offsets[jumped, 1]
        if cfg.jump_candidates > 0:
            residual = self.particles[:, :4] - cfg.motion.predict_mean(parents, dt)
            self.log_w = self.log_w + jump_mixture_log_weights(residual, cfg.motion.covariance(dt), cfg.jump_std,
                                                               eps, float(jumped.mean()))
            self.log_w = resampling.normalise_log_weights(self.log_w)

    def _keep_one_per_group(self) -> np.ndarray:
        """Collapse the N groups of K candidates: keep one per group, drawn in proportion to the
        candidates' weights, with the group's total weight. N uniforms. Returns the kept rows."""
        k = self.n_particles // self._n
        lw = self.log_w.reshape(self._n, k)
        group = logsumexp(lw, axis=1)
        keep = np.arange(self._n) * k + resampling.draw_per_row(lw, group, self.rng)
        self.particles = self.particles[keep]
        self.log_pv = self.log_pv[keep]
        self.log_w = group
        return keep

    @property
    def p_visible_per_particle(self) -> np.ndarray:
        """pi_p(1) = p(V_t = 1 | S^N_{1:t,p}, Z_1:t)."""
        return np.exp(self.log_pv[:, 1])

    def predict(self, dt: float) -> None:
        """Propagate every particle through p(S^N_t | S^N_{t-1}) and pi through the Markov chain.

        Draw order (fixed, for reproducibility): 4M normals (X), M normals (theta; not with the
        'grid' orientation proposal, which draws theta in the update), and with
        a jump component (``jump_probability`` or ``jump_rate_per_s`` > 0) M uniforms (unless jump
        candidates are used) and 2M normals (jumps); M = N * candidates (kept in groups of K until
        :meth:`_keep_one_per_group`).
        """
        cfg = self.config
        if cfg.candidates > 1:  # N groups of K candidates, each with weight w_p / K
            k = cfg.candidates
            self.particles = np.repeat(self.particles, k, axis=0)
            self.log_pv = np.repeat(self.log_pv, k, axis=0)
            self.log_w = np.repeat(self.log_w, k) - np.log(k)
        parents = self.particles[:, :4].copy()
        self.particles[:, :4] = cfg.motion.sample(parents, dt, self.rng)
        if cfg.orientation_proposal == "prior":
            self.particles[:, 4] = cfg.orientation.sample(self.particles[:, 4], dt, self.rng)
        self._theta_sigma = float(np.sqrt(cfg.orientation.variance(dt)))
        if self._jump_probability(1.0) > 0:  # a jump component at all (whatever this step's dt)
            self._jump(parents, dt)
        self.log_pv = cfg.visibility.predict_log(self.log_pv)

    def step(self, frame_time: float, observation: FrameObservation | None) -> TrackState:
        cfg = self.config
        self._theta_sigma = 0.0  # predict sets it
        dt, image_xy = self._advance(frame_time, observation)

        log_lik = 0.0
        scored = None
        if observation is not None:
            try:
                scored = self._score(observation, image_xy)
            except ObservationUnavailable:
                observation = None  # the detector did not answer: predict only
        if scored is None and cfg.orientation_proposal == "grid" and dt > 0:
            # no observation (none given, or the detector did not answer): theta from its prior,
            # as the 'prior' proposal would have drawn it in predict
            self.particles[:, 4] = cfg.orientation.sample(self.particles[:, 4], dt, self.rng)
        if scored is not None:
            scores, joint = scored  # joint: log l_p(v) + log pi^-_p(v)
            log_m = np.logaddexp(joint[:, 0], joint[:, 1])  # log m_p
            self.log_pv = joint - log_m[:, None]  # log pi_p(v)
            # log w_{t-1} is normalised, so the log likelihood is log sum_p w_{t-1,p} m_p
            log_lik = self._normalise(self.log_w + log_m, image_xy, observation)
        if self.n_particles > self._n:
            keep = self._keep_one_per_group()
            image_xy = image_xy[keep]
            if scored is not None:
                scores = scores[keep]

        return self._finish(frame_time, observation is not None, image_xy, self.p_visible_per_particle, log_lik,
                            scores if scored is not None else None)

    def _take(self, idx: np.ndarray) -> None:
        self.particles = self.particles[idx]
        self.log_pv = self.log_pv[idx]

    def _log_likelihood(self, scores: np.ndarray) -> np.ndarray:
        """log p(Z | S, V = v)^temper for each score, (..., 2) with columns v = 0, 1."""
        return self.config.temper * self.config.likelihood.log_likelihood(scores)

    def _score(self, observation: FrameObservation, image_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One batched query: scores (N,) at the particles' (sampled) orientation and the joint
        log l_p(v) + log pi^-_p(v) (N, 2) there; with the 'grid' proposal, the log m_p it returns
        integrates theta over its random-walk step (see orientation_proposal)."""
        cfg = self.config
        n = self.n_particles
        log_pv = self.log_pv  # log pi^-_p(v), times an independent cue's r_p (both v: see the docstring)
        cue = cue_log_ratio(observation, image_xy)
        if cue is not None:
            log_pv = log_pv + cue[:, None]
        if cfg.orientation_proposal == "prior":
            hyps = np.column_stack([image_xy, self.particles[:, 4]])
            scores, _ = sanitise_scores(*observation.score_at(hyps), n)
            return scores, log_pv + self._log_likelihood(scores)
        grid, valid = observation.score_grid(image_xy)
        grid = np.asarray(grid, float)
        valid = np.asarray(valid, bool).reshape(-1)
        if grid.shape != (n, N_ANGLES) or valid.shape != (n,):
            raise ValueError(f"score_grid returned shapes {grid.shape}, {valid.shape}; expected ({n}, {N_ANGLES})")
        ok = valid & np.all(np.isfinite(grid), axis=1)
        grid = np.where(ok[:, None], np.clip(grid, -1.0, 1.0), 0.0)
        theta, log_m, scores, joint = sample_orientation(grid, self.particles[:, 4], self._theta_sigma,
                                                         log_pv, self._log_likelihood, self.rng)
        self.particles[:, 4] = wrap_degrees(theta)
        # the weight update below takes logaddexp over joint; give it the theta-marginal instead
        corr = log_m - np.logaddexp(joint[:, 0], joint[:, 1])
        return scores, joint + corr[:, None]


RBPF = RaoBlackwellisedParticleFilter
