"""Reading images from disk as RGB arrays, with errors that say what is wrong."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np


class ImageReadError(ValueError):
    pass


def read_rgb(path: str | Path) -> np.ndarray:
    """Read an image file as a uint8 (H, W, 3) RGB array."""
    p = Path(path)
    if not p.exists():
        raise ImageReadError(f"{p}: no such file")
    if p.is_dir():
        raise ImageReadError(f"{p}: is a directory, expected an image file")
    try:
        return decode_rgb(p.read_bytes())
    except ImageReadError:
        raise ImageReadError(f"{p}: not a readable image (OpenCV could not decode it)") from None


def decode_rgb(data) -> np.ndarray:
    """An encoded image's bytes (JPEG, PNG, ...) as a uint8 (H, W, 3) RGB array: the one decoder
    of a file read from disk and of the same bytes published on the bus (equal pixels)."""
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if img is None:
        raise ImageReadError("not a decodable image")
    return np.ascontiguousarray(img[:, :, ::-1])


def encode_rgb(image: np.ndarray, fmt: str, quality: int = 95) -> bytes:
    """A uint8 (H, W, 3) RGB array as ``fmt`` bytes: png (lossless, fastest level) or jpeg (quality 1-100)."""
    bgr = np.ascontiguousarray(image[:, :, ::-1])
    if fmt == "png":
        ok, buf = cv2.imencode(".png", bgr, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    elif fmt == "jpeg":
        ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    else:
        raise ValueError(f"unknown image format {fmt!r} (png or jpeg)")
    if not ok:
        raise ValueError(f"OpenCV could not encode a {image.shape} image as {fmt}")
    return buf.tobytes()
