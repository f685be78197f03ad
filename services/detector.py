"""Detector service: answers batched polar-match queries over Zenoh.

Holds the last few frames and the current template; answers "frame F, these N hypotheses" with
scores, preparing each frame once per client over only the regions queried (the same
:class:`common.detector.observation.DetectorObservation` code path as an in-process run, so
the scores are bit-identical). Publishes a copy of every query and reply for the recorder
(Zenoh queries are invisible to subscribers). Run: ``python -m services.detector --help``.
"""

from __future__ import annotations

import argparse
import logging
import time
from collections import OrderedDict

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from common.detector import FrameCache, PolarMatcher, Template
from common.detector.layout import N_ANGLES, N_COLUMNS, N_ROWS
from common.detector.observation import DetectorObservation
from common.msgs import RawImage, ScoreQuery, ScoreReply, pack, unpack
from common.msgs import Template as TemplateMsg
from common.msgs import msg_to_image
from services import options
from services.bus import BusConfig, Counters, Inbox, Stopper, attachment_ns, ns_attachment, open_session, payload_bytes, publisher

log = logging.getLogger("polartrack.detector")


class DetectorSettings(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    max_frames: int = Field(8, ge=1, description="Frames held (oldest dropped): bounds memory")
    wait_frame_s: float = Field(1.0, ge=0, description="How long a query waits for its frame's image to arrive")


def template_to_msg(t: Template, version: int, frame_index: int) -> TemplateMsg:
    return TemplateMsg(version=version, rows=t.pmatrix.shape[0], columns=t.pmatrix.shape[1],
                       pmatrix=np.ascontiguousarray(t.pmatrix, np.complex64).tobytes(), centre_x=t.centre[0],
                       centre_y=t.centre[1], box=list(t.box or ()), frame_index=frame_index)


def msg_to_template(m: TemplateMsg) -> Template:
    if m.rows != N_ROWS or m.columns % N_COLUMNS or m.columns == 0:
        raise ValueError(f"template P-matrix {m.rows}x{m.columns}, expected 12 x 34C")
    pm = unpack(m.pmatrix, np.complex64, (m.rows, m.columns))
    return Template(pmatrix=pm, centre=(m.centre_x, m.centre_y), box=tuple(m.box) if len(m.box) == 4 else None)


class DetectorCore:
    """The detector without the bus: frames in, queries in, replies out."""

    def __init__(self, settings: DetectorSettings | None = None):
        self.settings = settings or DetectorSettings()
        self.frames: OrderedDict[int, tuple[np.ndarray, float]] = OrderedDict()
        self.templates: OrderedDict[int, PolarMatcher] = OrderedDict()
        self.caches: dict[str, FrameCache] = {}
        self.counters = Counters("detector")

    def add_frame(self, index: int, image: np.ndarray, time_s: float) -> None:
        self.frames[index] = (image, time_s)
        while len(self.frames) > self.settings.max_frames:
            self.frames.popitem(last=False)

    def install_template(self, version: int, template: Template) -> None:
        self.templates[version] = PolarMatcher(template)
        while len(self.templates) > 4:
            self.templates.popitem(last=False)

    def handle(self, q: ScoreQuery) -> tuple[ScoreReply, TemplateMsg | None]:
        """Answer one query. Never raises: problems become an error status."""
        rep = ScoreReply(request_id=q.request_id, client=q.client, frame_index=q.frame_index)
        frame = self.frames.get(q.frame_index)
        if frame is None:
            rep.status, rep.error = ScoreReply.UNKNOWN_FRAME, f"frame {q.frame_index} is not held"
            return rep, None
        image, time_s = frame
        width = {ScoreQuery.AT: 3, ScoreQuery.GRID: 2, ScoreQuery.TEMPLATE: 6}.get(q.kind)
        try:
            if width is None:
                raise ValueError(f"unknown query kind {q.kind}")
            hyps = unpack(q.hypotheses, np.float64, (q.count, width))
            if not np.all(np.isfinite(hyps)):
                raise ValueError("hypotheses contain NaN or infinite coordinates")
        except ValueError as exc:
            self.counters.add("malformed")
            rep.status, rep.error = ScoreReply.BAD_REQUEST, str(exc)
            return rep, None
        t0 = time.perf_counter()
        try:
            if q.kind == ScoreQuery.TEMPLATE:
                if q.count != 1:
                    raise ValueError("a TEMPLATE query has exactly one row (cx, cy, x, y, w, h)")
                cx, cy, bx, by, bw, bh = hyps[0]
                template = Template.from_image(image, (cx, cy), box=(bx, by, bw, bh))
                version = (max(self.templates) if self.templates else 0) + 1
                self.install_template(version, template)
                tm = template_to_msg(template, version, q.frame_index)
                rep.template.CopyFrom(tm)
                rep.count, rep.angles = 0, 0
                return rep, tm
            matcher = self.templates.get(q.template_version)
            if matcher is None:
                rep.status, rep.error = ScoreReply.NO_TEMPLATE, f"no template version {q.template_version}"
                return rep, None
            cache = self.caches.setdefault(q.client, FrameCache())
            obs = DetectorObservation(q.frame_index, time_s, image, matcher, cache)
            if q.kind == ScoreQuery.AT:
                scores, valid = obs.score_at(hyps)
                rep.angles = 1
            else:
                scores, valid = obs.score_grid(hyps)
                rep.angles = N_ANGLES
        except ValueError as exc:
            self.counters.add("malformed")
            rep.status, rep.error = ScoreReply.BAD_REQUEST, str(exc)
            return rep, None
        except Exception as exc:  # noqa: BLE001 - a service never stops on one bad query
            log.exception("query %s failed", q.request_id)
            self.counters.add("errors")
            rep.status, rep.error = ScoreReply.INTERNAL_ERROR, f"{type(exc).__name__}: {exc}"
            return rep, None
        rep.count = q.count
        rep.scores = pack(scores)
        rep.valid = pack(valid, np.uint8)
        rep.score_ms = 1e3 * (time.perf_counter() - t0)
        return rep, None


def warm_up() -> None:
    """Compile the numba sampler before joining the bus (first compilation takes seconds)."""
    rng = np.random.default_rng(0)
    img = (rng.random((160, 160, 3)) * 255).astype(np.float32)
    matcher = PolarMatcher(Template.from_image(img, (80.0, 80.0)))
    obs = DetectorObservation(0, 0.0, img, matcher, FrameCache())
    obs.score_at(np.array([[80.0, 80.0, 0.0]]))
    obs.score_grid(np.array([[80.0, 80.0]]))


def serve(bus: BusConfig, settings: DetectorSettings, stopper: Stopper) -> Counters:
    warm_up()
    core = DetectorCore(settings)
    c = core.counters
    inbox = Inbox()
    capture_ns: OrderedDict[int, int] = OrderedDict()
    with open_session(bus) as session:
        subs = [
            session.declare_subscriber(bus.key("frame/image"), inbox.callback("image", maxlen=settings.max_frames)),
            session.declare_subscriber(bus.key("template"), inbox.callback("template")),
        ]
        queryable = session.declare_queryable(bus.key("detector/score"), inbox.callback("query"))
        pub_query = publisher(session, bus.key("detector/query"))
        pub_reply = publisher(session, bus.key("detector/reply"))
        pub_template = publisher(session, bus.key("template"))
        pub_status = publisher(session, bus.key("status/detector"))
        token = session.liveliness().declare_token(bus.key("alive/detector"))
        log.info("detector up on %s", bus.key("detector/score"))

        def drain_images() -> None:
            while (s := inbox.pop("image")) is not None:
                c.add("received")
                try:
                    msg = RawImage.FromString(payload_bytes(s))
                    idx = int(msg.frame_id)
                    img = msg_to_image(msg)
                except Exception as exc:  # noqa: BLE001
                    c.add("malformed")
                    log.warning("malformed frame image: %s", exc)
                    continue
                capture_ns[idx] = attachment_ns(s) or msg.timestamp.ToNanoseconds()
                while len(capture_ns) > settings.max_frames:
                    capture_ns.popitem(last=False)
                core.add_frame(idx, img, capture_ns[idx] * 1e-9)

        def drain_templates() -> None:
            while (s := inbox.pop("template")) is not None:
                try:
                    m = TemplateMsg.FromString(payload_bytes(s))
                    if m.version not in core.templates:
                        core.install_template(m.version, msg_to_template(m))
                except Exception as exc:  # noqa: BLE001
                    c.add("malformed")
                    log.warning("malformed template: %s", exc)

        last_status = time.monotonic()
        while not stopper.stopped:
            inbox.wait(0.2)
            drain_images()
            drain_templates()
            if time.monotonic() - last_status > 1.0:
                c.values["dropped"] = inbox.dropped["image"]
                pub_status.put(c.status().SerializeToString())
                last_status = time.monotonic()
            query = inbox.pop("query")
            if query is None:
                continue
            raw = payload_bytes(query)
            try:
                q = ScoreQuery.FromString(raw)
            except Exception as exc:  # noqa: BLE001
                c.add("malformed")
                log.warning("malformed query: %s", exc)
                err = ScoreReply(status=ScoreReply.BAD_REQUEST, error=f"not a ScoreQuery: {exc}")
                query.reply(query.key_expr, err.SerializeToString())
                query.drop()
                continue
            deadline = time.monotonic() + settings.wait_frame_s
            while q.frame_index not in core.frames and time.monotonic() < deadline and not stopper.stopped:
                inbox.wait(0.01)
                drain_images()
            drain_templates()
            reply, new_template = core.handle(q)
            ns = capture_ns.get(q.frame_index, time.time_ns())
            att = ns_attachment(ns)
            payload = reply.SerializeToString()
            query.reply(query.key_expr, payload, attachment=att)
            query.drop()
            pub_query.put(raw, attachment=att)
            pub_reply.put(payload, attachment=att)
            if new_template is not None:
                pub_template.put(new_template.SerializeToString(), attachment=att)
            c.add("published")
        c.values["dropped"] = inbox.dropped["image"]
        pub_status.put(c.status(final=True).SerializeToString())
        token.undeclare()
        for s in subs:
            s.undeclare()
        queryable.undeclare()
    return c


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m services.detector", description=__doc__)
    options.add_bus_arguments(p)
    p.add_argument("--max-frames", dest="max_frames", type=int, help="frames held")
    args = p.parse_args(argv)
    bus, settings = options.load("detector", args, DetectorSettings, ["max_frames"])
    from services.bus import setup_logging

    setup_logging("detector", args.log_level)
    serve(bus, settings, Stopper())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
