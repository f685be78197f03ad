"""foxglove.RawImage (rgb8) to and from its wire bytes with one copy of the pixels, the frame's
index beside them (:data:`INDEX_FIELD`) and one fixed ``frame_id`` (:data:`CAMERA_FRAME`).

A 1280x720 frame is 2.7 MB. ``image_to_msg(...).SerializeToString()`` copies the pixels three
times (``tobytes``, into the message, into the serialised bytes) and ``msg_to_image(FromString(b))``
twice (into the message, out of it as ``bytes``). Here the bytes are built once (the small fields
serialised by protobuf, then the ``data`` field appended: a valid encoding, fields in another
order), and decoding scans the fields and views the pixels in the received bytes in place.
"""

from __future__ import annotations

import numpy as np

from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage

from . import RawImage

_DATA = RawImage.DESCRIPTOR.fields_by_name["data"].number

CAMERA_FRAME = "camera"
"""The ``frame_id`` of every frame image: one fixed camera frame, as Foxglove and Rerun expect
(Rerun's MCAP loader makes each frame_id a coordinate frame of its own)."""

INDEX_FIELD = 100
"""The frame's index travels in this field of the RawImage bytes: unknown to foxglove.RawImage,
so readers that decode by the schema skip it (protobuf keeps unknown fields as they are), and
:func:`decode_frame` reads it. Images without it (recordings before it) carry the index as
their ``frame_id``."""


def _varint(value: int) -> bytes:
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def encode_image(image: np.ndarray, capture_ns: int, index: int | None, frame_id: str = CAMERA_FRAME) -> bytes:
    """The wire bytes of ``image_to_msg(image, capture_ns, frame_id)`` (uint8 RGB (H, W, 3)) and
    the frame's ``index`` in :data:`INDEX_FIELD` (None: no index field)."""
    h, w = image.shape[:2]
    head = RawImage(frame_id=frame_id, width=w, height=h, encoding="rgb8", step=3 * w)
    head.timestamp.FromNanoseconds(int(capture_ns))
    extra = b"" if index is None else _varint(INDEX_FIELD << 3) + _varint(int(index))
    prefix = head.SerializeToString() + extra + _varint(_DATA << 3 | 2) + _varint(image.size)
    out = bytearray(len(prefix) + image.size)
    out[: len(prefix)] = prefix
    np.frombuffer(out, np.uint8, image.size, len(prefix)).reshape(image.shape)[...] = image
    return out


def _read_varint(buf, i: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        if i >= len(buf) or shift > 63:
            raise ValueError("truncated or malformed protobuf varint")
        byte = buf[i]
        i += 1
        value |= (byte & 0x7F) << shift
        if not byte & 0x80:
            return value, i
        shift += 7


def decode_frame(buf: bytes, pixels: bool = True) -> tuple[int, object, np.ndarray | None]:
    """(frame index, the message without its pixels, uint8 RGB (H, W, 3)) of a ``frame/image``
    payload, a foxglove.RawImage (the pixels a read-only view into ``buf``) or a
    foxglove.CompressedImage (JPEG or PNG, decoded; ``pixels`` False: not decoded, None). The
    index from :data:`INDEX_FIELD`, else from a numeric ``frame_id``. ValueError (or protobuf's
    DecodeError) when malformed, or when there is no index."""
    index, msg, image = _decode(buf, pixels)
    if index is None:
        fid = msg.frame_id.strip()
        if not fid.isdigit():
            raise ValueError(f"no frame index (frame_id {fid[:20]!r})")
        index = int(fid)
    return index, msg, image


def decode_image(buf: bytes) -> tuple[RawImage, np.ndarray]:
    """(the message without its pixels, uint8 RGB (H, W, 3) read-only view into ``buf``) of the
    wire bytes of a RawImage; ValueError (or protobuf's DecodeError) when malformed, with the
    same geometry checks as :func:`common.msgs.convert.msg_to_image`."""
    _, msg, image = _decode(buf, True)
    if not isinstance(msg, RawImage):
        raise ValueError("a compressed image, not a RawImage")
    return msg, image


def is_compressed(buf: bytes) -> bool:
    """A foxglove.CompressedImage's bytes (its field 2 is the data), not a RawImage's (field 2 is
    the width); ValueError when malformed."""
    return any(number == 2 and wire == 2 for number, wire, *_ in _fields(buf))


def encode_compressed(data: bytes, fmt: str, capture_ns: int, index: int | None,
                      frame_id: str = CAMERA_FRAME) -> bytes:
    """The wire bytes of a foxglove.CompressedImage of ``data`` (``fmt`` jpeg or png) with the
    frame's ``index`` in :data:`INDEX_FIELD`."""
    head = CompressedImage(frame_id=frame_id, format=fmt)
    head.timestamp.FromNanoseconds(int(capture_ns))
    extra = b"" if index is None else _varint(INDEX_FIELD << 3) + _varint(int(index))
    return head.SerializeToString() + extra + _varint(2 << 3 | 2) + _varint(len(data)) + bytes(data)


COMPRESSED_FORMATS = ("jpeg", "png")


def _fields(buf):
    """(number, wire type, start, end, value) of each top-level field: value is the varint, or
    (offset, length) of a length-delimited field's bytes."""
    i, n = 0, len(buf)
    while i < n:
        start = i
        key, i = _read_varint(buf, i)
        wire = key & 7
        value = None
        if wire == 0:
            value, i = _read_varint(buf, i)
        elif wire == 1:
            i += 8
        elif wire == 5:
            i += 4
        elif wire == 2:
            length, i = _read_varint(buf, i)
            value = (i, length)
            i += length
        else:
            raise ValueError(f"unsupported protobuf wire type {wire}")
        if i > n:
            raise ValueError("truncated protobuf field" if wire != 2 else "truncated image data")
        yield key >> 3, wire, start, i, value


def _decode(buf: bytes, pixels: bool) -> tuple[int | None, object, np.ndarray | None]:
    fields = list(_fields(buf))
    compressed = any(number == 2 and wire == 2 for number, wire, *_ in fields)
    data_field = 2 if compressed else _DATA
    head, data, index = [], None, None
    for number, wire, start, end, value in fields:
        if number == INDEX_FIELD and wire == 0:
            index = value
        elif number == data_field and wire == 2:
            data = value
        else:
            head.append(bytes(buf[start:end]))
    if compressed:
        msg = CompressedImage.FromString(b"".join(head))
        if msg.format not in COMPRESSED_FORMATS:
            raise ValueError(f"unsupported image format {msg.format!r} (expected jpeg or png)")
        if data is None or data[1] == 0:
            raise ValueError("compressed image without data")
        if not pixels:
            return index, msg, None
        from common.sources.imageio import decode_rgb

        offset, length = data
        return index, msg, decode_rgb(memoryview(buf)[offset:offset + length])
    msg = RawImage.FromString(b"".join(head))
    if msg.encoding != "rgb8":
        raise ValueError(f"unsupported image encoding {msg.encoding!r} (expected rgb8)")
    h, w = int(msg.height), int(msg.width)
    if h <= 0 or w <= 0 or msg.step != 3 * w:
        raise ValueError(f"bad image geometry {w}x{h} step {msg.step}")
    offset, length = data if data is not None else (0, 0)
    if length != h * msg.step:
        raise ValueError(f"image data has {length} bytes, expected {h * msg.step} (truncated?)")
    return index, msg, np.frombuffer(buf, np.uint8, length, offset).reshape(h, w, 3)
