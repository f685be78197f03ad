"""Messages released in log-time order: a recorder writes what arrives, and what arrives is
nearly in capture-time order but not quite (the estimate of frame N comes after the image of
frame N+1; a status is published whenever its period ends). :class:`LogTimeOrder` holds the
newest messages for ``hold_ns`` of log time and releases the others sorted, so that a file's
messages, and so its chunks, follow log time (what ``rerun mcap check`` and players expect)."""

from __future__ import annotations

import heapq
import itertools
from typing import Any


class LogTimeOrder:
    """Push (log time, item); get back the items whose log time is at least ``hold_ns`` behind
    the newest seen, oldest first. At most ``max_held`` are held (beyond, the oldest go at once).
    A message older than one already released is released at once and counted in ``late``
    (it is never dropped)."""

    def __init__(self, hold_ns: int, max_held: int = 256):
        self.hold_ns, self.max_held = int(hold_ns), int(max_held)
        self._heap: list[tuple[int, int, Any]] = []
        self._seq = itertools.count()
        self.newest: int | None = None
        self.released: int | None = None
        """The log time of the last item released."""
        self.late = 0

    def push(self, log_time: int, item: Any) -> list[Any]:
        log_time = int(log_time)
        if self.released is not None and log_time < self.released:
            self.late += 1
            return [item]
        self.newest = log_time if self.newest is None else max(self.newest, log_time)
        heapq.heappush(self._heap, (log_time, next(self._seq), item))
        out = []
        while self._heap and (self._heap[0][0] <= self.newest - self.hold_ns or len(self._heap) > self.max_held):
            out.append(self._pop())
        return out

    def drain(self) -> list[Any]:
        """Every held item, oldest first."""
        return [self._pop() for _ in range(len(self._heap))]

    def __len__(self) -> int:
        return len(self._heap)

    def _pop(self) -> Any:
        t, _, item = heapq.heappop(self._heap)
        self.released = t if self.released is None else max(self.released, t)
        return item
