"""Rerun logging of the bus messages: a run on the bus, or read back from its MCAP recording.

:class:`RunLogger` turns the project's messages (``frame/image``, ``frame/info``,
``track/estimate``, ``track/particles``, ``template``, ``run/config``, ``status/*``) into Rerun
logging calls on an explicit :class:`rerun.RecordingStream` (never the global one), so several
loggers can live in one process. It only reads messages: nothing here is part of the filters.

Every call is placed on two timelines: ``frame`` (sequence = frame index) and ``capture_time``
(timestamp = the frame's capture time, the MCAP log time). Rerun keeps the current time per
thread, so a logger must be used from one thread (the one that calls its methods).

Entity paths::

    camera/image              EncodedImage (JPEG) of the frame
    camera/particles          Points2D, particles in image pixels, coloured by weight (viridis)
    camera/estimate           Points2D, the MAP estimate (red; grey when prediction only)
    camera/estimate_box       LineStrips2D, the estimate's box (w, h; else the first box) rotated by theta
    camera/mmse               Points2D, the MMSE estimate
    camera/track              LineStrips2D, the last K MAP positions
    camera/truth              Points2D, true centre (when known)
    camera/truth_box          Boxes2D, true box (when the target is visible)
    camera/template           Boxes2D, where the template was taken (at that frame)
    ground/particles          Points2D, particles on the ground plane (world x, -y: north is up)
    ground/estimate, ground/track, ground/truth   the same on the ground plane
    plots/visibility/{p_visible,truth_fraction}   posterior visibility vs true visible fraction
    plots/error/{map_px,mmse_px}                  centre error vs truth, image pixels
    plots/theta/{estimate,truth}                  orientation (estimate relative to the template;
                                                  truth = image orientation), degrees
    plots/speed, plots/n_eff, plots/step_ms
    run/config                TextDocument (static), log/services TextLog (final service counters)

Multi-target runs (``track/multi_estimate``; the people scene's part truth in ``frame/info``)::

    camera/targets/<t>/parts       Points2D, target t's part centres in its identity colour (labels: part
                                   names; grey for a frame predicted only)
    camera/targets/<t>/skeleton    LineStrips2D, the body model's neighbour graph (child -> parent)
    camera/people_truth/<k>/parts, camera/people_truth/<k>/skeleton   person k's true parts (10-part
                                   model) in a light version of identity colour k
    plots/n_eff/target_<t>         N_eff of each population
    plots/error/target_<t>         mean part-centre error of target t against person t (px)

:func:`mcap_to_rrd` converts a recording (``polartrack view``).
"""

from __future__ import annotations

import json
import logging
import math
import os
import sys
import time
from collections import OrderedDict, deque
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from common.msgs import (
    Estimate,
    FrameInfo,
    MultiEstimate,
    ParticleCloud,
    RawImage,
    RunConfig,
    ServiceStatus,
    Template,
    message_class,
    unpack,
)
from common.msgs.convert import msg_to_cloud, msg_to_image
from common.msgs.image_wire import decode_frame
from common.tracking.state import oriented_box_corners

log = logging.getLogger("polartrack.rerun")

APPLICATION_ID = "polartrack"
FRAME = "frame"
SERIES_BATCH = 135
"""Time-series points buffered before they are sent (about half a second of a 30 fps run)."""
FLUSH_EVERY = 256
"""Messages logged between two (non-blocking) flushes of the recording stream. Without them Rerun's
batching pipeline held on to what was logged: a viewer grew 14 MB every 1,000 frames (55 MB in an
8-minute soak) while its Python objects stayed at a few MB; flushed every 256 messages, its
memory is flat (``tests/test_services_memory.py``)."""
CAPTURE_TIME = "capture_time"

RED = (230, 40, 40)
GREY = (160, 160, 160)
ORANGE = (255, 165, 0)
GREEN = (40, 220, 80)
CYAN = (0, 200, 255)
MAGENTA = (255, 0, 255)

