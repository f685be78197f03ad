"""The codec: every message <-> the library's objects, in one place (no bus code).

- frames: :func:`image_to_msg` / :func:`msg_to_image` (foxglove.RawImage; compressed images:
  :mod:`common.msgs.image_wire`), :func:`frame_info_msg` / :func:`info_frame` (FrameInfo);
- the detector's questions and answers: :func:`score_query` / :func:`query_hypotheses`,
  :func:`reply_scores`; :func:`template_to_msg` / :func:`msg_to_template` (Template);
- estimates: :func:`estimate_msg` (Estimate), :func:`particles_msg` / :func:`msg_to_cloud`
  (ParticleCloud), :func:`multi_estimate_msg` / :func:`msg_positions` (MultiEstimate).

``tests/test_codec.py`` round-trips each.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from common.detector.layout import N_COLUMNS, N_ROWS
from common.detector.template import Template
from common.msgs import (Estimate, FrameInfo, MultiEstimate, ParticleCloud, RawImage, ScoreQuery, ScoreReply, Truth, pack,
                         unpack)
from common.msgs import Template as TemplateMsg


def image_to_msg(image: np.ndarray, capture_ns: int, frame_id: str) -> RawImage:
    """uint8 RGB (H, W, 3) -> foxglove.RawImage (rgb8)."""
    h, w = image.shape[:2]
    msg = RawImage(frame_id=frame_id, width=w, height=h, encoding="rgb8", step=3 * w,
                   data=np.ascontiguousarray(image, np.uint8).tobytes())
    msg.timestamp.FromNanoseconds(int(capture_ns))
    return msg


def msg_to_image(msg: RawImage) -> np.ndarray:
    """foxglove.RawImage (rgb8) -> uint8 (H, W, 3); ValueError for anything malformed."""
    if msg.encoding != "rgb8":
        raise ValueError(f"unsupported image encoding {msg.encoding!r} (expected rgb8)")
    h, w = int(msg.height), int(msg.width)
    if h <= 0 or w <= 0 or msg.step != 3 * w:
        raise ValueError(f"bad image geometry {w}x{h} step {msg.step}")
    data = msg.data  # each read of a bytes field is a copy of the whole image
    if len(data) != h * msg.step:
        raise ValueError(f"image data has {len(data)} bytes, expected {h * msg.step} (truncated?)")
    return np.frombuffer(data, np.uint8).reshape(h, w, 3)


def estimate_msg(frame_index: int, capture_ns: int, state, filter_name: str, skipped: int = 0,
                 step_ms: float = 0.0) -> Estimate:
    m, mm = state.map_estimate, state.mmse_estimate
    dx, dy = state.box_offset or (0.0, 0.0)
    return Estimate(
        frame_index=frame_index, time_s=state.time, observed=state.observed, filter=filter_name,
        x=m.image_x, y=m.image_y, theta_deg=m.theta, p_visible=state.p_visible, world_x=m.x, world_y=m.y,
        vx=m.vx, vy=m.vy, speed=state.speed, mmse_x=mm.image_x, mmse_y=mm.image_y,
        n_eff=float(state.n_eff) if np.isfinite(state.n_eff) else 0.0, resampled=bool(state.resampled),
        frames_skipped=skipped, step_ms=step_ms, latency_ms=(time.time_ns() - capture_ns) / 1e6,
        w=state.size[0] if state.size else 0.0, h=state.size[1] if state.size else 0.0,
        reacquired=bool(state.reacquired), box_dx=dx, box_dy=dy)


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


QUERY_WIDTHS = {ScoreQuery.AT: 3, ScoreQuery.GRID: 2, ScoreQuery.TEMPLATE: 6, ScoreQuery.PEAK: 2,
                ScoreQuery.HISTOGRAMS: 4, ScoreQuery.SIMILARITY: 4}
"""Values per hypothesis of each query kind: (x, y, theta_deg), (x, y), (cx, cy, box x, y, w, h),
(x, y), and boxes (x0, y0, x1, y1)."""


PART_KINDS = (ScoreQuery.HISTOGRAMS, ScoreQuery.SIMILARITY)
"""The multi-target filters' part-evidence questions (the others are the polar matcher's)."""
REPLY_DTYPES = {"float32": np.float32, "float64": np.float64}
"""A part-evidence reply's ``dtype``: the array's own, so that the client gets it back bit for bit."""


def score_query(request_id: int, client: str, frame_index: int, kind: int, hypotheses: np.ndarray,
                **fields) -> ScoreQuery:
    """A question to the detector about frame ``frame_index``: ``hypotheses`` (count x the kind's
    width, float64 on the wire) and the kind's other ``fields`` (template_version, factor, ...)."""
    hyps = np.asarray(hypotheses, np.float64)
    return ScoreQuery(request_id=request_id, client=client, frame_index=frame_index, kind=kind, count=len(hyps),
                      hypotheses=pack(hyps), **fields)


