"""RawImage wire bytes built and read with one copy of the pixels equal protobuf's own."""

import numpy as np
import pytest

from common.msgs import RawImage
from common.msgs.convert import image_to_msg, msg_to_image
from common.msgs.image_wire import CAMERA_FRAME, decode_frame, decode_image, encode_image


@pytest.fixture
def image():
    return np.random.default_rng(0).integers(0, 256, (72, 128, 3), dtype=np.uint8)


def test_encoded_bytes_parse_to_the_same_message(image):
    for ns, fid in ((1_700_000_000_123_456_789, "41"), (0, ""), (5, "x" * 300)):
        assert RawImage.FromString(bytes(encode_image(image, ns, None, fid))) == image_to_msg(image, ns, fid)
    # with the index: the same foxglove.RawImage to a reader that knows only the schema
    parsed = RawImage.FromString(bytes(encode_image(image, 9, 123456)))
    want = image_to_msg(image, 9, CAMERA_FRAME)
    for f in RawImage.DESCRIPTOR.fields:
        assert getattr(parsed, f.name) == getattr(want, f.name), f.name


def test_decode_reads_both_field_orders(image):
    for buf in (bytes(encode_image(image, 77, None, "3")), image_to_msg(image, 77, "3").SerializeToString()):
        msg, got = decode_image(buf)
        assert np.array_equal(got, image) and msg.frame_id == "3" and msg.timestamp.ToNanoseconds() == 77
        assert not msg.data


def test_the_frame_index_travels_beside_a_fixed_camera_frame(image):
    index, msg, got = decode_frame(bytes(encode_image(image, 77, 2**40)))
    assert index == 2**40 and msg.frame_id == CAMERA_FRAME and np.array_equal(got, image)
    # an older recording's image: the index is its frame_id
    assert decode_frame(image_to_msg(image, 77, "12").SerializeToString())[0] == 12
    with pytest.raises(ValueError, match="no frame index"):
        decode_frame(image_to_msg(image, 77, "camera").SerializeToString())


def test_decode_rejects_what_msg_to_image_rejects(image):
    bad = image_to_msg(image, 1, "0")
    bad.data = bad.data[:1000]
    with pytest.raises(ValueError):
        msg_to_image(RawImage.FromString(bad.SerializeToString()))
    with pytest.raises(ValueError, match="truncated"):
        decode_image(bad.SerializeToString())
    good = bytes(encode_image(image, 1, 0))
    for broken in (good[:-1], good[:20], b"\x00\xffnot protobuf at all"):
        with pytest.raises(Exception):
            decode_image(broken)
    other = image_to_msg(image, 1, "0")
    other.encoding = "bgr8"
    with pytest.raises(ValueError, match="encoding"):
        decode_image(other.SerializeToString())
