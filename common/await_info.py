"""Items about a frame held until that frame's info has come.

A run's estimate comes from the tracker and its frame's info (the truth) from ingest, and on a
loaded machine the estimate can arrive first. Whatever joins the two (the recorder's Foxglove
drawing, :class:`common.msgs.annotations.TrackDrawing`; the launcher's run summary,
:class:`common.evaluation.LiveErrors`) holds the item until that frame's info, or a later frame's,
has come: the infos come in frame order, so a frame passed over has lost its info for good.
"""

from __future__ import annotations

from typing import Generic, TypeVar

T = TypeVar("T")


class AwaitInfo(Generic[T]):
    """Held items, each about a frame; released in the order they were held."""

    def __init__(self, keep: int | None = None):
        self.keep = keep
        """At most this many held (None: no bound); beyond it the oldest is released unjoined."""
        self.latest = -1
        """The latest frame whose info has come (-1: none yet)."""
        self._held: list[tuple[int, T]] = []

    def hold(self, index: int, item: T) -> list[T]:
        """``item``, about frame ``index``: released at once if that frame's info has come, else held;
        returns what is released (the oldest held, beyond ``keep``)."""
        if int(index) <= self.latest:
            return [item]
        self._held.append((int(index), item))
        out = []
        while self.keep is not None and len(self._held) > self.keep:
            out.append(self._held.pop(0)[1])
        return out

    def info(self, index: int) -> list[T]:
        """Frame ``index``'s info has come: the items it releases (those about it or earlier frames)."""
        self.latest = max(self.latest, int(index))
        out = [item for i, item in self._held if i <= self.latest]
        self._held = [(i, item) for i, item in self._held if i > self.latest]
        return out

    def flush(self) -> list[T]:
        """Every item still held."""
        out = [item for _, item in self._held]
        self._held = []
        return out
