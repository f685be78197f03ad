"""What the multi-target filters share: targets, particles, gating, association, likelihood, estimates.

Particles of all targets live in one array (T, N, P, 4) -- population t holds target t's N
configurations, [x, y, vx, vy] per part -- with log weights (T, N). Each component draws from its
own generator, spawned from the tracker's seed: ``init``, ``motion``, ``genetic``, ``resample``,
``mcmc``. Same seed, same frames -> bit-identical estimates.
"""

from __future__ import annotations

import numpy as np

from ..tracking import resampling
from ..tracking._frames import FrameClock
from .appearance import PartEvidence, part_boxes
from .association import association_probabilities, attribute_ratio, jpda_probabilities, log_gauss2
from .body import body_model
from .config import MultiTargetConfig
from .depth import DepthOrder
from .gating import Measurements, gate_gamma, measure, units, update_measurement_cov
from .likelihood import AssociationTerms, TargetModels, log_likelihood
from .motion import predict, project_to_structure
from .occlusion import detection_probability, occluder_boxes
from .references import reference_histograms
from .state import InitError, MultiInit, MultiTrackState

RNG_STREAMS = ("init", "motion", "genetic", "resample", "mcmc")


def _rngs(seed: int | np.random.SeedSequence) -> dict[str, np.random.Generator]:
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(int(seed))
    return {name: np.random.default_rng(s) for name, s in zip(RNG_STREAMS, ss.spawn(len(RNG_STREAMS)))}


def normalise_rows(log_w: np.ndarray) -> np.ndarray:
    """Per-target log-sum-exp normalisation of (T, N) log weights."""
    return np.stack([resampling.normalise_log_weights(row) for row in log_w])


