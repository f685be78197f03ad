"""Random fields: smooth fractal noise for textures, and fast per-frame sensor noise."""

from __future__ import annotations

import cv2
import numpy as np
from scipy.special import ndtri

from .pixel_loops import add_noise


def smooth_noise(rng: np.random.Generator, shape: tuple[int, int], cell: int) -> np.ndarray:
    """Smooth noise of roughly unit std with features about ``cell`` pixels across (float32)."""
    h, w = shape
    if cell <= 1:
        return rng.standard_normal((h, w), dtype=np.float32)
    gh, gw = h // cell + 4, w // cell + 4
    g = rng.standard_normal((gh, gw), dtype=np.float32)
    big = cv2.resize(g, (gw * cell, gh * cell), interpolation=cv2.INTER_CUBIC)
    out = big[cell: cell + h, cell: cell + w]
    # cubic interpolation between unit-variance lattice values loses some variance
    return out * np.float32(1.0 / max(float(out.std()), 1e-6))


def fractal_noise(
    rng: np.random.Generator, shape: tuple[int, int], cells: tuple[int, ...], amps: tuple[float, ...]
) -> np.ndarray:
    """Sum of ``smooth_noise`` octaves, normalised to roughly unit std (float32)."""
    acc = np.zeros(shape, np.float32)
    for cell, amp in zip(cells, amps):
        acc += np.float32(amp) * smooth_noise(rng, shape, int(cell))
    return acc * np.float32(1.0 / np.sqrt(sum(a * a for a in amps)))


class SensorNoise:
    """Additive, approximately Gaussian noise of std ``sigma`` grey levels, integer valued.

    Each pixel channel takes one random byte ``b`` and adds ``round(sigma * Phi^-1((b + 0.5) / 256))``
    (Gaussian quantiles, truncated at about +-2.7 sigma), saturating at 0 and 255: as
    ``cv2.subtract(cv2.add(img, LUT(b, pos)), LUT(b, neg))`` with the positive and negative parts
    of the quantile table, in one numba pass (:func:`.pixel_loops.add_noise`, 3x quicker).
    """

    def __init__(self, sigma: float):
        self.sigma = float(sigma)
        q = np.round(self.sigma * ndtri((np.arange(256) + 0.5) / 256.0))
        self._pos = np.clip(q, 0, 255).astype(np.uint8)
        self._neg = np.clip(-q, 0, 255).astype(np.uint8)

    def apply(self, img: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """``img`` (uint8) plus noise drawn from ``rng``; returns a new array."""
        if self.sigma <= 0:
            return img.copy()
        src = np.ascontiguousarray(img)
        out = np.empty_like(src)
        add_noise(src.reshape(-1), random_bytes(rng, src.size), self._pos, self._neg, out.reshape(-1))
        return out


def random_bytes(rng: np.random.Generator, n: int) -> np.ndarray:
    """``np.frombuffer(rng.bytes(n), np.uint8)`` without its two copies: ``Generator.bytes`` draws
    ``(n - 1) // 4 + 1`` uint32 with ``integers`` and returns their little-endian bytes; the
    same draw, viewed as bytes (tested against ``rng.bytes``).

    PCG64 makes a uint32 as the low, then (buffered) the high half of one 64-bit output, so an
    even number of uint32 drawn with nothing buffered are exactly the raw 64-bit outputs viewed
    as bytes, and leave nothing buffered: that case takes ``random_raw``, twice as fast.
    """
    words = (n - 1) // 4 + 1
    bitgen = rng.bit_generator
    if words % 2 == 0 and type(bitgen) is np.random.PCG64 and not bitgen.state["has_uint32"]:
        raw = bitgen.random_raw(words // 2).astype("<u8", copy=False)
        return raw.view(np.uint8)[:n]
    drawn = rng.integers(0, 4294967296, size=words, dtype=np.uint32).astype("<u4", copy=False)
    return drawn.view(np.uint8)[:n]
