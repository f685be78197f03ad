"""Random fields: smooth fractal noise for textures, and fast per-frame sensor noise."""

from __future__ import annotations

import cv2
import numpy as np
from scipy.special import ndtri


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
    (Gaussian quantiles, truncated at about +-2.7 sigma), saturating at 0 and 255. Random bytes and
    two table look-ups keep this to a few milliseconds per 1280x720 frame.
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
        u = random_bytes(rng, img.size).reshape(img.shape)
        out = cv2.add(img, cv2.LUT(u, self._pos))
        return cv2.subtract(out, cv2.LUT(u, self._neg))


def random_bytes(rng: np.random.Generator, n: int) -> np.ndarray:
    """``np.frombuffer(rng.bytes(n), np.uint8)`` without its two copies: ``Generator.bytes`` draws
    ``(n - 1) // 4 + 1`` uint32 with ``integers`` and returns their little-endian bytes; the
    same draw, viewed as bytes (tested against ``rng.bytes``)."""
    words = rng.integers(0, 4294967296, size=(n - 1) // 4 + 1, dtype=np.uint32).astype("<u4", copy=False)
    return words.view(np.uint8)[:n]
