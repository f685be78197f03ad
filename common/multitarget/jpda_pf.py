"""The JPDA-PF baseline: a generic particle filter with joint probabilistic data association.

Jaward, Mihaylova, Canagarajah and Bull (2006), the non-MCMC baseline of Bhaskar and Mihaylova
(2011, Table 1): per target a SIR filter over the same state, motion and likelihood as EPMCMC, but
no genetic moves and no MCMC; the measurements of all targets' fixed gates are pooled per part and
associated jointly (:func:`.association.jpda_probabilities`); particle weights by the expected
likelihood under the joint association probabilities; systematic resampling when the ESS falls
below the threshold.
"""

from __future__ import annotations

import numpy as np

from ..tracking import resampling
from .appearance import PartEvidence
from .motion import predict
from .state import MultiTrackState
from .tracker import MultiTargetFilter, normalise_rows


class JPDAParticleFilter(MultiTargetFilter):
    """``step(frame_time, evidence) -> MultiTrackState``; one batched likelihood call per frame."""

    def step(self, frame_time: float, evidence: PartEvidence) -> MultiTrackState:
        cfg = self.config
        dt = self.clock.advance(frame_time)
        t_n, n = self.log_w.shape
        if dt > 0:
            self.particles = predict(self.particles, self.body, self.targets.height, dt, cfg.motion, self.rngs["motion"])
        meas, terms = self.associate(evidence)
        ll = self.log_likelihood(self.particles[..., :2], np.arange(t_n), evidence, terms)
        self.log_w = normalise_rows(self.log_w + ll)
        w = self.weights()
        n_eff = np.array([resampling.ess(row) for row in w])
        moved = n_eff <= cfg.evolution.ess_threshold_fraction * n
        state = self.finish(frame_time, meas, terms, n_eff, moved, {})
        scheme = resampling.get_scheme(cfg.resampling)
        for t in np.flatnonzero(moved):
            self.particles[t] = self.particles[t, scheme(w[t], self.rngs["resample"])]
            self.log_w[t] = -np.log(n)
        return state