class MultiTargetFilter:
    """Base of :class:`~.epmcmc.EPMCMCFilter` and :class:`~.jpda_pf.JPDAParticleFilter`."""

    def __init__(self, config: MultiTargetConfig | None, init: MultiInit, first_evidence: PartEvidence,
                 seed: int | np.random.SeedSequence = 0) -> None:
        """``init``: initial part centres and heights; the reference histograms of every part are taken
        from ``first_evidence`` (the first frame) at those centres, from the pixels of each part's box
        that no target in front covers (:mod:`.references`)."""
        self.config = cfg = config if config is not None else MultiTargetConfig()
        self.body = body = body_model(cfg.n_parts)
        parts = np.asarray(init.parts, float)
        if parts.ndim != 3 or parts.shape[1:] != (body.n_parts, 2):
            raise InitError(f"initial parts have shape {parts.shape}; the {cfg.n_parts}-part model needs (T, {body.n_parts}, 2)")
        self.rngs = _rngs(seed)
        height = np.asarray(init.height, float)
        size = body.box[None] * height[:, None, None]
        if cfg.reference_min_visible is None:
            refs = first_evidence.histograms(part_boxes(parts, size).reshape(-1, 4)).reshape(len(parts), body.n_parts, -1)
        else:
            refs, _ = reference_histograms(first_evidence, parts, size, cfg.reference_min_visible)
        self.targets = TargetModels(body, height, refs)
        self._rest_pose = body.to_absolute(body.offset * height[:, None, None])  # (T, P, 2), root at 0
        self.depth = DepthOrder(len(parts), cfg.depth)
        t_n, n = len(parts), cfg.n_particles
        pos = parts[:, None] + cfg.init_spread * self.rngs["init"].standard_normal((t_n, n, body.n_parts, 2))
        pos = body.to_absolute(project_to_structure(body.to_relative(pos), body, height[:, None]))
        vel = np.zeros_like(pos)
        if cfg.init_speed_spread > 0:
            vel += cfg.init_speed_spread * self.rngs["init"].standard_normal((t_n, n, 1, 2))
        self.particles = np.concatenate([pos, vel], axis=-1)
        self.log_w = np.full((t_n, n), -np.log(n))
        self.clock = FrameClock(None)
        g = cfg.gate
        r0 = g.gate_size**2 / gate_gamma(g.p_gate)
        q_n = len(units(body.n_parts, g.level)[1])
        self.r_cov = np.broadcast_to(r0 * np.eye(2), (t_n, q_n, 2, 2)).copy()

    @property
    def n_targets(self) -> int:
        return self.particles.shape[0]

    @property
    def n_particles(self) -> int:
        return self.particles.shape[1]

    def weights(self) -> np.ndarray:
        """(T, N) normalised weights."""
        w = np.exp(normalise_rows(self.log_w))
        return w / w.sum(axis=1, keepdims=True)

    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean (T, P, 2) and covariance (T, P, 2, 2) of every part's position."""
        w = self.weights()
        pos = self.particles[..., :2]
        mean = np.einsum("tn,tnpd->tpd", w, pos)
        d = pos - mean[:, None]
        return mean, np.einsum("tn,tnpi,tnpj->tpij", w, d, d)

    def estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """Weighted-mean part centres (T, P, 2) and velocities (T, P, 2)."""
        m = np.einsum("tn,tnpd->tpd", self.weights(), self.particles)
        return m[..., :2], m[..., 2:]

    # ------------------------------------------------------------------ association

    def associate(self, evidence: PartEvidence) -> tuple[Measurements, AssociationTerms]:
        """Gate every target, find its measurements, compute the association probabilities."""
        cfg = self.config
        a = cfg.association_model
        mean, cov = self.moments()
        meas = measure(mean, cov, self.r_cov, self.targets.box_size, self.targets.references, evidence, cfg.gate,
                       self.match_parts)  # fmt: skip
        rest = self._rest_pose + mean[:, :1]
        if a.occlusion_floor is None and cfg.likelihood.hidden_similarity is None:
            front = self.depth.front(rest, self.targets.box_size)  # nothing reads it: no query for it
        else:
            front = self.depth.update(rest, self.targets.box_size, self.targets.references,
                                      self.body.max_dev <= cfg.depth.core_deviation, evidence)  # fmt: skip
        p_detect = self.detection_probability(mean, front)
        self._occluders = occluder_boxes(rest, self.targets.box_size, front)
        if cfg.association == "jpda":
            return meas, self._jpda_terms(meas, p_detect)
        lg = log_gauss2(meas.z - meas.centre[:, :, None], meas.s_cov[:, :, None])
        attr = attribute_ratio(meas.rho, a.attribute_lambda) if cfg.association == "elpda" else None
        beta = association_probabilities(lg, meas.valid, meas.volume, p_detect[:, None], cfg.gate.p_gate,
                                         a.clutter_density, attr)  # fmt: skip
        return meas, self._terms(meas.z, meas.valid, beta, meas.volume, meas.centre, cfg.association == "pda")

    @property
    def match_parts(self) -> np.ndarray | None:
        """(P,) the parts a structure-level measurement is matched on (``GateConfig.core_deviation``)."""
        dev = self.config.gate.core_deviation
        return None if dev is None else self.body.max_dev <= dev

    def detection_probability(self, parts: np.ndarray, front: np.ndarray | None = None) -> np.ndarray:
        """(T,) P_D of every target predicted at ``parts`` (T, P, 2): scaled by its visible share when
        ``occlusion_floor`` is set (:mod:`.occlusion`). Who hides whom is ``front`` ((T, T) bool, [t, u] = u
        in front of t), by default the running depth order (:mod:`.depth`) without new evidence. Both are
        judged on each body standing in its rest pose at the predicted root: the limbs' estimates are the
        noisiest (several px), and a lower leg a few px off would swap the depth order of two people on
        nearby lanes."""
        a = self.config.association_model
        if a.occlusion_floor is None:
            return np.full(self.n_targets, a.p_detect)
        rest = self._rest_pose + parts[:, :1]
        if front is None:
            front = self.depth.front(rest, self.targets.box_size)
        return detection_probability(a.p_detect, rest, self.targets.box_size, a.occlusion_floor, front)

    def _terms(self, z, valid, beta, volume, centre, combined: bool = False) -> AssociationTerms:
        g = self.config.gate
        if g.adaptive and g.r_in_likelihood:
            r = self.r_cov.copy()
        else:
            r = np.broadcast_to(self.config.association_model.measurement_sigma**2 * np.eye(2), self.r_cov.shape).copy()
        return AssociationTerms(z, valid, beta, volume, r,
                                self.config.gate.p_gate, units(self.body.n_parts, self.config.gate.level)[1],
                                centre, combined, self._occluders)  # fmt: skip

    def _jpda_terms(self, meas: Measurements, p_detect: np.ndarray) -> AssociationTerms:
        """JPDA: per unit, every target's measurements pooled into one set shared by all targets."""
        cfg = self.config
        a = cfg.association_model
        t_n, q_n, m_n = meas.valid.shape
        z = np.broadcast_to(meas.z.transpose(1, 0, 2, 3).reshape(1, q_n, t_n * m_n, 2), (t_n, q_n, t_n * m_n, 2))
        diff = z - meas.centre[:, :, None]
        gated = meas.valid.transpose(1, 0, 2).reshape(1, q_n, -1) & (np.sum(diff * diff, axis=-1) <= cfg.gate.gate_size**2)
        lg = log_gauss2(diff, meas.s_cov[:, :, None])
        beta = np.stack([jpda_probabilities(lg[:, q], gated[:, q], p_detect, cfg.gate.p_gate, a.clutter_density)
                         for q in range(q_n)], axis=1)  # fmt: skip
        return self._terms(np.ascontiguousarray(z), gated, beta, meas.volume, meas.centre)

    def log_likelihood(self, pos: np.ndarray, model: np.ndarray, evidence: PartEvidence,
                       terms: AssociationTerms | None) -> np.ndarray:
        """(K, N) log L of configurations (K, N, P, 2) under targets ``model`` (K,)."""
        return log_likelihood(pos, model, self.targets, evidence, terms, self.config.likelihood)

    def advance(self, frame_time: float) -> bool:
        """Move to ``frame_time``: sample the transition prior (True) or, on the first step, nothing (False)."""
        dt = self.clock.advance(frame_time)
        if dt > 0:
            self.particles = predict(self.particles, self.body, self.targets.height, dt, self.config.motion,
                                     self.rngs["motion"])  # fmt: skip
        return dt > 0

    def weigh(self, evidence: PartEvidence) -> tuple[Measurements, AssociationTerms, np.ndarray, np.ndarray,
                                                      np.ndarray, np.ndarray]:
        """Gate, associate and update the log weights by the likelihood; returns the measurements, the
        association terms, the log-likelihoods (T, N) of the particles, the normalised weights (T, N),
        the ESS (T,) and which populations fell to the resampling threshold (T,)."""
        meas, terms = self.associate(evidence)
        ll = self.log_likelihood(self.particles[..., :2], np.arange(self.n_targets), evidence, terms)
        self.log_w = normalise_rows(self.log_w + ll)
        w = self.weights()
        n_eff = np.array([resampling.ess(row) for row in w])
        return meas, terms, ll, w, n_eff, n_eff <= self.config.evolution.ess_threshold_fraction * self.n_particles

    def finish(self, frame_time: float, meas: Measurements, terms: AssociationTerms, n_eff: np.ndarray,
               moved: np.ndarray, acceptance: dict) -> MultiTrackState:
        """Estimate, re-estimate R (adaptive gates), and report."""
        parts, vel = self.estimate()
        if self.config.gate.adaptive:
            g = self.config.gate
            self.r_cov = update_measurement_cov(self.r_cov, meas, terms.beta, g.innovation_rate, g.min_sigma,
                                                g.gate_size / np.sqrt(gate_gamma(g.p_gate)))
        return MultiTrackState(
            time=float(frame_time), parts=parts, velocity=vel, n_eff=n_eff, moved=moved,
            gate_area=meas.volume.copy(), n_measurements=meas.valid.sum(axis=-1), acceptance=acceptance,
        )  # fmt: skip

    def step(self, frame_time: float, evidence: PartEvidence) -> MultiTrackState:  # pragma: no cover - abstract
        raise NotImplementedError
