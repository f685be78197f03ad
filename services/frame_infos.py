"""What both tracker modes (single- and multi-target) do with the bus: take the next frame info,
skipping stale ones in real time, and read a detector reply."""

from __future__ import annotations

import logging
from collections import deque

from common.msgs import FrameInfo, ScoreReply
from common.validation import FrameOrder, Guard, Senders, check_frame_info
from services.bus import Counters, Inbox, Stopper, attachment_sender, payload_bytes


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

    def __init__(self, inbox: Inbox, skip_stale: bool, max_lag_frames: int, c: Counters, log: logging.Logger,
                 guard: Guard | None = None):
        """``guard``: the service's checks; an info from another sender than the run's ingest, or
        one that fails :func:`common.validation.check_frame_info` (non-finite or backward time,
        index not increasing, a time jump, a bad homography or size), is dropped and counted."""
        if max_lag_frames < 0:
            raise ValueError(f"max_lag_frames must be >= 0, got {max_lag_frames}")
        self.inbox, self.skip_stale, self.max_lag_frames = inbox, skip_stale, max_lag_frames
        self.c, self.log = c, log
        self.guard = guard if guard is not None else Guard("tracker", Senders(), log,
                                                           on_reject=lambda k, r: c.add("malformed"))
        self.order = FrameOrder()
        self.waiting: deque[FrameInfo] = deque()

    def _drain(self) -> None:
        while (sample := self.inbox.pop("info")) is not None:
            info = self.guard.decode("frame/info", FrameInfo, payload_bytes(sample), attachment_sender(sample),
                                     check_frame_info, self.order)
            if info is None:
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


def _same_query(rep: ScoreReply, q) -> None:
    from common.validation import Invalid

    if q is not None and (rep.request_id != q.request_id or rep.client != q.client or rep.frame_index != q.frame_index):
        raise Invalid("not_this_query", f"reply to {rep.client}#{rep.request_id} (frame {rep.frame_index})")


def first_reply(replies, c: Counters, log: logging.Logger, guard: Guard | None = None, query=None) -> ScoreReply | None:
    """The first well-formed ScoreReply among a query's replies from the run's detector, to
    ``query`` (when given), or None. Malformed ones, replies to another query and (with a
    ``guard`` holding the run's ids) replies from any other queryable are counted and ignored."""
    for reply in replies:
        if reply.ok is not None:
            if guard is None:
                try:
                    return ScoreReply.FromString(reply.ok.payload.to_bytes())
                except Exception as exc:  # noqa: BLE001
                    c.add("malformed")
                    log.warning("malformed reply: %s", exc)
                continue
            rep = guard.decode("detector/score", ScoreReply, reply.ok.payload.to_bytes(),
                               attachment_sender(reply.ok), _same_query, query)
            if rep is not None:
                return rep
    return None


class ReplyPicker:
    """:func:`first_reply` for a querier that also counts the replies that come after the one it
    took: a second queryable on the key answers too (a query goes to every queryable), and its
    replies, faster or slower than the detector's, are each counted as ``foreign_sender`` on
    ``detector/score`` (the slower ones at the next query, from the reply channels kept)."""

    def __init__(self, c: Counters, log: logging.Logger, guard: Guard, keep: int = 8):
        self.c, self.log, self.guard, self.keep = c, log, guard, keep
        self.previous: deque = deque(maxlen=keep)

    def _late(self, reply) -> None:
        if reply.ok is None:
            return
        try:
            self.guard.senders.check("detector/score", attachment_sender(reply.ok))
        except Exception as exc:  # noqa: BLE001 - Invalid: another queryable's reply
            self.guard.reject("detector/score", exc)

    def drain(self) -> None:
        """Count the replies that have come since, on the channels of the last queries."""
        still = deque(maxlen=self.keep)
        for handler in self.previous:
            while True:
                try:
                    reply = handler.try_recv()
                except Exception:  # noqa: BLE001 - closed: every reply is in
                    break
                if reply is None:
                    still.append(handler)
                    break
                self._late(reply)
        self.previous = still

    def first(self, replies, query) -> ScoreReply | None:
        self.drain()
        rep = first_reply(replies, self.c, self.log, self.guard, query)
        if hasattr(replies, "try_recv"):
            self.previous.append(replies)
        return rep
