"""The target template: the P-matrix of the target, built once from an image and a centre."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from common.detector.frame import prepare_frame
from common.detector.layout import N_COLUMNS, N_ROWS, SUPPORT_RADIUS_PX, column_harmonics
from common.detector.sampler import sample_pmatrices

FORMAT_VERSION = 1


class FlatTemplateError(ValueError):
    """The template's footprint holds no texture (every wavelet coefficient zero): an exactly uniform
    region, e.g. a black first frame, gives nothing to match."""


def check_textured(pmatrix: np.ndarray) -> np.ndarray:
    """``pmatrix``, or FlatTemplateError when it is all zero."""
    if not np.any(pmatrix):
        raise FlatTemplateError("template region is flat (all-zero wavelet coefficients)")
    return pmatrix


@dataclass(frozen=True)
class Template:
    pmatrix: np.ndarray
    """(12, 34 * C) complex64 P-matrix of the target (C = 1 grey, 3 RGB)."""
    centre: tuple[float, float]
    """Pixel (x, y) in the source image the template was taken at."""
    box: tuple[float, float, float, float] | None = None
    """Optional target box (x, y, w, h) in the source image, kept for display and scale."""

    @property
    def channels(self) -> int:
        return self.pmatrix.shape[1] // N_COLUMNS

    @classmethod
    def from_image(cls, image: np.ndarray, centre: tuple[float, float],
                   box: tuple[float, float, float, float] | None = None) -> "Template":
        """Build the template at pixel ``centre`` of ``image`` (grey or RGB)."""
        cx, cy = (float(v) for v in centre)
        if not (np.isfinite(cx) and np.isfinite(cy)):
            raise ValueError(f"template centre must be finite, got {centre}")
        r = SUPPORT_RADIUS_PX
        prep = prepare_frame(image, (cx - r, cy - r, cx + r + 1, cy + r + 1))
        x, y = np.array([cx]), np.array([cy])
        if not prep.in_support(x, y)[0]:
            h, w = np.asarray(image).shape[:2]
            raise ValueError(
                f"template centre ({cx:g}, {cy:g}) is too close to the edge of the {w}x{h} image: "
                f"it must be at least {r} px inside it"
            )
        pm = check_textured(sample_pmatrices(prep, x, y, np.array([True]))[0])
        return cls(pmatrix=pm, centre=(cx, cy), box=None if box is None else tuple(float(v) for v in box))

    def save(self, path: str | Path) -> None:
        """Write the template as a small ``.npz`` file (about 10 kB for RGB)."""
        meta = {"format": FORMAT_VERSION, "centre": self.centre, "box": self.box}
        with open(path, "wb") as fh:
            np.savez_compressed(fh, pmatrix=self.pmatrix, meta=np.array(json.dumps(meta)))

    @classmethod
    def load(cls, path: str | Path) -> "Template":
        try:
            with np.load(path, allow_pickle=False) as z:
                pm = z["pmatrix"]
                meta = json.loads(str(z["meta"]))
        except (OSError, KeyError, ValueError) as exc:
            raise ValueError(f"{path}: not a PolarTrack template file ({exc})") from exc
        if meta.get("format") != FORMAT_VERSION:
            raise ValueError(f"{path}: template format {meta.get('format')} is not supported")
        if pm.ndim != 2 or pm.shape[0] != N_ROWS or pm.shape[1] % N_COLUMNS:
            raise ValueError(f"{path}: P-matrix has shape {pm.shape}, expected (12, 34 * C)")
        box = meta.get("box")
        return cls(pmatrix=pm.astype(np.complex64), centre=tuple(meta["centre"]),
                   box=None if box is None else tuple(box))


def rotate_pmatrix(pmatrix: np.ndarray, theta_deg: float, kc: np.ndarray | None = None) -> np.ndarray:
    """The P-matrix of the image rotated anticlockwise (as displayed) by ``theta_deg`` about the
    P-matrix centre, from the same band-limited model the matcher correlates with.

    Column ``c``'s 12 rows are samples at 30 degree steps of an angular signal whose harmonics
    are ``k_c - 6 .. k_c + 6`` (:func:`common.detector.layout.column_harmonics`; the two edge
    harmonics share one DFT bin and get half of it each). Rotating by ``theta`` multiplies
    harmonic ``h`` by ``exp(-i h theta)``; at ``theta = 30 r`` degrees this is exactly
    ``np.roll(pmatrix, r, axis=0)``. ``rotate_pmatrix(P, -theta)`` turns a P-matrix sampled on a
    target rotated by ``theta`` back to the template's orientation.
    """
    P = np.asarray(pmatrix)
    if P.ndim != 2 or P.shape[0] != N_ROWS or P.shape[1] % N_COLUMNS:
        raise ValueError(f"expected a (12, 34 C) P-matrix, got shape {P.shape}")
    kc_one = column_harmonics() if kc is None else np.asarray(kc, np.int64)
    kc_all = np.tile(kc_one, P.shape[1] // N_COLUMNS)
    th = np.deg2rad(float(theta_deg))
    X = np.fft.fft(P.astype(np.complex128), axis=0)  # (12, M): DFT bin j of each column
    # factor[j, c]: sum over the harmonics h == j (mod 12) of column c's band of w_h exp(-i h theta)
    factor = np.zeros((N_ROWS, P.shape[1]), np.complex128)
    for d in range(-6, 7):
        h = kc_all + d
        wgt = 0.5 if abs(d) == 6 else 1.0
        factor[h % N_ROWS, np.arange(P.shape[1])] += wgt * np.exp(-1j * h * th)
    return np.fft.ifft(X * factor, axis=0).astype(np.complex64)


def correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Normalised correlation ``Re <a, b> / (|a| |b|)`` of two P-matrices (0 if either is zero)."""
    na, nb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
    if na == 0 or nb == 0:
        return 0.0
    return float(np.real(np.vdot(a, b)) / (na * nb))
