"""What the trackers consume: one :class:`FrameObservation` per video frame.

A filter never sees pixels, only the detector's score function for that frame
(Pang 2010 §5: "it is not necessary to compute the Polar Matching output of the
entire video frame"). Each particle filter makes exactly one batched
:meth:`FrameObservation.score_at` call per frame with all N hypotheses; the
windowed-ML baseline makes one :meth:`FrameObservation.score_grid` call.

``step(t, None)`` on a filter means "no observation for this frame" (the
detector had nothing): the filter predicts only.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

N_ANGLES = 48
"""Polar Matching angles per position: 0, 7.5, ..., 352.5 degrees (Pang §2)."""

GRID_ANGLES_DEG = np.arange(N_ANGLES) * (360.0 / N_ANGLES)
"""The angles (degrees) of the columns of :meth:`FrameObservation.score_grid`."""


@runtime_checkable
class FrameObservation(Protocol):
    time: float
    """Capture time, seconds."""
    homography: np.ndarray | None
    """3x3 world (ground plane) -> image pixels; None means the image IS the world frame (identity)."""
    image_size: tuple[int, int]
    """(width, height) in pixels."""

    def score_at(self, hyps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """hyps (N, 3): image x, y (pixels) and theta (degrees, anticlockwise as displayed,
        relative to the template). Returns scores (N,) float in [-1, 1] and valid (N,) bool
        (False where the hypothesis' support leaves the frame; score 0 there)."""
        ...

    def score_grid(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """xy (N, 2) -> scores (N, 48) at angles 0, 7.5, ..., 352.5 degrees, and valid (N,)."""
        ...


class CuedObservation:
    """A :class:`FrameObservation` with an independent cue on the target's position: ``cue(image_xy)
    -> (N,)`` log likelihood ratios for the target at those image points, which the particle
    filters add to each particle's log likelihood under both visibility hypotheses (it moves
    weight between places, not between "seen" and "hidden"; :func:`cue_log_ratio`). Everything
    else is ``base``'s."""

    def __init__(self, base, cue):
        self.base = base
        self._cue = cue

    def __getattr__(self, name):
        return getattr(self.base, name)

    def cue_log_ratio(self, image_xy: np.ndarray) -> np.ndarray:
        return self._cue(image_xy)


def cue_log_ratio(observation, image_xy: np.ndarray) -> np.ndarray | None:
    """The observation's independent cue at ``image_xy`` (N, 2): (N,) log ratios to add to each
    particle's log likelihood (non-finite values count as 0, no evidence), or None when it has no cue."""
    f = getattr(observation, "cue_log_ratio", None)
    if f is None:
        return None
    lr = np.asarray(f(image_xy), dtype=float).reshape(-1)
    if lr.shape != (len(image_xy),):
        raise ValueError(f"cue returned shape {lr.shape}; expected ({len(image_xy)},)")
    return np.where(np.isfinite(lr), lr, 0.0)


class ObservationUnavailable(Exception):
    """Raised by ``score_at`` / ``score_grid`` when the detector cannot answer (no reply before the
    timeout, the frame unknown to it, ...). A filter then treats the frame as unobserved,
    exactly like ``step(t, None)``: a missing reply is no observation, not a crash."""


def sanitise_scores(scores: np.ndarray, valid: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Check shapes and enforce the protocol: score 0 where invalid or non-finite, clipped to [-1, 1]."""
    scores = np.asarray(scores, dtype=float).reshape(-1)
    valid = np.asarray(valid, dtype=bool).reshape(-1)
    if scores.shape != (n,) or valid.shape != (n,):
        raise ValueError(f"score_at returned shapes {scores.shape}, {valid.shape}; expected ({n},)")
    valid = valid & np.isfinite(scores)
    return np.where(valid, np.clip(scores, -1.0, 1.0), 0.0), valid


def inside_image_log_prior(image_xy: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """0 for particles whose image position lies in [0, W-1] x [0, H-1], -inf elsewhere (Pang §3: the
    target is within the frame). The filter drops it for a frame where it would leave no particle
    with weight (:meth:`common.tracking._frames.ParticleFilter._normalise`)."""
    w, h = image_size
    x, y = image_xy[:, 0], image_xy[:, 1]
    inside = (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)  # False for NaN
    return np.where(inside, 0.0, -np.inf)
