"""Frame preparation: image -> demodulated, spline-prefiltered DTCWT subbands (levels 2..5).

Done once per frame (or once per region of a frame), so that any number of hypotheses can then
be sampled at sub-pixel positions in one vectorised call (spec sections 1 and 3):

1. pad to a multiple of the pyramid block (32 px) by symmetric reflection (right/bottom only, so
   pixel coordinates are unchanged);
2. forward DTCWT with the rotation-symmetric ``_bp`` filters (:mod:`common.detector.transform`);
3. per subband, demodulate by its nominal centre frequency and apply the phase ``FIX``;
4. cubic B-spline prefilter, so sampling is a 4x4 tap sum.

A *region* is prepared the same way from a crop that extends ``KERNEL_MARGIN_PX`` beyond it on
every side not at the frame edge. Margin rule: inside a region, every coefficient of levels 2..5
agrees with the full-frame one to within 1 percent of that subband's RMS (levels 2-3 to 1e-4);
the tests check it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import cv2
import numpy as np

from common.detector.layout import BLOCK, FIX, LEVELS, NLEVELS, SUBBAND_FREQ, SUPPORT_RADIUS_PX
from common.detector.transform import highpasses

KERNEL_MARGIN_PX = 64
"""Extra pixels transformed beyond a region on every side, so that the region's coefficients
match the full frame's (the DTCWT's level-5 kernels reach far: see the margin rule above)."""

_Z1 = np.sqrt(3.0) - 2.0
_SPLINE_PREFILTER = np.sqrt(3.0) * _Z1 ** np.abs(np.arange(-8, 9))
_SPLINE_PREFILTER = (_SPLINE_PREFILTER / _SPLINE_PREFILTER.sum()).astype(np.float32)
"""Inverse of the cubic B-spline's sampled kernel (1, 4, 1) / 6, truncated at 8 taps a side
(relative error ~3e-5); an FIR filter lets OpenCV do it with SIMD, 4x faster than
scipy.ndimage.spline_filter here."""


def _checked_image(image: np.ndarray) -> np.ndarray:
    """``image`` as (H, W, C), C 1 or 3, in its own dtype (only the crop is converted to float32)."""
    arr = np.asarray(image)
    if arr.ndim == 2:
        arr = arr[:, :, None]
    if arr.ndim != 3 or arr.shape[2] not in (1, 3):
        raise ValueError(f"expected a grey (H, W) or colour (H, W, 3) image, got shape {arr.shape}")
    if arr.shape[0] < 1 or arr.shape[1] < 1:
        raise ValueError("empty image")
    return arr if arr.dtype in (np.uint8, np.float32) else np.asarray(arr, np.float32)


@dataclass
class PreparedLevel:
    """One level of a prepared region: spline coefficients of ``FIX * demodulated subband``."""

    level: int
    coef: np.ndarray
    """complex64 (h, w, 6 * C): index ``s * C + c`` for subband ``s``, channel ``c``."""
    origin_px: tuple[int, int]
    """Pixel (x, y) of the crop's top-left corner; sample (0, 0) of this level is centred on
    pixel ``origin + 2**level * 0.5 - 0.5``."""


@dataclass
class PreparedFrame:
    """The prepared pyramid of a frame or of a region of it."""

    width: int
    """Width of the original (unpadded) frame in pixels."""
    height: int
    channels: int
    levels: dict[int, PreparedLevel]
    region: tuple[int, int, int, int]
    """(x0, y0, x1, y1), pixels, end exclusive: where hypotheses may be scored. The whole frame
    for a full preparation."""
    valid_box: tuple[float, float, float, float] = field(init=False)
    """(xmin, ymin, xmax, ymax) of hypothesis centres that are in support: inside the frame by
    ``SUPPORT_RADIUS_PX`` and inside ``region`` by the same."""

    def __post_init__(self) -> None:
        r = SUPPORT_RADIUS_PX
        x0, y0, x1, y1 = self.region
        self.valid_box = (
            float(max(r, x0 + r)),
            float(max(r, y0 + r)),
            float(min(self.width - 1 - r, x1 - 1 - r)),
            float(min(self.height - 1 - r, y1 - 1 - r)),
        )

    def in_support(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        bx0, by0, bx1, by1 = self.valid_box
        return (x >= bx0) & (x <= bx1) & (y >= by0) & (y <= by1)

    def contains_box(self, box: tuple[float, float, float, float]) -> bool:
        bx0, by0, bx1, by1 = self.valid_box
        return box[0] >= bx0 and box[1] >= by0 and box[2] <= bx1 and box[3] <= by1


def _demodulator(h: int, w: int) -> np.ndarray:
    """``FIX_s * exp(-i (wx_s j + wy_s i))`` over an (h, w) coefficient grid: (h, w, 6) complex64.

    Every element depends on its (i, j) only, so this is the top-left corner of a grid cached
    for sizes rounded up to 64 coefficients (regions come in many sizes; a cache per exact size
    missed a third of the time)."""
    return _demodulator_grid(-(-h // 64) * 64, -(-w // 64) * 64)[:h, :w]


@lru_cache(maxsize=32)
def _demodulator_grid(h: int, w: int) -> np.ndarray:
    jj = np.arange(w, dtype=np.float64)[None, :, None]
    ii = np.arange(h, dtype=np.float64)[:, None, None]
    phase = -(SUBBAND_FREQ[:, 0] * jj + SUBBAND_FREQ[:, 1] * ii)
    out = (np.exp(1j * phase) * FIX).astype(np.complex64)
    out.setflags(write=False)
    return out


def _prepare_levels(crop: np.ndarray, origin: tuple[int, int]) -> dict[int, PreparedLevel]:
    hp = highpasses(crop, nlevels=NLEVELS, first=min(LEVELS))
    out: dict[int, PreparedLevel] = {}
    for level in LEVELS:
        c = hp[level]  # (h, w, C, 6)
        h, w, nch, _ = c.shape
        d = c.transpose(0, 1, 3, 2) * _demodulator(h, w)[:, :, :, None]  # (h, w, 6, C)
        d = d.reshape(h, w, 6 * nch)
        flt = d.view(np.float32)  # (h, w, 12 C) real/imag interleaved
        flt = cv2.sepFilter2D(flt, -1, _SPLINE_PREFILTER, _SPLINE_PREFILTER,
                              borderType=cv2.BORDER_REFLECT_101)
        coef = np.ascontiguousarray(flt).view(np.complex64).reshape(h, w, 6 * nch)
        out[level] = PreparedLevel(level=level, coef=coef, origin_px=origin)
    return out


def _round_out(v: float, block: int) -> int:
    return int(np.floor(v / block) * block)


def prepare_frame(image: np.ndarray, region: tuple[float, float, float, float] | None = None) -> PreparedFrame:
    """Prepare ``image`` (grey or RGB) for polar matching, whole or only over ``region``.

    ``region`` (x0, y0, x1, y1) in pixels is where hypotheses will be scored; it is rounded out
    to the 32-pixel block grid and clipped to the frame, and the crop transformed is the region
    plus ``KERNEL_MARGIN_PX`` on each side (clipped to the frame, where the padding is the same
    symmetric reflection as a full-frame preparation).
    """
    img = _checked_image(image)
    height, width, nch = img.shape
    hp = -(-height // BLOCK) * BLOCK
    wp = -(-width // BLOCK) * BLOCK
    if region is None:
        rx0, ry0, rx1, ry1 = 0, 0, wp, hp
        cx0, cy0, cx1, cy1 = 0, 0, wp, hp
    else:
        if not np.all(np.isfinite(region)):
            raise ValueError(f"region must be finite, got {region}")
        rx0 = max(0, _round_out(region[0], BLOCK))
        ry0 = max(0, _round_out(region[1], BLOCK))
        rx1 = min(wp, -_round_out(-region[2], BLOCK))
        ry1 = min(hp, -_round_out(-region[3], BLOCK))
        if rx1 <= rx0 or ry1 <= ry0:
            raise ValueError(f"region {region} does not overlap the {width}x{height} frame")
        m = KERNEL_MARGIN_PX
        cx0, cy0 = max(0, rx0 - m), max(0, ry0 - m)
        cx1, cy1 = min(wp, rx1 + m), min(hp, ry1 + m)
    # Symmetric padding only where the crop passes the frame's right/bottom edge.
    src = img[cy0:min(cy1, height), cx0:min(cx1, width)]
    pad_b, pad_r = cy1 - min(cy1, height), cx1 - min(cx1, width)
    if pad_b or pad_r:
        src = cv2.copyMakeBorder(src, 0, pad_b, 0, pad_r, cv2.BORDER_REFLECT)
        if src.ndim == 2:
            src = src[:, :, None]
    levels = _prepare_levels(np.ascontiguousarray(src, np.float32), (cx0, cy0))
    return PreparedFrame(width=width, height=height, channels=nch, levels=levels,
                         region=(rx0, ry0, rx1, ry1))


class FrameCache:
    """Prepared regions of the most recent frames, so each frame is prepared once per query area.

    ``get(key, image, box)`` returns a preparation whose valid box covers ``box`` (hypothesis
    centres), preparing the union of the old and new areas when the cloud moved outside the
    prepared region. At most ``max_frames`` frames are kept (oldest dropped first).
    """

    def __init__(self, max_frames: int = 4, full_frame_fraction: float = 0.6):
        self.max_frames = max_frames
        self.full_frame_fraction = full_frame_fraction
        self._items: dict[object, PreparedFrame] = {}
        self.preparations = 0

    def get(self, key: object, image: np.ndarray, box: tuple[float, float, float, float] | None) -> PreparedFrame:
        prep = self._items.get(key)
        if prep is not None and (box is None and prep.region == (0, 0, *_padded(prep)) or
                                 box is not None and prep.contains_box(box)):
            return prep
        h, w = image.shape[:2]
        region = None
        if box is not None:
            r = SUPPORT_RADIUS_PX
            want = [box[0] - r, box[1] - r, box[2] + r + 1, box[3] + r + 1]
            if prep is not None:
                x0, y0, x1, y1 = prep.region
                want = [min(want[0], x0), min(want[1], y0), max(want[2], x1), max(want[3], y1)]
            area = (want[2] - want[0]) * (want[3] - want[1])
            if area < self.full_frame_fraction * w * h:
                region = tuple(want)
        prep = prepare_frame(image, region)
        self.preparations += 1
        self._items.pop(key, None)
        self._items[key] = prep
        while len(self._items) > self.max_frames:
            self._items.pop(next(iter(self._items)))
        return prep


def _padded(prep: PreparedFrame) -> tuple[int, int]:
    return (-(-prep.width // BLOCK) * BLOCK, -(-prep.height // BLOCK) * BLOCK)
