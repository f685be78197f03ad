"""Single-target trackers for DTCWT Polar Matching scores (Pang et al. 2010; Nelson et al. 2008).

Small swappable components:

* :mod:`.resampling` -- resampling schemes ``(weights, rng) -> indices``, ESS, log-weight helpers.
* :mod:`.motion` -- near-constant-velocity model, orientation random walk, visibility Markov chain.
* :mod:`.likelihood` -- Pang's Beta likelihood ratio, Nelson's exponential score likelihood.
* :mod:`.observation` -- the :class:`FrameObservation` protocol the trackers consume.
* :mod:`.camera` -- world <-> image homographies.
* :mod:`.state` -- :class:`InitialState`, :class:`TrackState`, :class:`Estimate`.
* :mod:`.rbpf`, :mod:`.sir`, :mod:`.windowed_ml` -- the three trackers.
* :mod:`.testing` -- a synthetic Gaussian-bump observation.
"""

from .likelihood import BetaRatioLikelihood, ExponentialScoreLikelihood, LikelihoodModel
from .motion import NearConstantVelocity, OrientationRandomWalk, VisibilityMarkovChain, wrap_degrees
from .observation import GRID_ANGLES_DEG, FrameObservation
from .rbpf import RBPF, RaoBlackwellisedParticleFilter, RBPFConfig
from .sir import SIR, SIRConfig, SIRParticleFilter
from .state import Estimate, InitialState, TrackState
from .windowed_ml import WindowedMaximumLikelihood, WindowedML, WindowedMLConfig

__all__ = [
    "BetaRatioLikelihood",
    "Estimate",
    "ExponentialScoreLikelihood",
    "FrameObservation",
    "GRID_ANGLES_DEG",
    "InitialState",
    "LikelihoodModel",
    "NearConstantVelocity",
    "OrientationRandomWalk",
    "RBPF",
    "RBPFConfig",
    "RaoBlackwellisedParticleFilter",
    "SIR",
    "SIRConfig",
    "SIRParticleFilter",
    "TrackState",
    "VisibilityMarkovChain",
    "WindowedML",
    "WindowedMLConfig",
    "WindowedMaximumLikelihood",
    "wrap_degrees",
]
