"""What both tracker modes (single- and multi-target) do with the bus: take the next frame info,
skipping stale ones in real time, and read a detector reply."""

from __future__ import annotations

import logging
from collections import deque

from common.msgs import FrameInfo, ScoreReply
from services.bus import Counters, Inbox, Stopper, payload_bytes


class InfoQueue:
    """The frame infos waiting for a tracker, in order, and the live source's staleness rule.

    ``next()`` takes every info the bus has delivered (malformed ones are counted and logged),
    then hands out the oldest. With ``skip_stale`` (a real-time source) a frame is stale when
    more than ``max_lag_frames`` newer frames are already waiting: stale frames are skipped (the
    oldest first) and counted in ``dropped``, so the tracker runs at most ``max_lag_frames``
    behind the source and a short burst of slow frames (a spread cloud's large regions) is
    caught up instead of lost. ``max_lag_frames=0`` always jumps to the newest frame. The end of
    stream is never skipped, and frames before it are still tracked. Without ``skip_stale`` (a
    file paced by its consumers) nothing is skipped.
    """

    def __init__(self, inbox: Inbox, skip_stale: bool, max_lag_frames: int, c: Counters, log: logging.Logger):
        if max_lag_frames < 0:
            raise ValueError(f"max_lag_frames must be >= 0, got {max_lag_frames}")
        self.inbox, self.skip_stale, self.max_lag_frames = inbox, skip_stale, max_lag_frames
        self.c, self.log = c, log
        self.waiting: deque[FrameInfo] = deque()

    def _drain(self) -> None:
        while (sample := self.inbox.pop("info")) is not None:
            try:
                info = FrameInfo.FromString(payload_bytes(sample))
            except Exception as exc:  # noqa: BLE001
                self.c.add("malformed")
                self.log.warning("malformed frame info: %s", exc)
                continue
            self.c.add("received")
            self.waiting.append(info)

    def next(self, stopper: Stopper, timeout: float = 0.2) -> tuple[FrameInfo | None, int]:
        """(the next frame info, or None when none came within ``timeout`` s; how many stale
        infos were skipped to reach it)."""
        self._drain()
        if not self.waiting:
            if stopper.stopped or not self.inbox.wait(timeout):
                return None, 0
            self._drain()
            if not self.waiting:
                return None, 0
        skipped = 0
        if self.skip_stale:
            while len(self.waiting) > self.max_lag_frames + 1 and not self.waiting[0].end_of_stream:
                self.waiting.popleft()
                skipped += 1
            if skipped:
                self.c.add("dropped", skipped)
        return self.waiting.popleft(), skipped


def first_reply(replies, c: Counters, log: logging.Logger) -> ScoreReply | None:
    """The first well-formed ScoreReply among a query's replies (malformed ones counted), or None."""
    for reply in replies:
        if reply.ok is not None:
            try:
                return ScoreReply.FromString(reply.ok.payload.to_bytes())
            except Exception as exc:  # noqa: BLE001
                c.add("malformed")
                log.warning("malformed reply: %s", exc)
    return None
