"""Messages <-> the library's objects (no bus code): estimates, particle clouds, templates, frames."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from common.detector.layout import N_COLUMNS, N_ROWS
from common.detector.template import Template
from common.msgs import Estimate, FrameInfo, ParticleCloud, pack, unpack
from common.msgs import Template as TemplateMsg


def estimate_msg(frame_index: int, capture_ns: int, state, filter_name: str, skipped: int = 0,
                 step_ms: float = 0.0) -> Estimate:
    m, mm = state.map_estimate, state.mmse_estimate
    return Estimate(
        frame_index=frame_index, time_s=state.time, observed=state.observed, filter=filter_name,
        x=m.image_x, y=m.image_y, theta_deg=m.theta, p_visible=state.p_visible, world_x=m.x, world_y=m.y,
        vx=m.vx, vy=m.vy, speed=state.speed, mmse_x=mm.image_x, mmse_y=mm.image_y,
        n_eff=float(state.n_eff) if np.isfinite(state.n_eff) else 0.0, resampled=bool(state.resampled),
        frames_skipped=skipped, step_ms=step_ms, latency_ms=(time.time_ns() - capture_ns) / 1e6,
        w=state.size[0] if state.size else 0.0, h=state.size[1] if state.size else 0.0,
        reacquired=bool(state.reacquired))


CLOUD_DTYPE = np.float32
"""The particle cloud is for display (the Rerun viewer, Foxglove's annotations): float32 holds a
pixel or a ground position to far below a pixel and halves what every frame's cloud records."""


def particles_msg(frame_index: int, state) -> ParticleCloud | None:
    if state.particles is None:
        return None
    n = len(state.particles)
    pv = state.particle_visibility if state.particle_visibility is not None else np.full(n, state.p_visible)
    return ParticleCloud(frame_index=frame_index, time_s=state.time, count=n,
                         particles=pack(state.particles, CLOUD_DTYPE), image_xy=pack(state.particles_image, CLOUD_DTYPE),
                         weights=pack(state.weights, CLOUD_DTYPE), p_visible=pack(pv, CLOUD_DTYPE))


@dataclass(frozen=True)
class Cloud:
    """A decoded ``ParticleCloud``: world states (n, 5: x, vx, y, vy, theta), image positions
    (n, 2), weights and p(visible) (n,), as float64."""

    states: np.ndarray
    image_xy: np.ndarray
    weights: np.ndarray
    p_visible: np.ndarray | None


def cloud_field(data: bytes, n: int, width: int | None) -> np.ndarray:
    """One array of a ``ParticleCloud``: float32 (what the tracker publishes) or float64 (what
    recordings before it hold), told apart by the byte count; ValueError for any other size."""
    shape = (n,) if width is None else (n, width)
    items = n * (width or 1)
    dtype = np.float32 if items and len(data) == 4 * items else np.float64
    return unpack(data, dtype, shape).astype(np.float64)


def msg_to_cloud(msg: ParticleCloud) -> Cloud:
    """The arrays of a cloud; ValueError when a size disagrees with its count."""
    n = int(msg.count)
    return Cloud(states=cloud_field(msg.particles, n, 5), image_xy=cloud_field(msg.image_xy, n, 2),
                 weights=cloud_field(msg.weights, n, None),
                 p_visible=cloud_field(msg.p_visible, n, None) if msg.p_visible else None)


def template_to_msg(t: Template, version: int, frame_index: int) -> TemplateMsg:
    return TemplateMsg(version=version, rows=t.pmatrix.shape[0], columns=t.pmatrix.shape[1],
                       pmatrix=np.ascontiguousarray(t.pmatrix, np.complex64).tobytes(), centre_x=t.centre[0],
                       centre_y=t.centre[1], box=list(t.box or ()), frame_index=frame_index)


def pmatrix_from_bytes(data: bytes, rows: int, columns: int) -> np.ndarray:
    """A (12, 34 C) complex64 P-matrix from its bytes; ValueError for any other shape or size."""
    if rows != N_ROWS or columns % N_COLUMNS or columns == 0:
        raise ValueError(f"P-matrix {rows}x{columns}, expected 12 x 34C")
    return unpack(data, np.complex64, (rows, columns))


def msg_to_template(m: TemplateMsg) -> Template:
    pm = pmatrix_from_bytes(m.pmatrix, m.rows, m.columns)
    return Template(pmatrix=pm, centre=(m.centre_x, m.centre_y), box=tuple(m.box) if len(m.box) == 4 else None)


def info_homography(info: FrameInfo) -> np.ndarray | None:
    return np.asarray(info.homography, float).reshape(3, 3) if len(info.homography) == 9 else None


@dataclass(frozen=True)
class InfoFrame:
    """A frame as the bus describes it (a FrameInfo), with its pixels only where they were taken
    (a stabilising tracker): what :class:`common.runner.Tracker` steps on outside the process
    that reads the source."""

    index: int
    time: float
    size: tuple[int, int]
    homography: np.ndarray | None = None
    image: np.ndarray | None = field(default=None, repr=False)


def info_frame(info: FrameInfo, image: np.ndarray | None = None) -> InfoFrame:
    return InfoFrame(int(info.index), info.time_s, (int(info.width), int(info.height)), info_homography(info), image)