def query_hypotheses(q: ScoreQuery) -> np.ndarray:
    """The (count, width) hypotheses of a query; ValueError for an unknown kind or a size that
    disagrees with the count."""
    width = QUERY_WIDTHS.get(q.kind)
    if width is None:
        raise ValueError(f"unknown query kind {q.kind}")
    return unpack(q.hypotheses, np.float64, (q.count, width))


def reply_scores(rep: ScoreReply, n: int, angles: int | None) -> tuple[np.ndarray, np.ndarray]:
    """Scores (n,) for ``angles`` None (AT) or (n, angles), and valid (n,), from a reply; ValueError
    when a size disagrees."""
    shape = (n,) if angles is None else (n, angles)
    return unpack(rep.scores, np.float64, shape), unpack(rep.valid, np.uint8, (n,)).astype(bool)


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


def frame_info_msg(frame, capture_ns: int = 0, source_name: str = "", total: int = 0, true_centre=None) -> FrameInfo:
    """A source's frame (:class:`common.sources.Frame`) -> its FrameInfo: index, time, capture
    time, size, homography, and the ground truth when the source knows it (``true_centre``: the
    target's centre even while hidden, the synthetic scene's). :func:`info_frame` is the way back."""
    h, w = frame.image.shape[:2]
    info = FrameInfo(index=frame.index, time_s=frame.time, capture_ns=capture_ns, width=w, height=h,
                     source=source_name, total_frames=total)
    if frame.homography is not None:
        info.homography.extend(float(v) for v in frame.homography.ravel())
    t = frame.truth
    if t is not None:
        nan = math.nan
        tr = Truth(visible=t.box is not None, angle_deg=nan if t.angle_deg is None else t.angle_deg,
                   visible_fraction=nan if t.visible_fraction is None else t.visible_fraction)
        if t.box is not None:
            tr.box_x, tr.box_y, tr.box_w, tr.box_h = t.box
        c = true_centre if true_centre is not None else t.centre
        tr.centre_x, tr.centre_y = c if c is not None else (nan, nan)
        info.truth.CopyFrom(tr)
    if frame.people is not None:  # the people scene: every person's 10 part centres
        info.truth_people = len(frame.people.parts)
        info.truth_parts = pack(frame.people.parts)
    return info


def info_homography(info: FrameInfo) -> np.ndarray | None:
    return np.asarray(info.homography, float).reshape(3, 3) if len(info.homography) == 9 else None


@dataclass(frozen=True)
class InfoFrame:
    """A frame as the bus describes it (a FrameInfo), with its pixels only where they were taken
    (a stabilising tracker): what :class:`common.single_target.runner.Tracker` steps on outside the process
    that reads the source."""

    index: int
    time: float
    size: tuple[int, int]
    homography: np.ndarray | None = None
    image: np.ndarray | None = field(default=None, repr=False)


def info_frame(info: FrameInfo, image: np.ndarray | None = None) -> InfoFrame:
    return InfoFrame(int(info.index), info.time_s, (int(info.width), int(info.height)), info_homography(info), image)


def multi_estimate_msg(frame_index: int, state, run, capture_ns: int | None = None,
                       step_ms: float = 0.0) -> MultiEstimate:
    """The message of one frame's estimates (``state``: a :class:`common.multitarget.MultiTrackState`
    of ``run``, a :class:`common.multitarget.runner.MultiRun`; no loss: float64 arrays as bytes)."""
    from common.multitarget.body import body_model

    body = body_model(run.config.n_parts)
    t_n, p_n = state.parts.shape[:2]
    gate = np.asarray(state.gate_area, np.float64)
    return MultiEstimate(
        frame_index=frame_index, time_s=state.time, filter=run.method, targets=t_n, parts=p_n,
        part_names=list(body.names), positions=pack(state.parts), velocities=pack(state.velocity),
        n_eff=pack(state.n_eff), moved=pack(state.moved, np.uint8), units=gate.shape[1] if gate.ndim == 2 else 0,
        gate_area=pack(gate), n_measurements=pack(state.n_measurements, np.int64),
        acceptance={k: float(v) for k, v in state.acceptance.items()}, parents=pack(body.parent, np.int32),
        observed=True, step_ms=step_ms,
        latency_ms=0.0 if capture_ns is None else (time.time_ns() - capture_ns) / 1e6)  # fmt: skip


def msg_positions(m: MultiEstimate) -> np.ndarray:
    """(T, P, 2) part centres of a MultiEstimate; ValueError if malformed."""
    return unpack(m.positions, np.float64, (m.targets, m.parts, 2))
