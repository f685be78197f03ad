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


__all__ = ["RawImage", "FrameInfo", "Truth", "ScoreQuery", "ScoreReply", "Template", "Estimate", "MultiEstimate", "ParticleCloud",
           "RunConfig", "ServiceStatus", "ImageAnnotations", "TOPICS", "message_class", "pack", "unpack"]
