"""The target template: the P-matrix of the target, built once from an image and a centre."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from common.detector.frame import prepare_frame
from common.detector.layout import N_COLUMNS, N_ROWS, SUPPORT_RADIUS_PX
from common.detector.sampler import sample_pmatrices

FORMAT_VERSION = 1


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
        pm = sample_pmatrices(prep, x, y, np.array([True]))[0]
        if not np.any(pm):
            raise ValueError("template region is flat (all-zero wavelet coefficients)")
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
