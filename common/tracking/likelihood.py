"""Observation likelihoods p(Z_t | X_t, theta_t, V_t), evaluated at the Polar Matching score.

Both models return, for N hypotheses, an (N, 2) array of *log* likelihoods with
columns (V = 0, V = 1), each up to one constant common to every hypothesis and
both columns (so it cancels in the normalised weights). The RBPF marginalises
V over the columns; the SIR filter picks the column of each particle's sampled V.
Either model can be used by either filter.

* :class:`BetaRatioLikelihood` -- Pang et al. 2010 eqs. 15-19 (track-before-detect ratio).
* :class:`ExponentialScoreLikelihood` -- Nelson et al. 2008 eq. 15.
"""

from __future__ import annotations

from typing import Annotated, Literal, Protocol

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.special import betaln


class VisibilityLikelihood(Protocol):
    def log_likelihood(self, scores: np.ndarray) -> np.ndarray:
        """scores (N,) raw Polar Matching scores in [-1, 1] -> (N, 2) log-likelihoods, columns (V=0, V=1)."""
        ...


class BetaRatioLikelihood(BaseModel):
    """Pang 2010 track-before-detect likelihood ratio.

        Z = clip(max(0, score), eps, 1 - eps)                          (Pang §3: negative scores -> 0)
        p(Z_t | S_t, V_t = 1) ∝ Beta(Z | a1, b1) / Beta(Z | a0, b0)    (eq. 15)
        p(Z_t | S_t, V_t = 0) ∝ 1                                      (eq. 16)

    In the log domain,
        log ratio = (a1 - a0) log Z + (b1 - b0) log(1 - Z) - ln B(a1, b1) + ln B(a0, b0),
    which for the defaults is log(B(1,7)/B(5,7)) + 4 log Z = log(330 Z^4) (eq. 19).
    The clip keeps it finite at Z = 0 and Z = 1 whatever the shape parameters.
    """

    model_config = ConfigDict(frozen=True, extra="forbid", use_attribute_docstrings=True)

    kind: Literal["beta_ratio"] = "beta_ratio"
    a1: float = Field(5.0, gt=0.0)
    """alpha of the visible-target PDF Beta(Z|a1,b1). Pang 2010 eq. 18: 5."""
    b1: float = Field(7.0, gt=0.0)
    """beta of the visible-target PDF. Pang 2010 eq. 18: 7."""
    a0: float = Field(1.0, gt=0.0)
    """alpha of the background/occluded PDF Beta(Z|a0,b0). Pang 2010 eq. 18: 1."""
    b0: float = Field(7.0, gt=0.0)
    """beta of the background/occluded PDF. Pang 2010 eq. 18: 7."""
    eps: float = Field(1e-5, gt=0.0, lt=0.5)
    """Z is clipped to [eps, 1 - eps] before taking logs (ours, numerical). Scores are single-precision
    sums of about 1200 products, good to about 1e-6: below 1e-5 from 0 or 1 their differences are
    rounding. With b1 < b0 (the calibrated profiles) the ratio grows as (1 - Z)^(b1 - b0) near Z = 1, so
    an eps of 1e-9 let a rounding difference of 1e-7 between two identical particles on the template's
    own frame weigh 10^5 to 1 and collapse the cloud."""

    def clipped_score(self, scores: np.ndarray) -> np.ndarray:
        """Z = clip(max(0, score), eps, 1 - eps)."""
        return np.clip(np.maximum(np.asarray(scores, dtype=float), 0.0), self.eps, 1.0 - self.eps)

    def log_ratio(self, scores: np.ndarray) -> np.ndarray:
        """log [Beta(Z | a1, b1) / Beta(Z | a0, b0)] for each score."""
        z = self.clipped_score(scores)
        return (
            (self.a1 - self.a0) * np.log(z)
            + (self.b1 - self.b0) * np.log1p(-z)
            - betaln(self.a1, self.b1)
            + betaln(self.a0, self.b0)
        )

    def log_likelihood(self, scores: np.ndarray) -> np.ndarray:
        lr = self.log_ratio(scores)
        return np.stack([np.zeros_like(lr), lr], axis=-1)


def beta_by_moments(z: np.ndarray) -> tuple[float, float] | None:
    """(a, b) of the Beta with the mean and variance of the sample ``z`` (values in (0, 1)); None
    when no Beta has them (fewer than two values, none spread, or a variance a Beta cannot have)."""
    z = np.asarray(z, dtype=float).reshape(-1)
    if z.size < 2 or not np.all(np.isfinite(z)):
        return None
    m, v = float(z.mean()), float(z.var())
    if not (0.0 < m < 1.0) or not (0.0 < v < m * (1.0 - m)):
        return None
    c = m * (1.0 - m) / v - 1.0
    return m * c, (1.0 - m) * c


class ExponentialScoreLikelihood(BaseModel):
    """Nelson 2008 eq. 15:  p(z_t | X_t) = exp(k * Pi)  if V_t = 1,  exp(NV_c)  otherwise.

    Pi is the raw Polar Matching score (negative values are *not* floored, as in
    eq. 15). With ``nv_c_on_score_scale=True`` the occluded term is exp(k * NV_c)
    instead, i.e. NV_c is compared with the score itself (see the note on the field).
    """

    model_config = ConfigDict(frozen=True, extra="forbid", use_attribute_docstrings=True)

    kind: Literal["exponential"] = "exponential"
    k: float = 5.0
    """Likelihood scale k (per unit score). Nelson 2008 Table I: 5."""
    nv_c: float = 0.2
    """Likelihood constant NV_c when occluded. Nelson 2008 Table I: 0.2."""
    nv_c_on_score_scale: bool = True
    """True (default): the occluded log-likelihood is k * NV_c, so V=1 is favoured when score > NV_c, as
    the paper's prose requires ('NV_c ... higher than the background correlation score ... but much less
    than the self correlation score'). False: literally eq. 15 as printed, exp(NV_c), which favours V=1
    whenever score > NV_c / k = 0.04, i.e. almost everywhere."""

    def log_likelihood(self, scores: np.ndarray) -> np.ndarray:
        s = np.asarray(scores, dtype=float)
        occluded = self.k * self.nv_c if self.nv_c_on_score_scale else self.nv_c
        return np.stack([np.full_like(s, occluded), self.k * s], axis=-1)


LikelihoodModel = Annotated[BetaRatioLikelihood | ExponentialScoreLikelihood, Field(discriminator="kind")]
"""Either likelihood, as a config field (pydantic picks the class from ``kind``)."""