_SERIES = {
    "plots/visibility/p_visible": ("posterior p(visible)", RED),
    "plots/visibility/truth_fraction": ("true visible fraction", GREEN),
    "plots/error/map_px": ("MAP centre error (px)", RED),
    "plots/error/mmse_px": ("MMSE centre error (px)", ORANGE),
    "plots/theta/estimate": ("theta, estimate (deg, rel. template)", RED),
    "plots/theta/truth": ("angle, truth (deg, image)", GREEN),
    "plots/speed": ("speed (world units/s)", CYAN),
    "plots/n_eff": ("N_eff", MAGENTA),
    "plots/step_ms": ("filter step (ms)", GREY),
}

IDENTITY = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
            (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207)]
"""Identity colours of the targets (target t: IDENTITY[t % 10]); person k of the truth the same, lighter."""


def identity_colour(t: int, light: bool = False) -> tuple[int, int, int]:
    c = IDENTITY[t % len(IDENTITY)]
    return tuple(int(v + (255 - v) * 0.55) for v in c) if light else c


def skeleton_strips(positions: np.ndarray, parents: np.ndarray) -> list[list[list[float]]]:
    """(P, 2) part centres and (P,) parents (-1: root) -> one 2-point strip per edge of the graph."""
    return [[positions[c].tolist(), positions[p].tolist()] for c, p in enumerate(parents)
            if 0 <= p < len(positions) and np.isfinite(positions[[c, p]]).all()]


_KINDS = {
    "track/multi_estimate": "multi_estimates",
    "frame/image": "images",
    "frame/info": "infos",
    "track/estimate": "estimates",
    "track/particles": "clouds",
    "template": "templates",
    "run/config": "configs",
}


def blueprint() -> rrb.Blueprint:
    """Camera view with the overlays, the ground plane view, and the time series."""
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial2DView(origin="camera", name="Camera: particles, estimate, truth"),
                rrb.Tabs(
                    rrb.Spatial2DView(origin="ground", name="Ground plane (x east, up = north)"),
                    rrb.TextDocumentView(origin="run", name="Run config"),
                ),
                row_shares=[3, 2],
            ),
            rrb.Vertical(
                rrb.TimeSeriesView(origin="plots/visibility", name="Visibility",
                                   axis_y=rrb.ScalarAxis(range=(0.0, 1.05))),
                rrb.TimeSeriesView(origin="plots/error", name="Centre error vs truth (px)"),
                rrb.TimeSeriesView(origin="plots/theta", name="Orientation (deg)"),
                rrb.TimeSeriesView(origin="plots/speed", name="Speed"),
                rrb.TimeSeriesView(origin="plots/n_eff", name="N_eff"),
            ),
            column_shares=[3, 2],
        ),
        rrb.TimePanel(timeline=FRAME),
        collapse_panels=False,
    )


def display_available() -> bool:
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


class _Bounded(OrderedDict):
    """A dict that forgets its oldest entries beyond ``maxlen``."""

    def __init__(self, maxlen: int):
        super().__init__()
        self.maxlen = maxlen

    def __setitem__(self, key, value) -> None:
        super().__setitem__(key, value)
        self.move_to_end(key)
        while len(self) > self.maxlen:
            self.popitem(last=False)


