"""Sampling P-matrices of many hypotheses from a prepared frame, in one compiled loop.

For each hypothesis and each level: the sample position of every P-matrix point, a 4x4 cubic
B-spline tap sum over all ``6 * C`` prepared subbands at once (the taps are shared by subbands
and channels), remodulation by each subband's centre frequency, and the scatter into the
P-matrix (spec sections 3-4). Building P-matrices point by point in Python costs ~1.4 ms each;
this loop is compiled with numba.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numba
import numpy as np

from common.detector.frame import PreparedFrame
from common.detector.threads import run_chunks
from common.detector.layout import LEVELS, N_COLUMNS, N_ROWS, SUBBAND_FREQ, destinations, points_per_level

_POINTS = {lvl: np.ascontiguousarray(p, np.float64) for lvl, p in points_per_level().items()}
_DEST = destinations()
_FREQ = np.ascontiguousarray(SUBBAND_FREQ, np.float64)
_ROT = {}
for _lvl, _pts in _POINTS.items():
    _ph = _pts @ SUBBAND_FREQ.T  # (P, 6): w_s . offset_p
    _ROT[_lvl] = np.ascontiguousarray(np.stack([np.cos(_ph), np.sin(_ph)], axis=-1))


@numba.njit(cache=True, nogil=True, fastmath=True)
def _sample_level(coef, scale, ox, oy, xs, ys, valid, rot, freq, didx, dsign, dcount,
                  offs, nch, out, norm2):
    """Sample one level for every valid hypothesis into ``out[n]`` (float32 real/imag pairs).

    ``coef`` is float32 (h, w * 2K): per row, the real/imag pairs of the K = 6 * C prepared
    subbands of each column, so each of the 4 tap rows is one contiguous run of 4 * 2K floats.
    Remodulation ``exp(i w.(u, v))`` at point ``p`` is the hypothesis' phase times the fixed
    ``rot[p, s] = exp(i w_s . offset_p)``. Value (p, s, ch) goes to the ``dcount[p, s]`` complex
slots ``didx[p, s, ch, d]`` with imaginary sign ``dsign`` (conjugated where -1).
``norm2[n]`` accumulates ``|F|^2``.
    """
    h = coef.shape[0]
    K2 = 12 * nch
    w = coef.shape[1] // K2
    n_hyp = xs.shape[0]
    n_pts = offs.shape[0]
    acc = np.empty(K2, np.float32)
    col4 = np.empty(4 * K2, np.float32)
    wu = np.empty(4, np.float32)
    e0r = np.empty(6)
    e0i = np.empty(6)
    for n in range(n_hyp):
        if not valid[n]:
            continue
        u0 = (xs[n] - ox + 0.5) / scale - 0.5
        v0 = (ys[n] - oy + 0.5) / scale - 0.5
        for s in range(6):
            ph = freq[s, 0] * u0 + freq[s, 1] * v0
            e0r[s] = math.cos(ph)
            e0i[s] = math.sin(ph)
        nrm = 0.0
        for p in range(n_pts):
            u = u0 + offs[p, 0]
            v = v0 + offs[p, 1]
            iu = math.floor(u)
            iv = math.floor(v)
            t = u - iu
            t2 = t * t
            t3 = t2 * t
            wu[0] = (1 - t) ** 3 / 6.0
            wu[1] = (3 * t3 - 6 * t2 + 4) / 6.0
            wu[2] = (-3 * t3 + 3 * t2 + 3 * t + 1) / 6.0
            wu[3] = t3 / 6.0
            t = v - iv
            t2 = t * t
            t3 = t2 * t
            wv0 = np.float32((1 - t) ** 3 / 6.0)
            wv1 = np.float32((3 * t3 - 6 * t2 + 4) / 6.0)
            wv2 = np.float32((-3 * t3 + 3 * t2 + 3 * t + 1) / 6.0)
            wv3 = np.float32(t3 / 6.0)
            c0 = min(max(iu - 1, 0), w - 4) * K2
            r0 = min(max(iv - 1, 0), h - 1)
            r1 = min(max(iv, 0), h - 1)
            r2 = min(max(iv + 1, 0), h - 1)
            r3 = min(max(iv + 2, 0), h - 1)
            a0 = coef[r0, c0:c0 + 4 * K2]
            a1 = coef[r1, c0:c0 + 4 * K2]
            a2 = coef[r2, c0:c0 + 4 * K2]
            a3 = coef[r3, c0:c0 + 4 * K2]
            for k in range(4 * K2):
                col4[k] = wv0 * a0[k] + wv1 * a1[k] + wv2 * a2[k] + wv3 * a3[k]
            wb0, wb1, wb2, wb3 = wu[0], wu[1], wu[2], wu[3]
            for k in range(K2):
                acc[k] = (wb0 * col4[k] + wb1 * col4[K2 + k] + wb2 * col4[2 * K2 + k]
                          + wb3 * col4[3 * K2 + k])
            for s in range(6):
                er = e0r[s] * rot[p, s, 0] - e0i[s] * rot[p, s, 1]
                ei = e0r[s] * rot[p, s, 1] + e0i[s] * rot[p, s, 0]
                cnt = dcount[p, s]
                for ch in range(nch):
                    k = 2 * (s * nch + ch)
                    vr = acc[k] * er - acc[k + 1] * ei
                    vi = acc[k] * ei + acc[k + 1] * er
                    nrm += cnt * (vr * vr + vi * vi)
                    for d in range(cnt):
                        j = 2 * didx[p, s, ch, d]
                        out[n, j] = vr
                        out[n, j + 1] = dsign[p, s, d] * vi
        norm2[n] += nrm


@lru_cache(maxsize=4)
def _dest_tables(nch: int) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per level: flat complex slot ``col * 12 + row`` (P, 6, C, 2), imaginary sign (P, 6, 2)
    and count (P, 6) of each sampled value, columns in canonical order (channel-major)."""
    out = {}
    for level, (rows, cols, conj, count) in _DEST.items():
        idx = np.zeros(rows.shape[:2] + (nch, 2), np.int64)
        for ch in range(nch):
            idx[:, :, ch, :] = (cols + ch * N_COLUMNS) * N_ROWS + rows
        sign = np.where(conj, -1.0, 1.0).astype(np.float32)
        out[level] = (idx, sign, count)
    return out


