"""Message schemas of the bus: the project's own protobuf messages and Foxglove's RawImage and
ImageAnnotations (the track drawn on the image: ``common/msgs/annotations.py``),
the topic of each, and packing of NumPy arrays into ``bytes`` fields.

The generated code (``polartrack/messages_pb2.py``) comes from ``proto/`` via
``tools/gen_proto.sh``; do not edit it by hand.
"""

from __future__ import annotations

import numpy as np
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

from common.msgs.polartrack.messages_pb2 import (
    Estimate,
    FrameInfo,
    MultiEstimate,
    ParticleCloud,
    RunConfig,
    ScoreQuery,
    ScoreReply,
    ServiceStatus,
    Template,
    Truth,
)

from common.msgs.topics import recorded_messages  # noqa: E402 (the table imports the classes above)

TOPICS: dict[str, type] = recorded_messages()
"""Recorded topic suffix (after ``polartrack/<stream>/``) -> message class, from the pipeline's
graph (:mod:`common.msgs.topics`). Status topics are ``status/<service>`` (ServiceStatus)."""


def message_class(suffix: str) -> type | None:
    if suffix in TOPICS:
        return TOPICS[suffix]
    if suffix.startswith("status/"):
        return ServiceStatus
    return None


def pack(a: np.ndarray, dtype=np.float64) -> bytes:
    return np.ascontiguousarray(a, dtype=np.dtype(dtype).newbyteorder("<")).tobytes()


def unpack(b: bytes, dtype, shape: tuple[int, ...]) -> np.ndarray:
    """Array of ``shape`` from little-endian bytes; ValueError if the size does not match."""
    dt = np.dtype(dtype).newbyteorder("<")
    n = int(np.prod(shape)) if shape else 1
    if len(b) != n * dt.itemsize:
        raise ValueError(f"expected {n} x {dt.itemsize} bytes for shape {shape}, got {len(b)}")
    return np.frombuffer(b, dtype=dt).reshape(shape).astype(np.dtype(dtype).newbyteorder("="))


def image_to_msg(image: np.ndarray, capture_ns: int, frame_id: str) -> RawImage:
    """uint8 RGB (H, W, 3) -> foxglove.RawImage (rgb8)."""
    h, w = image.shape[:2]
    msg = RawImage(frame_id=frame_id, width=w, height=h, encoding="rgb8", step=3 * w,
                   data=np.ascontiguousarray(image, np.uint8).tobytes())
    msg.timestamp.FromNanoseconds(int(capture_ns))
    return msg


def msg_to_image(msg: RawImage) -> np.ndarray:
    """foxglove.RawImage (rgb8) -> uint8 (H, W, 3); ValueError for anything malformed."""
    if msg.encoding != "rgb8":
        raise ValueError(f"unsupported image encoding {msg.encoding!r} (expected rgb8)")
    h, w = int(msg.height), int(msg.width)
    if h <= 0 or w <= 0 or msg.step != 3 * w:
        raise ValueError(f"bad image geometry {w}x{h} step {msg.step}")
    data = msg.data  # each read of a bytes field is a copy of the whole image
    if len(data) != h * msg.step:
        raise ValueError(f"image data has {len(data)} bytes, expected {h * msg.step} (truncated?)")
    return np.frombuffer(data, np.uint8).reshape(h, w, 3)


__all__ = ["RawImage", "FrameInfo", "Truth", "ScoreQuery", "ScoreReply", "Template", "Estimate", "MultiEstimate", "ParticleCloud",
           "RunConfig", "ServiceStatus", "ImageAnnotations", "TOPICS", "message_class", "pack", "unpack", "image_to_msg", "msg_to_image"]
