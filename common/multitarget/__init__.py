"""Multi-target articulated tracking (Bhaskar and Mihaylova 2011): EPMCMC with ELPDA, and baselines.

Small components:

* :mod:`.config` -- every parameter, documented (:class:`MultiTargetConfig`, :func:`method_config`).
* :mod:`.body` -- pictorial-structure body models with 1, 2, 6 and 10 parts.
* :mod:`.motion` -- constant velocity jointly with the structure.
* :mod:`.appearance` -- colour histograms; the :class:`PartEvidence` query interface and its
  in-process integral-histogram implementation.
* :mod:`.gating` -- validation gates (fixed, or re-estimated every frame) and measurements.
* :mod:`.association` -- PDA / ELPDA association probabilities (eqs. 9-12), the expected
  likelihood (eq. 13), JPDA.
* :mod:`.likelihood` -- appearance + association + pairwise structure, weighted sum.
* :mod:`.genetic` -- constrained crossover, mutation, exchange (eq. 8), MH acceptance.
* :mod:`.epmcmc`, :mod:`.jpda_pf` -- the filters, ``step(frame_time, evidence) -> MultiTrackState``.
* :mod:`.metrics` -- combined RMSE, OSPA, MOTA / IDF1, identity checks.
"""

from .appearance import HistogramEvidence, PartEvidence
from .body import BodyModel, body_model
from .config import METHODS, MultiTargetConfig, method_config
from .epmcmc import EPMCMCFilter
from .jpda_pf import JPDAParticleFilter
from .state import InitError, MultiInit, MultiTrackState, read_boxes


def make_filter(config: MultiTargetConfig, init: MultiInit, first_evidence: PartEvidence, seed: int = 0):
    """The filter named by ``config.filter``."""
    cls = EPMCMCFilter if config.filter == "epmcmc" else JPDAParticleFilter
    return cls(config, init, first_evidence, seed)


__all__ = [
    "BodyModel", "EPMCMCFilter", "HistogramEvidence", "InitError", "JPDAParticleFilter", "METHODS",
    "MultiInit", "MultiTargetConfig", "MultiTrackState", "PartEvidence", "body_model", "make_filter",
    "method_config", "read_boxes",
]  # fmt: skip
