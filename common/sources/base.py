"""The types every frame source shares: :class:`Frame`, :class:`GroundTruth`, :class:`Source`,
:class:`WrappedSource` and :class:`SourceError` (the sources themselves and ``open_source`` are in
:mod:`common.sources`; sources defined elsewhere, such as :mod:`common.scene.events`, build on
these alone)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterator

import numpy as np

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff")


class SourceError(ValueError):
    """The source cannot be opened or is inconsistent; the message says how to fix it."""


@dataclass(frozen=True)
class GroundTruth:
    box: tuple[float, float, float, float] | None
    """(x, y, w, h), top-left corner and size in pixels (0-based); None when not visible."""
    angle_deg: float | None = None
    """Image orientation of the target (anticlockwise as displayed), when the source knows it."""
    visible_fraction: float | None = None

    @property
    def centre(self) -> tuple[float, float] | None:
        if self.box is None:
            return None
        x, y, w, h = self.box
        return (x + w / 2.0, y + h / 2.0)


@dataclass(frozen=True)
class Frame:
    index: int
    """Position in source order, from 0."""
    time: float
    """Capture time in seconds (source clock)."""
    image: np.ndarray = field(repr=False)
    """uint8 (H, W, 3) RGB."""
    homography: np.ndarray | None = None
    """3x3 ground plane (metres) -> image pixels, when the source knows the camera pose."""
    truth: GroundTruth | None = None
    people: object | None = field(default=None, repr=False)
    """The people scene's :class:`common.scene.people.PeopleTruth` (every person's part centres)."""
    encoded: tuple[str, bytes] | None = field(default=None, repr=False)
    """(format, bytes) of the file the frame was read from (``jpeg`` or ``png``), when it has one:
    published and recorded as they are (``image`` is decoded from these very bytes)."""

    @property
    def size(self) -> tuple[int, int]:
        return (self.image.shape[1], self.image.shape[0])


class Source:
    """Base class: a name, a frame rate, an optional length, iteration over frames."""

    name: str = "source"
    fps: float = 30.0
    live: bool = False
    """True for real-time sources (a camera): consumers may skip stale frames."""
    image_format: str = "raw"
    """How its frames go on the bus and into the recording with ``--image-format auto`` when they
    have no file bytes of their own (:func:`common.sources.published.published_image`): rendered
    scenes ``raw`` (their per-pixel noise does not compress), video and cameras ``jpeg:90``."""

    def __len__(self) -> int:  # pragma: no cover - overridden
        raise TypeError(f"{self.name} has no known length")

    def __iter__(self) -> Iterator[Frame]:  # pragma: no cover - overridden
        raise NotImplementedError

    @property
    def has_truth(self) -> bool:
        return False


class WrappedSource(Source):
    """A source over another one, ``inner``: it takes the inner source's name, frame rate, liveness
    and image format, its length and whether it has ground truth, and those of the extras named in
    :attr:`forwarded` (such as ``true_centre``) that the inner source has."""

    forwarded: tuple[str, ...] = ()

    def __init__(self, source: Source):
        self.inner = source
        self.name, self.fps, self.live, self.image_format = source.name, source.fps, source.live, source.image_format
        for attr in self.forwarded:  # only what the inner source can answer
            if hasattr(source, attr):
                setattr(self, attr, getattr(source, attr))

    def __len__(self) -> int:
        return len(self.inner)

    @property
    def has_truth(self) -> bool:
        return self.inner.has_truth
