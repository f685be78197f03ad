"""Polar matching scores: the template against many hypotheses, at 48 angles or at given angles.

With template P-matrix ``H`` and a candidate's ``F`` (spec section 5): ``S = conj(FFT_rows(H)) *
FFT_rows(F)``; the 12 harmonics of column ``c`` are centred on its own harmonic ``k_c`` (the
zero padding "placed according to the column number"), giving the band-limited correlation

    r(theta) = sum_c sum_{h = k_c - 6}^{k_c + 6} w_h S[h mod 12, c] exp(i h theta),

with ``w = 1/2`` at the two edge harmonics (the same DFT bin). ``score = Re r / (12 |H| |F|)``,
in [-1, 1]. Harmonics run from -6 to 14, so ``r`` is exactly representable on the 48-angle grid
(inverse FFT) and is evaluated directly at any requested angle.
"""

from __future__ import annotations

import numpy as np

from common.detector.frame import PreparedFrame
from common.detector.layout import N_ANGLES, N_ROWS, column_harmonics
from common.detector.sampler import sample_columns
from common.detector.template import Template

ANGLES_DEG = np.arange(N_ANGLES) * (360.0 / N_ANGLES)
"""The 48-angle grid: 0, 7.5, ..., 352.5 degrees (anticlockwise as displayed)."""


