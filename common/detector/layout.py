"""Constants of the P-matrix construction, in one place (polar-matching spec sections 2-5).

Angles are anticlockwise *as displayed* (image row 0 at the top, y down). Level ``l`` of the
DTCWT has coefficients every ``2**l`` pixels; coefficient ``[i, j]`` is centred on pixel
``x = 2**l (j + 0.5) - 0.5`` (same for y with i).
"""

from __future__ import annotations

import numpy as np

NLEVELS = 5
"""Depth of the transform; frames are padded to a multiple of ``2**NLEVELS`` pixels."""

BLOCK = 2**NLEVELS
"""Pyramid block size in pixels: a region's origin and size are multiples of this."""

LEVELS = (2, 3, 4, 5)
"""Levels used (level 1 is too poorly sampled to be rotation invariant)."""

N_ROWS = 12
"""P-matrix rows: one row down = the image rotated 30 degrees anticlockwise."""

N_ANGLES = 48
"""Angle grid of the correlation (7.5 degrees, zero padding factor 4)."""

FIX = np.array([1j, -1j, 1j, -1, 1, -1], dtype=np.complex128)
"""Per-subband phase fix so that the twelve directional values rotate into each other."""

_S5 = np.sqrt(5.0)
SUBBAND_FREQ = (np.pi / 2.15) * np.array(
    [[-1, -3], [-_S5, -_S5], [-3, -1], [-3, 1], [-_S5, _S5], [-1, 3]], dtype=np.float64
)
"""Nominal centre frequency (wx, wy_down) of each subband, radians per coefficient sample,
for the ``_bp`` filters (spec section 2 table)."""

RINGS: tuple[tuple[int, int], ...] = ((2, 1), (2, 2), (3, 1), (3, 2), (4, 1))
"""Rings as (level, radius in level samples); every used level also has a centre column."""

DESIGN_TARGET_PX = 48
"""The target length (matched pixels) the layout is designed for: a ~50 px car, its rings (out to
16 px from the centre) on the car and the level-5 centre column's kernel the context about it
(``ScaleSettings.target_size_px`` upsamples smaller targets to this)."""

KC_GAIN = 0.8 * 1.6 * np.pi
"""Derived: a ring column's harmonic centre is round(KC_GAIN * rho * sin(15 + 30 s deg))."""


def ring_offsets(rho: float) -> np.ndarray:
    """(12, 2) offsets (dx, dy) in level samples of the ring points, phi_n = 90 + 30 n degrees."""
    phi = np.deg2rad(90.0 + 30.0 * np.arange(N_ROWS))
    return np.stack([rho * np.cos(phi), -rho * np.sin(phi)], axis=1)


def column_harmonics(kc_sign: float = 1.0) -> np.ndarray:
    """Harmonic centre k_c of each of the 34 columns of one channel, in P-matrix column order.

    Column order: for each level 2..5, its centre column then its rings by increasing radius
    (6 columns s = 0..5 per ring). ``kc_sign`` exists for the negative controls only.
    """
    s = np.arange(6)
    out: list[int] = []
    for level in LEVELS:
        out.append(0)
        for lvl, rho in RINGS:
            if lvl == level:
                k = np.round(KC_GAIN * rho * np.sin(np.deg2rad(15.0 + 30.0 * s))).astype(int)
                out.extend(int(v) for v in kc_sign * k)
    return np.asarray(out, dtype=np.int64)


def points_per_level() -> dict[int, np.ndarray]:
    """Sample points of each level as (P, 2) offsets in level samples: centre first, then rings."""
    pts: dict[int, np.ndarray] = {}
    for level in LEVELS:
        rows = [np.zeros((1, 2))]
        for lvl, rho in RINGS:
            if lvl == level:
                rows.append(ring_offsets(rho))
        pts[level] = np.concatenate(rows, axis=0)
    return pts


N_COLUMNS = len(column_harmonics())
"""P-matrix columns per colour channel (34 with the default layout)."""

SUPPORT_RADIUS_PX = max(
    (max((rho for lvl, rho in RINGS if lvl == level), default=0) + 2) * 2**level for level in LEVELS
)
"""Radius in pixels about a hypothesis inside which every sampled coefficient's cubic-spline taps
lie: ``max_l (rho_max(l) + 2) * 2**l`` = 64 px with the default layout (set by level 5's centre
taps). A hypothesis closer than this to the frame edge is out of support: score 0 and a flag."""


def destinations() -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """Where each sampled value goes in the (12, N_COLUMNS) P-matrix of one channel.

    For each level: arrays ``(rows, cols, conj, count)`` of shapes (P, 6, 2), (P, 6, 2),
    (P, 6, 2), (P, 6) indexed by sample point ``p`` (as in :func:`points_per_level`) and subband
    ``k``: the value ``FIX_k c_k(point)`` is written to ``count`` places, conjugated where ``conj``.

    Centre point: ``D_k`` in row ``k`` and ``D_{k+6} = conj(D_k)`` in row ``k + 6``.
    Ring point ``n`` (row ``n``): ``P[n, s] = D_{(n+s) mod 12}``, so subband ``k`` lands in the one
    column ``s = (m - n) mod 12 < 6`` with ``m`` in ``{k, k + 6}``, conjugated when ``m >= 6``.
    """
    out = {}
    col = 0
    for level in LEVELS:
        rings = [rho for lvl, rho in RINGS if lvl == level]
        npts = 1 + 12 * len(rings)
        rows = np.zeros((npts, 6, 2), np.int64)
        cols = np.zeros((npts, 6, 2), np.int64)
        conj = np.zeros((npts, 6, 2), np.bool_)
        count = np.zeros((npts, 6), np.int64)
        for k in range(6):
            rows[0, k] = (k, k + 6)
            cols[0, k] = (col, col)
            conj[0, k] = (False, True)
            count[0, k] = 2
        col += 1
        for ring_i in range(len(rings)):
            for n in range(N_ROWS):
                p = 1 + 12 * ring_i + n
                for k in range(6):
                    for m in (k, k + 6):
                        s = (m - n) % 12
                        if s < 6:
                            rows[p, k, 0] = n
                            cols[p, k, 0] = col + s
                            conj[p, k, 0] = m >= 6
                            count[p, k] = 1
            col += 6
        out[level] = (rows, cols, conj, count)
    return out