def sample_columns(prep: PreparedFrame, x: np.ndarray, y: np.ndarray,
                   valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """P-matrices transposed, (N, 34 C, 12) complex64, columns in canonical order, and their
    squared norms (N,). Zero where not ``valid``.

    Callers make sure ``valid`` hypotheses are in support (``prep.in_support``): taps outside
    the prepared grid are clamped, never read out of bounds, but give meaningless values.
    """
    x = np.ascontiguousarray(x, np.float64)
    y = np.ascontiguousarray(y, np.float64)
    valid = np.ascontiguousarray(valid, np.bool_)
    m = N_COLUMNS * prep.channels
    tables = _dest_tables(prep.channels)
    out = np.zeros((x.shape[0], m * N_ROWS * 2), np.float32)
    norm2 = np.zeros(x.shape[0], np.float64)
    levels = []
    for level in LEVELS:
        lv = prep.levels[level]
        idx, sign, count = tables[level]
        flat = lv.coef.view(np.float32).reshape(lv.coef.shape[0], -1)
        levels.append((flat, float(2**level), float(lv.origin_px[0]), float(lv.origin_px[1]),
                       _ROT[level], idx, sign, count, _POINTS[level]))

    def sample(a: int, b: int) -> None:
        for flat, scale, ox, oy, rot, idx, sign, count, pts in levels:
            _sample_level(flat, scale, ox, oy, x[a:b], y[a:b], valid[a:b], rot, _FREQ, idx, sign, count, pts,
                          prep.channels, out[a:b], norm2[a:b])

    run_chunks(sample, x.shape[0])
    return out.view(np.complex64).reshape(x.shape[0], m, N_ROWS), norm2


def sample_pmatrices(prep: PreparedFrame, x: np.ndarray, y: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """P-matrices (N, 12, 34 C) complex64 at pixel centres ``(x, y)``; zero where not ``valid``."""
    cols, _ = sample_columns(prep, x, y, valid)
    return np.ascontiguousarray(cols.transpose(0, 2, 1))
