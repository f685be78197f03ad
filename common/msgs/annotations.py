"""The track as Foxglove (and Rerun's MCAP loader) draw it: ``foxglove.ImageAnnotations`` on the
camera image, built from the project's own messages.

The recorder draws them (:class:`TrackDrawing`), off the tracker's critical path (see
``docs/recordings.md``), records them on ``track/annotations`` and publishes them there.

Single target: the estimate's oriented box (a line loop; a circle at the
centre when the box size is unknown), the particles as points, the ground truth's box when the
frame has one, and a label with p(visible). Several articulated targets: every part as a point,
the body model's skeleton as a line list, one colour a target. Every annotation carries the
frame's capture time, the image's timestamp, so that a viewer pairs them.
"""

from __future__ import annotations

import math

import numpy as np
from foxglove_schemas_protobuf.CircleAnnotation_pb2 import CircleAnnotation
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
from foxglove_schemas_protobuf.Point2_pb2 import Point2
from foxglove_schemas_protobuf.PointsAnnotation_pb2 import PointsAnnotation
from foxglove_schemas_protobuf.TextAnnotation_pb2 import TextAnnotation
from google.protobuf.timestamp_pb2 import Timestamp

from common.await_info import AwaitInfo
from common.msgs import unpack
from common.msgs.convert import cloud_field
from common.tracking.state import oriented_box_corners

ESTIMATE = Color(r=0.9, g=0.1, b=0.1, a=1.0)
PREDICTED = Color(r=0.6, g=0.6, b=0.6, a=1.0)
"""The estimate of a frame without a detector reply (prediction only)."""
TRUTH = Color(r=0.1, g=0.8, b=0.2, a=1.0)
PARTICLES = Color(r=1.0, g=0.55, b=0.0, a=0.6)
LABEL_BACKGROUND = Color(r=0.0, g=0.0, b=0.0, a=0.6)
WHITE = Color(r=1.0, g=1.0, b=1.0, a=1.0)
TARGETS = [Color(r=r, g=g, b=b, a=1.0) for r, g, b in
           ((0.90, 0.10, 0.10), (0.10, 0.45, 0.90), (0.95, 0.75, 0.05), (0.60, 0.20, 0.80),
            (0.05, 0.75, 0.75), (0.95, 0.45, 0.70), (0.45, 0.70, 0.15), (0.60, 0.40, 0.20))]

MAX_PARTICLES = 1000
"""Particles drawn at most (evenly spaced through the cloud): a 5,000-particle filter's points
would cost the tracker more to build than the rest of its message."""


def _stamp(ns: int) -> Timestamp:
    t = Timestamp()
    t.FromNanoseconds(int(ns))
    return t


def _finite(*v: float) -> bool:
    return all(math.isfinite(x) for x in v)


def _points(xy) -> list[Point2]:
    return [Point2(x=x, y=y) for x, y in xy]


