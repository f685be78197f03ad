"""In-process tracking: source frames -> detector observations -> filter steps.

``track_frames`` is the whole single-target pipeline without a bus: the same filter, template
and frame cache that the services run in separate processes, so the two give identical
estimates for the same source, seed and settings.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Iterator

import numpy as np

from common.detector import FrameCache, PolarMatcher, Template
from common.detector.layout import SUPPORT_RADIUS_PX
from common.detector.observation import DetectorObservation
from common.settings import TrackerSettings
from common.sources import Frame
from common.tracking import RBPF, SIR, InitialState, TrackState, WindowedML


class InitError(ValueError):
    """The initial box is unusable; the message says why and what to do."""


def check_init_box(box: tuple[float, float, float, float], width: int, height: int) -> None:
    x, y, w, h = box
    if not all(np.isfinite(v) for v in box):
        raise InitError(f"--init {box}: values must be finite")
    if w <= 0 or h <= 0:
        raise InitError(f"--init {x:g},{y:g},{w:g},{h:g}: width and height must be positive")
    cx, cy = x + w / 2, y + h / 2
    if not (0 <= cx < width and 0 <= cy < height):
        raise InitError(f"--init {x:g},{y:g},{w:g},{h:g}: the box centre ({cx:g}, {cy:g}) is outside the "
                        f"{width}x{height} frame")
    r = SUPPORT_RADIUS_PX
    if not (r <= cx <= width - 1 - r and r <= cy <= height - 1 - r):
        raise InitError(f"--init {x:g},{y:g},{w:g},{h:g}: the box centre must be at least {r} px inside the "
                        f"{width}x{height} frame to build the template")


def make_filter(settings: TrackerSettings, init_box: tuple[float, float, float, float],
                homography: np.ndarray | None, t0: float):
    """The configured filter, started on the centre of ``init_box`` (x, y, w, h) of the first frame."""
    x, y, w, h = init_box
    initial = InitialState.from_image_point((x + w / 2, y + h / 2), homography, time=t0,
                                            pos_std=settings.init_pos_std, vel_std=settings.init_vel_std)
    if settings.filter == "rbpf":
        cfg = settings.rbpf if settings.particles is None else settings.rbpf.model_copy(update={"n_particles": settings.particles})
        return RBPF(cfg, initial, seed=settings.seed)
    if settings.filter == "sir":
        cfg = settings.sir if settings.particles is None else settings.sir.model_copy(update={"n_particles": settings.particles})
        return SIR(cfg, initial, seed=settings.seed)
    return WindowedML(settings.ml, initial)


@dataclass
class Tracker:
    """A filter with its template: ``step(frame) -> TrackState`` for frames in source order."""

    settings: TrackerSettings
    matcher: PolarMatcher
    cache: FrameCache
    filter: object

    @classmethod
    def start(cls, first: Frame, init_box: tuple[float, float, float, float], settings: TrackerSettings) -> "Tracker":
        check_init_box(init_box, *first.size)
        x, y, w, h = init_box
        template = Template.from_image(first.image, (x + w / 2, y + h / 2), box=init_box)
        return cls(settings, PolarMatcher(template), FrameCache(),
                   make_filter(settings, init_box, first.homography, first.time))

    def observation(self, frame: Frame) -> DetectorObservation:
        return DetectorObservation(frame.index, frame.time, frame.image, self.matcher, self.cache, frame.homography)

    def step(self, frame: Frame) -> TrackState:
        return self.filter.step(frame.time, self.observation(frame))


def track_frames(frames: Iterable[Frame], init_box: tuple[float, float, float, float],
                 settings: TrackerSettings) -> Iterator[tuple[Frame, TrackState]]:
    """Track through ``frames``; the template is built on the first frame at ``init_box``."""
    tracker = None
    for frame in frames:
        if tracker is None:
            tracker = Tracker.start(frame, init_box, settings)
        yield frame, tracker.step(frame)