class PolarMatcher:
    """Scores hypotheses against one template. Stateless apart from the template's spectra."""

    def __init__(self, template: Template, kc: np.ndarray | None = None):
        self.template = template
        H = np.asarray(template.pmatrix, np.complex64)  # (12, M) canonical column order
        nch = template.channels
        kc_one = column_harmonics() if kc is None else np.asarray(kc, np.int64)
        kc_all = np.tile(kc_one, nch)
        m = kc_all.size
        self._norm_h = float(np.linalg.norm(H))
        self.h_min = int(kc_all.min()) - 6
        self.h_max = int(kc_all.max()) + 6
        if self.h_max - self.h_min >= N_ANGLES:
            raise ValueError("column harmonics span too wide for the 48-angle grid")
        nh = self.h_max - self.h_min + 1
        # place[c, j, h]: weight of DFT bin j of column c in harmonic h (12 bins centred on k_c,
        # the two edge harmonics sharing one bin at half weight).
        place = np.zeros((m, N_ROWS, nh))
        for c, k in enumerate(kc_all):
            for d in range(-6, 7):
                place[c, (k + d) % N_ROWS, k + d - self.h_min] += 0.5 if abs(d) == 6 else 1.0
        # The row FFT of F, the product with conj(FFT_rows(H)), the placement of each column's
        # bins on the harmonics and the sum over columns are all linear in F: one (M * 12,
        # n_harmonics) matrix W does them, spec = F (N, M * 12) @ W. One complex64 product is about
        # 2.5x quicker than the four steps it replaced (500 candidates: 3.0 -> 1.3 ms). W is
        # built in complex128.
        dft = np.exp(-2j * np.pi * np.outer(np.arange(N_ROWS), np.arange(N_ROWS)) / N_ROWS)  # [r, j]
        hc = np.conj(np.fft.fft(H.astype(np.complex128), axis=0)).T  # (M, 12) [c, j]
        w = np.einsum("rj,cj,cjk->crk", dft, hc, place)  # (M, 12 rows, nh)
        self._w = np.ascontiguousarray(w.reshape(m * N_ROWS, nh), np.complex64)
        self.harmonics = np.arange(self.h_min, self.h_max + 1)

    # -- core -----------------------------------------------------------------------------
    def spectra(self, cols: np.ndarray, norm2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Correlation spectra (N, n_harmonics) and norms |F| (N,) of candidates sampled by
        :meth:`sample` (shape (N, M, 12)): one matrix product with W."""
        spec = cols.reshape(cols.shape[0], -1) @ self._w  # (N, nh)
        return spec, np.sqrt(norm2)

    def _denominator(self, norm_f: np.ndarray) -> np.ndarray:
        den = N_ROWS * self._norm_h * norm_f
        return np.where(den > 0, den, np.inf)

    def grid_from_spectra(self, spec: np.ndarray, norm_f: np.ndarray) -> np.ndarray:
        n = spec.shape[0]
        full = np.zeros((n, N_ANGLES), np.complex128)
        full[:, self.harmonics % N_ANGLES] = spec
        r = np.fft.ifft(full, axis=1) * N_ANGLES
        return r.real / self._denominator(norm_f)[:, None]

    def at_from_spectra(self, spec: np.ndarray, norm_f: np.ndarray, theta_deg: np.ndarray) -> np.ndarray:
        th = np.deg2rad(np.asarray(theta_deg, np.float64))
        basis = np.exp(1j * th[:, None] * self.harmonics[None, :])
        r = np.einsum("nh,nh->n", spec, basis)
        return r.real / self._denominator(norm_f)

    # -- public ---------------------------------------------------------------------------
    def sample(self, prep: PreparedFrame, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Candidate P-matrix columns (N, M, 12), squared norms (N,) and support flags (N,)."""
        if prep.channels != self.template.channels:
            raise ValueError(
                f"frame has {prep.channels} channel(s) but the template was built from "
                f"{self.template.channels}: use the same colour mode for both"
            )
        valid = prep.in_support(xy[:, 0], xy[:, 1])
        cols, norm2 = sample_columns(prep, xy[:, 0], xy[:, 1], valid)
        return cols, norm2, valid

    def score_grid(self, prep: PreparedFrame, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Scores (N, 48) at ``ANGLES_DEG`` for hypotheses ``xy`` (N, 2) pixels; and valid (N,)."""
        xy = check_hypotheses(xy, 2)
        cols, norm2, valid = self.sample(prep, xy)
        spec, nf = self.spectra(cols, norm2)
        s = self.grid_from_spectra(spec, nf)
        s[~valid] = 0.0
        return s, valid

    def score_at(self, prep: PreparedFrame, xyt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Scores (N,) of hypotheses ``(x, y, theta_deg)`` (N, 3) at exactly their angle; valid (N,)."""
        xyt = check_hypotheses(xyt, 3)
        cols, norm2, valid = self.sample(prep, xyt[:, :2])
        spec, nf = self.spectra(cols, norm2)
        s = self.at_from_spectra(spec, nf, xyt[:, 2])
        s[~valid] = 0.0
        return s, valid

    def refine_peak(self, prep: PreparedFrame, x: float, y: float) -> tuple[float, float, np.ndarray]:
        """Best angle (degrees, in (-180, 180]) and score at one point, refined between grid
        bins on the band-limited curve; also returns the 48 grid scores."""
        xy = check_hypotheses(np.array([[x, y]]), 2)
        cols, norm2, valid = self.sample(prep, xy)
        if not valid[0]:
            return 0.0, 0.0, np.zeros(N_ANGLES)
        spec, nf = self.spectra(cols, norm2)
        grid = self.grid_from_spectra(spec, nf)[0]
        best = float(ANGLES_DEG[int(np.argmax(grid))])
        # golden-section search of the band-limited curve within one grid step of the best bin
        lo, hi = best - 7.5, best + 7.5
        f = lambda t: float(self.at_from_spectra(spec, nf, np.array([t]))[0])  # noqa: E731
        g = (np.sqrt(5.0) - 1) / 2
        a, b = hi - g * (hi - lo), lo + g * (hi - lo)
        fa, fb = f(a), f(b)
        for _ in range(60):
            if fa > fb:
                hi, b, fb = b, a, fa
                a = hi - g * (hi - lo)
                fa = f(a)
            else:
                lo, a, fa = a, b, fb
                b = lo + g * (hi - lo)
                fb = f(b)
        theta = 0.5 * (lo + hi)
        score = f(theta)
        theta = (theta + 180.0) % 360.0 - 180.0
        if theta <= -180.0:
            theta += 360.0
        return theta, score, grid


def check_hypotheses(arr: np.ndarray, ncols: int) -> np.ndarray:
    """Hypotheses as a float64 (N, ncols) array; NaN or infinite values raise ValueError."""
    a = np.asarray(arr, np.float64)
    if a.ndim == 1 and a.shape[0] == ncols:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != ncols:
        raise ValueError(f"hypotheses must have shape (N, {ncols}), got {np.shape(arr)}")
    if not np.all(np.isfinite(a)):
        bad = np.flatnonzero(~np.all(np.isfinite(a), axis=1))
        raise ValueError(f"hypotheses contain NaN or infinite coordinates (rows {bad[:5].tolist()})")
    return a
