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
from .state import MultiTrackState
from .tracker import MultiTargetFilter


class JPDAParticleFilter(MultiTargetFilter):
    """``step(frame_time, evidence) -> MultiTrackState``; one batched likelihood call per frame."""

    def step(self, frame_time: float, evidence: PartEvidence) -> MultiTrackState:
        self.advance(frame_time)
        meas, terms, _, w, n_eff, moved = self.weigh(evidence)
        state = self.finish(frame_time, meas, terms, n_eff, moved, {})
        scheme = resampling.get_scheme(self.config.resampling)
        for t in np.flatnonzero(moved):
            self.particles[t] = self.particles[t, scheme(w[t], self.rngs["resample"])]
            self.log_w[t] = -np.log(self.n_particles)
        return state
