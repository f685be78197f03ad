"""Bookkeeping shared by the trackers: elapsed time between frames and the latest homography."""

from __future__ import annotations

import numpy as np


def make_rng(seed: int | np.random.SeedSequence | np.random.Generator) -> np.random.Generator:
    """The tracker's own generator: a Generator is used as given (its state is then shared with the
    caller); an int or SeedSequence seeds a fresh PCG64."""
    if isinstance(seed, np.random.Generator):
        return seed
    return np.random.default_rng(seed)


class FrameClock:
    """Elapsed time T between successive steps (Pang §3: T is the frame interval, here from timestamps)."""

    def __init__(self, t0: float | None) -> None:
        self.last_time = t0
        self.homography: np.ndarray | None = None
        """The most recent observation's world->image homography (None: identity / none seen yet)."""

    def advance(self, frame_time: float) -> float:
        """Move to ``frame_time`` and return T = frame_time - previous time (0 on the first step of a
        tracker whose prior had no time). Time must not run backwards."""
        frame_time = float(frame_time)
        if not np.isfinite(frame_time):
            raise ValueError(f"frame time must be finite, got {frame_time}")
        dt = 0.0 if self.last_time is None else frame_time - self.last_time
        if dt < 0:
            raise ValueError(f"frame time {frame_time} is before the previous step's {self.last_time}")
        self.last_time = frame_time
        return dt

    def see(self, observation) -> np.ndarray | None:
        """Record and return the observation's homography (or the last one when ``observation`` is None)."""
        if observation is not None:
            h = observation.homography
            self.homography = None if h is None else np.asarray(h, dtype=float)
        return self.homography