def estimate_annotations(est, capture_ns: int, cloud=None, truth=None) -> ImageAnnotations:
    """The annotations of one single-target estimate (``polartrack.Estimate``), with the
    particles of its ``ParticleCloud`` and the frame's ``Truth`` when given."""
    stamp = _stamp(capture_ns)
    out = ImageAnnotations()
    colour = ESTIMATE if est.observed else PREDICTED
    if truth is not None and truth.visible and _finite(truth.box_x, truth.box_y, truth.box_w, truth.box_h):
        x, y, w, h = truth.box_x, truth.box_y, truth.box_w, truth.box_h
        out.points.append(PointsAnnotation(timestamp=stamp, type=PointsAnnotation.LINE_LOOP, thickness=1.0,
                                           points=_points([(x, y), (x + w, y), (x + w, y + h), (x, y + h)]),
                                           outline_color=TRUTH))
    if cloud is not None and cloud.count > 0:
        try:
            xy = cloud_field(cloud.image_xy, int(cloud.count), 2)
        except ValueError:
            xy = np.empty((0, 2))
        xy = xy[:: max(1, -(-len(xy) // MAX_PARTICLES))]
        xy = xy[np.isfinite(xy).all(axis=1)]
        if len(xy):
            out.points.append(PointsAnnotation(timestamp=stamp, type=PointsAnnotation.POINTS, thickness=2.0,
                                               points=_points(xy.tolist()), outline_color=PARTICLES))
    if not _finite(est.x, est.y):
        return out
    has_box = est.w > 0 and est.h > 0 and _finite(est.w, est.h, est.theta_deg, est.box_dx, est.box_dy)
    if has_box:
        corners = oriented_box_corners(est.x + est.box_dx, est.y + est.box_dy, est.w, est.h, est.theta_deg)
        out.points.append(PointsAnnotation(timestamp=stamp, type=PointsAnnotation.LINE_LOOP, thickness=2.0,
                                           points=_points(corners), outline_color=colour))
        top = min(corners, key=lambda p: (p[1], p[0]))
        at = Point2(x=top[0], y=top[1] - 4.0)
    else:
        at = Point2(x=est.x + 6.0, y=est.y - 6.0)
    out.circles.append(CircleAnnotation(timestamp=stamp, position=Point2(x=est.x, y=est.y), diameter=6.0,
                                        thickness=2.0, outline_color=colour))
    label = f"p(visible) {est.p_visible:.2f}" + (" re-acquired" if est.reacquired else "") + \
        ("" if est.observed else " predicted")
    out.texts.append(TextAnnotation(timestamp=stamp, position=at, text=label, font_size=14.0, text_color=WHITE,
                                    background_color=LABEL_BACKGROUND))
    return out


def multi_annotations(msg, capture_ns: int) -> ImageAnnotations:
    """The annotations of one multi-target estimate (``polartrack.MultiEstimate``): each
    target's parts as points and its skeleton (each part to its parent) as a line list."""
    stamp = _stamp(capture_ns)
    out = ImageAnnotations()
    t, p = int(msg.targets), int(msg.parts)
    if t == 0 or p == 0:
        return out
    try:
        pos = unpack(msg.positions, np.float64, (t, p, 2))
        parents = unpack(msg.parents, np.int32, (p,)) if msg.parents else np.full(p, -1, np.int32)
    except ValueError:
        return out
    bones = [(i, int(j)) for i, j in enumerate(parents) if 0 <= j < p and j != i]
    for k in range(t):
        colour = TARGETS[k % len(TARGETS)]
        parts = pos[k]
        ok = np.isfinite(parts).all(axis=1)
        if ok.any():
            out.points.append(PointsAnnotation(timestamp=stamp, type=PointsAnnotation.POINTS, thickness=5.0,
                                               points=_points(parts[ok].tolist()), outline_color=colour))
        segs = [pt for i, j in bones if ok[i] and ok[j] for pt in (parts[i], parts[j])]
        if segs:
            out.points.append(PointsAnnotation(timestamp=stamp, type=PointsAnnotation.LINE_LIST, thickness=2.0,
                                               points=_points(np.asarray(segs).tolist()), outline_color=colour))
        if ok[0]:
            out.texts.append(TextAnnotation(timestamp=stamp, position=Point2(x=parts[0][0], y=parts[0][1] - 10.0),
                                            text=f"target {k}", font_size=12.0, text_color=WHITE,
                                            background_color=LABEL_BACKGROUND))
    return out


class TrackDrawing:
    """A run's messages joined into one ``ImageAnnotations`` a frame, as they arrive: the frame's
    ``FrameInfo`` (its truth), its ``Estimate`` and its ``ParticleCloud``, which the tracker
    publishes right after the estimate (without a cloud, the drawing is complete with the next
    estimate or at :meth:`flush`). An estimate (and its cloud) may arrive before its frame's info:
    such a drawing waits for it (:class:`common.await_info.AwaitInfo`), at most ``keep`` drawings,
    the oldest going out first when more wait, and all of them at :meth:`flush`. A
    ``MultiEstimate`` is drawn at once. Each method returns the (log time, serialised annotations)
    completed by that message."""

    def __init__(self, keep: int = 256):
        self.truth: dict[int, object] = {}
        self.keep = keep
        self.pending = None  # (estimate, log time): waiting for its cloud
        self.waiting: AwaitInfo[tuple] = AwaitInfo(keep)
        """(estimate, log time, cloud or None): drawings complete but for their frame's info."""

    def info(self, info) -> list[tuple[int, bytes]]:
        if info.end_of_stream:
            return []
        if info.HasField("truth"):
            self.truth[int(info.index)] = info.truth
            while len(self.truth) > self.keep:
                del self.truth[next(iter(self.truth))]
        return [self._draw(*w) for w in self.waiting.info(int(info.index))]

    def estimate(self, est, log_time: int) -> list[tuple[int, bytes]]:
        out = []
        if self.pending is not None:  # the estimate before went without a cloud
            out = self._complete(*self.pending, None)
        self.pending = (est, int(log_time))
        return out

    def cloud(self, cloud) -> list[tuple[int, bytes]]:
        if self.pending is None or self.pending[0].frame_index != cloud.frame_index:
            return []
        est, t = self.pending
        self.pending = None
        return self._complete(est, t, cloud)

    def multi(self, msg, log_time: int) -> list[tuple[int, bytes]]:
        return [(int(log_time), multi_annotations(msg, log_time).SerializeToString())]

    def flush(self) -> list[tuple[int, bytes]]:
        """Every drawing still held: those waiting for their frame's info, then the last estimate's."""
        held = self.waiting.flush() + ([(*self.pending, None)] if self.pending is not None else [])
        self.pending = None
        return [self._draw(*w) for w in held]

    def _complete(self, est, t: int, cloud) -> list[tuple[int, bytes]]:
        """A frame's drawing, complete but for its info: drawn if that has come, else held."""
        return [self._draw(*w) for w in self.waiting.hold(int(est.frame_index), (est, t, cloud))]

    def _draw(self, est, t: int, cloud) -> tuple[int, bytes]:
        return t, estimate_annotations(est, t, cloud, self.truth.get(int(est.frame_index))).SerializeToString()
