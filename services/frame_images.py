"""Frame images off the bus: decoding a ``frame/image`` sample, and a stabilising tracker's store
of the latest frames' pixels by index (the Zenoh callback only queues; decoding happens in the
service's thread)."""

from __future__ import annotations

import time
from collections import OrderedDict

import numpy as np

from common.msgs import image_wire
from common.validation import MAX_FRAME_INDEX, Invalid, check_image_size
from services.bus import Inbox, attachment_ns, attachment_sender, payload_bytes


def decode_image(sample) -> tuple[int, np.ndarray, int]:
    """(frame index, uint8 RGB image, capture ns) of a ``frame/image`` sample; ValueError (or a
    protobuf DecodeError) when malformed. The image is a read-only view into the payload's bytes."""
    index, msg, image = image_wire.decode_frame(payload_bytes(sample))
    check_image_size(image.shape[1], image.shape[0])
    if not 0 <= index <= MAX_FRAME_INDEX:
        raise Invalid("bad_index", str(index)[:20])
    return index, image, attachment_ns(sample) or msg.timestamp.ToNanoseconds()


class FrameImages:
    """Subscribes to ``frame/image`` and hands out a frame's image by index (the last ``keep`` kept)."""

    def __init__(self, session, key: str, counters, keep: int = 8, guard=None):
        """``guard``: images from another sender than the run's ingest, or too large, are dropped and counted."""
        self.guard = guard
        self.inbox = Inbox()
        self.sub = session.declare_subscriber(key, self.inbox.callback("image", maxlen=keep))
        self.counters = counters
        self.keep = keep
        self.images: OrderedDict[int, np.ndarray] = OrderedDict()

    def _drain(self) -> None:
        while (s := self.inbox.pop("image")) is not None:
            if self.guard is not None and not self.guard.accept("frame/image", attachment_sender(s), len(s.payload)):
                continue
            try:
                index, image, _ = decode_image(s)
            except Exception as exc:  # noqa: BLE001
                if self.guard is not None:
                    self.guard.reject("frame/image", "undecodable", f"{type(exc).__name__}: {exc}")
                else:
                    self.counters.add("malformed")
                continue
            self.images[index] = image
            while len(self.images) > self.keep:
                self.images.popitem(last=False)

    def get(self, index: int, timeout: float, stopper=None) -> np.ndarray | None:
        """Frame ``index``'s image, waiting up to ``timeout`` s for it (None if it never came).
        Older frames are forgotten: frames are asked for in order."""
        deadline = time.monotonic() + timeout
        while True:
            self._drain()
            if index in self.images:
                for old in [i for i in self.images if i < index]:
                    del self.images[old]
                return self.images.pop(index)
            if time.monotonic() >= deadline or (stopper is not None and stopper.stopped):
                return None
            self.inbox.wait(min(0.05, max(0.0, deadline - time.monotonic())))

    def close(self) -> None:
        self.sub.undeclare()
