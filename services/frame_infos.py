"""What both tracker modes (single- and multi-target) do with the bus: take the next frame info,
skipping stale ones in real time, and read a detector reply."""

from __future__ import annotations

import logging

from common.msgs import FrameInfo, ScoreReply
from services.bus import Counters, Inbox, Stopper, payload_bytes


def next_frame_info(inbox: Inbox, skip_stale: bool, stopper: Stopper, c: Counters,
                    log: logging.Logger) -> tuple[FrameInfo | None, int]:
    """(the next frame info, or None when none came within 0.2 s or it was malformed; how many
    stale infos were skipped). With ``skip_stale`` (a real-time source) only the newest pending
    info is taken, the others are counted in ``dropped``, but the end of stream is never skipped."""
    if not inbox.wait(0.2):
        return None, 0
    sample = inbox.pop("info")
    if sample is None:
        return None, 0
    skipped = 0
    if skip_stale:
        while inbox.pending("info") and not stopper.stopped:
            newer = inbox.pop("info")
            try:
                if FrameInfo.FromString(payload_bytes(newer)).end_of_stream:
                    sample = newer
                    break
            except Exception:  # noqa: BLE001 - a malformed info is counted when it is the one taken
                pass
            sample = newer
            skipped += 1
            c.add("dropped")
    c.add("received")
    try:
        return FrameInfo.FromString(payload_bytes(sample)), skipped
    except Exception as exc:  # noqa: BLE001
        c.add("malformed")
        log.warning("malformed frame info: %s", exc)
        return None, skipped


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