class RunLogger:
    """Messages -> Rerun logging calls on ``rec``. Methods raise ``ValueError`` for malformed
    content; :meth:`log_message` decodes, dispatches and counts (never raises for bad data)."""

    def __init__(self, rec: rr.RecordingStream, *, jpeg_quality: int = 85, track_length: int = 300,
                 memory: int = 1024):
        import matplotlib

        self.rec = rec
        self.jpeg_quality = int(jpeg_quality)
        self.track_image: deque[tuple[float, float]] = deque(maxlen=int(track_length))
        self.track_world: deque[tuple[float, float]] = deque(maxlen=int(track_length))
        self._ns_by_index: _Bounded = _Bounded(memory)   # frame index -> capture ns
        self._truth: _Bounded = _Bounded(memory)         # frame index -> (cx, cy)
        self._est: _Bounded = _Bounded(memory)           # frame index -> (map x, y, mmse x, y)
        self._error_done: _Bounded = _Bounded(memory)
        self._people_truth: _Bounded = _Bounded(memory)  # frame index -> (people, 10, 2) true part centres
        self._multi: _Bounded = _Bounded(memory)         # frame index -> ((T, P, 2) estimated parts, P)
        self._multi_error_done: _Bounded = _Bounded(memory)
        self._targets_drawn = 0
        self._box_size: tuple[float, float] | None = None
        self._truth_drawn = False
        self._lut = matplotlib.colormaps["viridis"](np.linspace(0.0, 1.0, 256), bytes=True)[:, :3]
        self.stats: dict[str, int] = {"messages": 0, "images": 0, "infos": 0, "estimates": 0, "clouds": 0,
                                      "templates": 0, "configs": 0, "statuses": 0, "end_of_stream": 0,
                                      "malformed": 0, "skipped": 0, "multi_estimates": 0}
        self._now: tuple[int | None, int | None] = (None, None)  # (frame index, capture ns) being logged
        self._series: dict[str, list[tuple[int | None, int | None, float]]] = {}
        self._series_points = 0
        self._log_static(rec)

    @staticmethod
    def _log_static(rec: rr.RecordingStream) -> None:
        for path, (name, colour) in _SERIES.items():
            rec.log(path, rr.SeriesLines(names=name, colors=colour, widths=1.5), static=True)

    def rotate(self, path: str | os.PathLike) -> None:
        """Go on in a new file ``path`` (.rrd), the same recording (its id: Rerun shows the files
        opened together as one): the stream is closed and a new one opened, which frees what
        Rerun held for the old one (``docs/reliability.md``). File-only loggers."""
        self.flush_series()
        self.rec.flush()
        rid = self.rec.get_recording_id()
        self.rec.disconnect()
        rec = rr.RecordingStream(APPLICATION_ID, recording_id=rid)
        rec.save(str(path), default_blueprint=blueprint())
        self._log_static(rec)
        self.rec = rec
        self._set_time(*self._now)

    # ------------------------------------------------------------------ construction
    @classmethod
    def to_file(cls, path: str | os.PathLike, *, spawn: bool = False, recording_id: str | None = None,
                connect: str | None = None, serve_port: int | None = None, **kwargs) -> RunLogger:
        """A logger writing to ``path`` (.rrd), with the blueprint as default, and live as well:
        ``spawn`` starts a viewer and streams to it, ``connect`` streams to a running viewer or
        server at that gRPC URL (``rerun+http://HOST:PORT/proxy``), ``serve_port`` hosts a gRPC
        server on loopback that viewers connect to (``rerun --connect rerun+http://127.0.0.1:PORT/proxy``)."""
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id)
        bp = blueprint()
        try:
            sinks = [rr.FileSink(str(path))]
            if spawn:
                rr.spawn(connect=False, recording=rec)
                sinks.append(rr.GrpcSink())
            if connect:
                sinks.append(rr.GrpcSink(connect))
            if serve_port is not None:
                sinks.append(rr.GrpcServerSink(bind_ip="127.0.0.1", port=serve_port))
            if len(sinks) > 1:
                rec.set_sinks(*sinks, default_blueprint=bp)
            else:
                rec.save(str(path), default_blueprint=bp)
        except Exception:
            rec.disconnect()  # drop the buffered start-up data quietly
            raise
        return cls(rec, **kwargs)

    def close(self) -> None:
        """Flush and close the sinks (writes the .rrd footer)."""
        self.flush_series()
        self.rec.flush()
        self.rec.disconnect()

    # ------------------------------------------------------------------ time
    def _set_time(self, index: int | None, capture_ns: int | None) -> None:
        if capture_ns is None and index is not None:
            capture_ns = self._ns_by_index.get(int(index))
        self._now = (None if index is None else int(index), None if capture_ns is None else int(capture_ns))
        if index is None:
            self.rec.disable_timeline(FRAME)
        else:
            self.rec.set_time(FRAME, sequence=int(index))
        if capture_ns is None:
            self.rec.disable_timeline(CAPTURE_TIME)
        else:
            self.rec.set_time(CAPTURE_TIME, timestamp=np.datetime64(int(capture_ns), "ns"))

    def _scalar(self, path: str, value: float) -> None:
        """One point of a time series at the current time. Points are sent in columns (one
        ``send_columns`` per series every ``SERIES_BATCH`` points, and on close): nine series a
        frame logged one by one were a third of the viewer's work."""
        if math.isfinite(value):
            self._series.setdefault(path, []).append((*self._now, float(value)))
            self._series_points += 1
            if self._series_points >= SERIES_BATCH:
                self.flush_series()

    def flush_series(self) -> None:
        """Send the buffered time-series points."""
        for path, rows in self._series.items():
            groups: dict[tuple[bool, bool], list] = {}
            for index, ns, value in rows:
                groups.setdefault((index is not None, ns is not None), []).append((index, ns, value))
            for (has_index, has_ns), g in groups.items():
                indexes = []
                if has_index:
                    indexes.append(rr.TimeColumn(FRAME, sequence=[r[0] for r in g]))
                if has_ns:
                    indexes.append(rr.TimeColumn(CAPTURE_TIME, timestamp=np.array([r[1] for r in g], "datetime64[ns]")))
                if not indexes:  # no time at all: log them one by one on no timeline
                    self.rec.reset_time()
                    for _i, _n, value in g:
                        self.rec.log(path, rr.Scalars(value))
                    self._set_time(*self._now)
                    continue
                rr.send_columns(path, indexes=indexes, columns=rr.Scalars.columns(scalars=[r[2] for r in g]),
                                recording=self.rec)
        self._series.clear()
        self._series_points = 0

    # ------------------------------------------------------------------ messages
    def frame_image(self, msg: RawImage, capture_ns: int | None = None, index: int | None = None,
                    image: np.ndarray | None = None) -> None:
        """The frame as JPEG at ``camera/image``. The frame index is ``index`` (the image's
        :data:`common.msgs.image_wire.INDEX_FIELD`), else a numeric ``frame_id`` (older
        recordings), else looked up by capture time.
        ``image``: the pixels, when ``msg`` was decoded without them (:mod:`common.msgs.image_wire`)."""
        import cv2

        img = msg_to_image(msg) if image is None else image
        if capture_ns is None and msg.HasField("timestamp"):
            capture_ns = msg.timestamp.ToNanoseconds()
        if index is None:
            fid = msg.frame_id.strip()
            if fid.isdigit():
                index = int(fid)
            elif capture_ns is not None:
                index = next((i for i, ns in self._ns_by_index.items() if ns == capture_ns), None)
        ok, jpg = cv2.imencode(".jpg", cv2.cvtColor(img, cv2.COLOR_RGB2BGR),
                               [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        if not ok:
            raise ValueError("JPEG encoding failed")
        self._set_time(index, capture_ns)
        self.rec.log("camera/image", rr.EncodedImage(contents=jpg.tobytes(), media_type="image/jpeg"))

    def frame_info(self, msg: FrameInfo, capture_ns: int | None = None) -> None:
        """Truth (centre, box, visible fraction, angle) and the frame's time; end of stream is counted."""
        if msg.end_of_stream:
            self.stats["end_of_stream"] += 1
            return
        index = int(msg.index)
        ns = int(msg.capture_ns) if msg.capture_ns else capture_ns
        if ns is not None:
            self._ns_by_index[index] = ns
        self._set_time(index, ns)
        if msg.truth_people:
            self._people(index, unpack(msg.truth_parts, np.float64, (msg.truth_people, 10, 2)))
        if not msg.HasField("truth"):
            if self._truth_drawn:
                for p in ("camera/truth", "camera/truth_box", "ground/truth"):
                    self.rec.log(p, rr.Clear(recursive=False))
                self._truth_drawn = False
            return
        t = msg.truth
        self._truth_drawn = True
        if _finite(t.centre_x, t.centre_y):
            self._truth[index] = (t.centre_x, t.centre_y)
            self.rec.log("camera/truth", rr.Points2D([[t.centre_x, t.centre_y]], colors=GREEN,
                                                     radii=rr.Radius.ui_points(4.0)))
            gw = self._image_to_ground(msg.homography, t.centre_x, t.centre_y)
            if gw is not None:
                self.rec.log("ground/truth", rr.Points2D([[gw[0], -gw[1]]], colors=GREEN,
                                                         radii=rr.Radius.ui_points(4.0)))
            else:
                self.rec.log("ground/truth", rr.Clear(recursive=False))
            self._centre_error(index)
        else:
            self.rec.log("camera/truth", rr.Clear(recursive=False))
            self.rec.log("ground/truth", rr.Clear(recursive=False))
        if t.visible and _finite(t.box_x, t.box_y, t.box_w, t.box_h) and t.box_w > 0 and t.box_h > 0:
            self.rec.log("camera/truth_box", rr.Boxes2D(mins=[[t.box_x, t.box_y]], sizes=[[t.box_w, t.box_h]],
                                                        colors=GREEN, radii=rr.Radius.ui_points(1.0)))
            if self._box_size is None:
                self._box_size = (t.box_w, t.box_h)
        else:
            self.rec.log("camera/truth_box", rr.Clear(recursive=False))
        self._scalar("plots/visibility/truth_fraction", t.visible_fraction)
        self._scalar("plots/theta/truth", t.angle_deg)

    def estimate(self, msg: Estimate, capture_ns: int | None = None) -> None:
        """MAP (and MMSE) estimate, the bounded track, and the per-frame series."""
        index = int(msg.frame_index)
        self._set_time(index, capture_ns)
        colour = RED if msg.observed else GREY
        if _finite(msg.x, msg.y):
            self.track_image.append((msg.x, msg.y))
            self.rec.log("camera/estimate", rr.Points2D(
                [[msg.x, msg.y]], colors=colour, radii=rr.Radius.ui_points(5.0),
                labels=f"MAP theta={msg.theta_deg:.1f} p_vis={msg.p_visible:.2f}", show_labels=False))
            # the estimate's own box (w, h: the first box times the apparent scale), else the first box
            # about the target's centre where it was measured apart from the MAP (box_dx, box_dy)
            size = (msg.w, msg.h) if msg.w > 0 and msg.h > 0 and _finite(msg.w, msg.h) else self._box_size
            if size is not None and _finite(msg.theta_deg, msg.box_dx, msg.box_dy):
                self.rec.log("camera/estimate_box", rr.LineStrips2D(
                    [self._rotated_box(msg.x + msg.box_dx, msg.y + msg.box_dy, *size, msg.theta_deg)], colors=colour,
                    radii=rr.Radius.ui_points(1.0), labels="re-acquired" if msg.reacquired else None))
        else:
            self.rec.log("camera/estimate", rr.Clear(recursive=False))
            self.rec.log("camera/estimate_box", rr.Clear(recursive=False))
        if _finite(msg.mmse_x, msg.mmse_y):
            self.rec.log("camera/mmse", rr.Points2D([[msg.mmse_x, msg.mmse_y]], colors=ORANGE,
                                                    radii=rr.Radius.ui_points(3.0)))
        if len(self.track_image) >= 2:
            self.rec.log("camera/track", rr.LineStrips2D([list(self.track_image)], colors=RED,
                                                         radii=rr.Radius.ui_points(1.0)))
        if _finite(msg.world_x, msg.world_y):
            self.track_world.append((msg.world_x, -msg.world_y))
            self.rec.log("ground/estimate", rr.Points2D([[msg.world_x, -msg.world_y]], colors=colour,
                                                        radii=rr.Radius.ui_points(5.0)))
            if len(self.track_world) >= 2:
                self.rec.log("ground/track", rr.LineStrips2D([list(self.track_world)], colors=RED,
                                                             radii=rr.Radius.ui_points(1.0)))
        self._scalar("plots/visibility/p_visible", msg.p_visible)
        self._scalar("plots/speed", msg.speed)
        self._scalar("plots/theta/estimate", msg.theta_deg)
        self._scalar("plots/n_eff", msg.n_eff)
        self._scalar("plots/step_ms", msg.step_ms)
        self._est[index] = (msg.x, msg.y, msg.mmse_x, msg.mmse_y)
        self._centre_error(index)

    def _people(self, index: int, ten: np.ndarray) -> None:
        """The people scene's truth: every person's 10-part skeleton."""
        from common.multitarget.body import body_model

        body = body_model(10)
        parts = body.from_ten(ten)
        self._people_truth[index] = ten
        for k, pos in enumerate(parts):
            colour = identity_colour(k, light=True)
            self.rec.log(f"camera/people_truth/{k}/parts", rr.Points2D(pos, colors=colour, radii=rr.Radius.ui_points(2.5)))
            self.rec.log(f"camera/people_truth/{k}/skeleton", rr.LineStrips2D(
                skeleton_strips(pos, body.parent), colors=colour, radii=rr.Radius.ui_points(1.0)))
        self._multi_error(index)

    def multi_estimate(self, msg, capture_ns: int | None = None) -> None:
        """Every target's parts and skeleton in its identity colour, and its N_eff."""
        index = int(msg.frame_index)
        t_n, p_n = int(msg.targets), int(msg.parts)
        pos = unpack(msg.positions, np.float64, (t_n, p_n, 2))
        parents = unpack(msg.parents, np.int32, (p_n,))
        n_eff = unpack(msg.n_eff, np.float64, (t_n,))
        names = list(msg.part_names) if len(msg.part_names) == p_n else None
        self._set_time(index, capture_ns)
        for t in range(t_n):
            colour = identity_colour(t) if msg.observed else GREY  # grey: predicted only (no evidence)
            self.rec.log(f"camera/targets/{t}/parts", rr.Points2D(
                pos[t], colors=colour, radii=rr.Radius.ui_points(4.0),
                labels=[f"{t}:{n}" for n in names] if names else None, show_labels=False))
            self.rec.log(f"camera/targets/{t}/skeleton", rr.LineStrips2D(
                skeleton_strips(pos[t], parents), colors=colour, radii=rr.Radius.ui_points(2.0)))
            self._scalar(f"plots/n_eff/target_{t}", float(n_eff[t]))
        for t in range(t_n, self._targets_drawn):
            self.rec.log(f"camera/targets/{t}", rr.Clear(recursive=True))
        self._targets_drawn = t_n
        self._scalar("plots/step_ms", msg.step_ms)
        self._multi[index] = (pos, p_n)
        self._multi_error(index)

    def _multi_error(self, index: int) -> None:
        """Mean part-centre error of target t against person t (targets in the scene's person order)."""
        if index in self._multi_error_done or index not in self._multi or index not in self._people_truth:
            return
        from common.multitarget.body import body_model

        pos, p_n = self._multi[index]
        truth = body_model(p_n).from_ten(self._people_truth[index])
        if len(truth) != len(pos):
            return
        self._set_time(index, None)
        for t, err in enumerate(np.linalg.norm(pos - truth, axis=-1).mean(axis=-1)):
            self._scalar(f"plots/error/target_{t}", float(err))
        self._multi_error_done[index] = True

    def particles(self, msg: ParticleCloud, capture_ns: int | None = None) -> None:
        """The cloud over the image and on the ground plane, coloured by normalised weight."""
        n = int(msg.count)
        cloud = msg_to_cloud(msg)
        state, image_xy, w = cloud.states, cloud.image_xy, cloud.weights
        self._set_time(int(msg.frame_index), capture_ns)
        w = np.where(np.isfinite(w) & (w > 0), w, 0.0)
        top = w.max() if n else 0.0
        wn = w / top if top > 0 else np.ones(n)
        order = np.argsort(wn, kind="stable")  # heaviest drawn last (on top)
        colours = self._lut[np.clip((wn[order] * 255).astype(np.int64), 0, 255)]
        radius = rr.Radius.ui_points(1.5)
        ixy = image_xy[order]
        ok = np.isfinite(ixy).all(axis=1)
        self.rec.log("camera/particles", rr.Points2D(ixy[ok], colors=colours[ok], radii=radius))
        gxy = state[order][:, [0, 2]] * (1.0, -1.0)
        ok = np.isfinite(gxy).all(axis=1)
        self.rec.log("ground/particles", rr.Points2D(gxy[ok], colors=colours[ok], radii=radius))

    def template(self, msg: Template, capture_ns: int | None = None) -> None:
        if len(msg.box) == 4:
            x, y, w, h = msg.box
            if _finite(x, y, w, h) and w > 0 and h > 0:
                self._box_size = (w, h)
                self._set_time(int(msg.frame_index), capture_ns)
                self.rec.log("camera/template", rr.Boxes2D(mins=[[x, y]], sizes=[[w, h]], colors=CYAN,
                                                           labels=f"template v{msg.version}"))

    def run_config(self, msg: RunConfig) -> None:
        from common.record.meta import run_metadata

        meta = run_metadata(msg.SerializeToString())  # typed or (older runs) JSON text: the same

        def pretty(text: str) -> str:
            try:
                return json.dumps(json.loads(text), indent=2)
            except json.JSONDecodeError:
                return text

        settings = pretty(meta.get("settings_json") or "{}")
        text = (f"# Run {msg.run_id}\n\n* source: `{msg.source}`\n* seed: {msg.seed}\n* pace: {msg.pace}\n"
                f"* init box: {list(msg.init_box)}\n\n```json\n{settings}\n```\n")
        if meta.get("multi_json"):
            text += f"\n## Multi-target run\n\n```json\n{pretty(meta['multi_json'])}\n```\n"
        self.rec.log("run/config", rr.TextDocument(text, media_type="text/markdown"), static=True)

    def service_status(self, msg: ServiceStatus, capture_ns: int | None = None) -> None:
        if msg.final:
            self._set_time(None, capture_ns)
            self.rec.log("log/services", rr.TextLog(
                f"{msg.service}: received {msg.received}, published {msg.published}, malformed {msg.malformed}, "
                f"dropped {msg.dropped}, errors {msg.errors}, cpu {msg.cpu_s:.1f} s", level="INFO"))

    # ------------------------------------------------------------------ dispatch
    def log_message(self, topic: str, data: bytes, capture_ns: int | None = None) -> bool:
        """Decode ``data`` of ``topic`` (suffix, e.g. ``track/estimate``) and log it. Malformed
        messages are counted in ``stats['malformed']`` and skipped; unknown topics in ``skipped``."""
        self.stats["messages"] += 1
        if self.stats["messages"] % FLUSH_EVERY == 0:
            self.rec.flush(timeout_sec=0)  # started, not waited for: bounds what Rerun buffers
        cls = message_class(topic)
        if cls is None or topic in ("detector/query", "detector/reply", "track/annotations"):
            # (the annotations are the track as Foxglove draws it: Rerun draws its own from the estimates)
            self.stats["skipped"] += 1
            return False
        try:
            msg = None if cls is RawImage else cls.FromString(data)
            if cls is RawImage:  # the pixels viewed in place, not copied twice through protobuf
                index, head, image = decode_frame(data)
                self.frame_image(head, capture_ns, index=index, image=image)
            elif cls is FrameInfo:
                self.frame_info(msg, capture_ns)
            elif cls is Estimate:
                self.estimate(msg, capture_ns)
            elif cls is MultiEstimate:
                self.multi_estimate(msg, capture_ns)
            elif cls is ParticleCloud:
                self.particles(msg, capture_ns)
            elif cls is Template:
                self.template(msg, capture_ns)
            elif cls is RunConfig:
                self.run_config(msg)
            elif cls is ServiceStatus:
                self.service_status(msg, capture_ns)
                self.stats["statuses"] += 1
                return True
        except Exception as exc:  # noqa: BLE001 - any bad message is counted, never fatal
            self.stats["malformed"] += 1
            if self.stats["malformed"] <= 10 or self.stats["malformed"] % 100 == 0:
                log.warning("malformed %s message (%d so far): %s: %s", topic, self.stats["malformed"],
                            type(exc).__name__, exc)
            return False
        self.stats[_KINDS[topic]] += 1
        return True

    # ------------------------------------------------------------------ helpers
    def _centre_error(self, index: int) -> None:
        if index in self._error_done or index not in self._truth or index not in self._est:
            return
        tx, ty = self._truth[index]
        x, y, mx, my = self._est[index]
        self._set_time(index, None)
        self._scalar("plots/error/map_px", math.hypot(x - tx, y - ty))
        self._scalar("plots/error/mmse_px", math.hypot(mx - tx, my - ty))
        self._error_done[index] = True

    @staticmethod
    def _image_to_ground(homography, u: float, v: float) -> tuple[float, float] | None:
        if len(homography) != 9:
            return None
        h = np.asarray(homography, float).reshape(3, 3)
        try:
            p = np.linalg.solve(h, [u, v, 1.0])
        except np.linalg.LinAlgError:
            return None
        if not np.isfinite(p).all() or abs(p[2]) < 1e-12:
            return None
        return float(p[0] / p[2]), float(p[1] / p[2])

    @staticmethod
    def _rotated_box(cx: float, cy: float, w: float, h: float, theta_deg: float) -> list[list[float]]:
        """Closed outline of a w x h box at (cx, cy) turned anticlockwise as displayed (y down)."""
        corners = [list(p) for p in oriented_box_corners(cx, cy, w, h, theta_deg)]
        return corners + corners[:1]


# ---------------------------------------------------------------------- MCAP -> RRD
MCAP_MAGIC = b"\x89MCAP0\r\n"


def mcap_to_rrd(mcap_path: str | os.PathLike, rrd_path: str | os.PathLike, *, spawn: bool = False,
                jpeg_quality: int = 85, track_length: int = 300, connect: str | None = None,
                serve_port: int | None = None, before_close=None) -> dict:
    """Convert a recording written by the recorder to a Rerun .rrd file. Returns the counts
    (``images``, ``estimates``, ``clouds``, ``malformed``, ...), ``truncated`` (the file ended
    mid-record: converted up to there) and ``seconds``. Raises ``ValueError`` if ``mcap_path``
    is not an MCAP file, ``OSError`` if it cannot be read. Streamed with :func:`common.record.reader.stream_messages`
    (bounded memory; chunks that fail their CRC, state more than 64 MiB decompressed or do not
    decompress skipped and counted in ``records_skipped``)."""
    from common.record.reader import ReadReport, RecordingError, stream_messages

    t0 = time.perf_counter()
    mcap_path, rrd_path = Path(mcap_path), Path(rrd_path)
    with open(mcap_path, "rb") as fh:
        if fh.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise ValueError(f"{mcap_path}: not an MCAP file")
    logger = RunLogger.to_file(rrd_path, spawn=spawn, connect=connect, serve_port=serve_port,
                               jpeg_quality=jpeg_quality, track_length=track_length)
    logger.rec.set_log_time_enabled(False)  # the conversion's wall clock means nothing here
    truncated = False
    report = ReadReport()
    kinds: dict = {}
    try:
        try:
            for topic, log_time, data in stream_messages(str(mcap_path), None, report, kinds=kinds):
                cls = message_class(topic)
                encoding, schema = kinds.get(topic, ("", None))
                expected = {cls.DESCRIPTOR.full_name} | ({"foxglove.CompressedImage"} if topic == "frame/image" else set()) \
                    if cls is not None else set()
                if cls is not None and (encoding != "protobuf" or schema not in expected):
                    logger.stats["messages"] += 1
                    logger.stats["skipped"] += 1
                    log.warning("channel %s: encoding %r schema %r, expected protobuf %s; skipped",
                                topic, encoding, schema, cls.DESCRIPTOR.full_name)
                    continue
                logger.log_message(topic, data, log_time)
        except RecordingError as exc:
            raise ValueError(str(exc)) from None
        if report.cut:  # a recorder killed mid-record
            truncated = True
            log.warning("%s: read stopped early (%s); converted what was read", mcap_path, report.cut)
        if report.skipped:
            log.warning("%s: records skipped: %s", mcap_path, report.skipped)
        if before_close is not None:  # e.g. a gRPC server kept up for late viewers (it closes with the logger)
            before_close()
    finally:
        logger.close()
    return {**logger.stats, "truncated": truncated, "records_skipped": dict(report.skipped), "rrd": str(rrd_path),
            "seconds": round(time.perf_counter() - t0, 3)}


def open_viewer(rrd_path: str | os.PathLike) -> bool:
    """Open the Rerun viewer on a file (detached); False when no display is available."""
    import subprocess

    if not display_available():
        return False
    subprocess.Popen([sys.executable, "-m", "rerun", str(rrd_path)], start_new_session=True,
                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return True
