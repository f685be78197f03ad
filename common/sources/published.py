"""Frames as the bus carries them: raw pixels (foxglove.RawImage) or compressed bytes
(foxglove.CompressedImage), chosen by ``--image-format``, and the frame every consumer then sees.

- ``auto``: a frame read from a JPEG or PNG file goes out as those very bytes; other frames as
  their source prefers (:attr:`common.sources.base.Source.image_format`: raw for rendered
  scenes, ``jpeg:90`` for video and cameras);
- ``raw``, ``png`` (lossless), ``jpeg[:QUALITY]`` (lossy, quality 95 by default).

Consumers decode what was published, so a lossy format changes the pixels the tracker sees:
:func:`as_published` gives the in-process tracker (``track``) the same decoded frame, and live
run, in-process track and replay stay equal bit for bit.
"""

from __future__ import annotations

import dataclasses
from typing import Iterator

from common.sources.imageio import decode_rgb, encode_rgb
from common.sources.base import Frame, Source, SourceError, WrappedSource

FORMATS = ("auto", "raw", "png", "jpeg")


def parse_image_format(spec: str) -> tuple[str, int]:
    """(format, JPEG quality) of ``auto``, ``raw``, ``png``, ``jpeg`` or ``jpeg:Q`` (Q 1-100);
    ValueError with the accepted forms otherwise."""
    fmt, _, q = str(spec).partition(":")
    if fmt not in FORMATS or (q and fmt != "jpeg"):
        raise ValueError(f"image format {spec!r}: use auto, raw, png, jpeg or jpeg:QUALITY")
    quality = 95
    if q:
        if not q.isdigit() or not 1 <= int(q) <= 100:
            raise ValueError(f"image format {spec!r}: the JPEG quality is 1-100")
        quality = int(q)
    return fmt, quality


def published_image(frame: Frame, spec: str, source_format: str = "raw") -> tuple[str, bytes] | None:
    """What goes on the bus for ``frame``: None for raw pixels, else (format, bytes)."""
    fmt, quality = parse_image_format(spec)
    if fmt == "auto":
        if frame.encoded is not None:
            return frame.encoded
        fmt, quality = parse_image_format(source_format)
    if fmt == "raw":
        return None
    return fmt, encode_rgb(frame.image, fmt, quality)


def lossy(frame: Frame, spec: str, source_format: str = "raw") -> bool:
    """Whether consumers of the published frame see other pixels than ``frame.image``."""
    fmt, _ = parse_image_format(spec)
    if fmt == "auto":
        if frame.encoded is not None:
            return False  # the image was decoded from these bytes
        fmt, _ = parse_image_format(source_format)
    return fmt == "jpeg"


def as_published(frame: Frame, spec: str, source_format: str = "raw") -> Frame:
    """``frame`` as a consumer of the bus decodes it (the same frame unless the format is lossy)."""
    if not lossy(frame, spec, source_format):
        return frame
    fmt, data = published_image(frame, spec, source_format)
    return dataclasses.replace(frame, image=decode_rgb(data), encoded=(fmt, data))


class PublishedSource(WrappedSource):
    """A source whose frames are as the bus would carry them with ``spec`` (see module)."""

    forwarded = ("true_centre", "scene", "person_boxes")

    def __init__(self, source: Source, spec: str):
        parse_image_format(spec)
        super().__init__(source)
        self.spec = spec

    def frame(self, i: int) -> Frame:
        if not hasattr(self.inner, "frame"):
            raise SourceError(f"{self.name}: not seekable")
        return as_published(self.inner.frame(i), self.spec, self.image_format)

    def __iter__(self) -> Iterator[Frame]:
        for f in self.inner:
            yield as_published(f, self.spec, self.image_format)
