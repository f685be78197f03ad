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
    img = cv2.imread(str(p), cv2.IMREAD_COLOR)
    if img is None:
        raise ImageReadError(f"{p}: not a readable image (OpenCV could not decode it)")
    return np.ascontiguousarray(img[:, :, ::-1])
