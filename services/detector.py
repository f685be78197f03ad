"""Detector service: answers batched polar-match queries over Zenoh.

Holds the last few frames and the recent templates (by version); answers "frame F, these N
hypotheses, at resampling factor k" with scores, the template query of the first frame, and the
template adaptation's PEAK (refined angle, score and P-matrix at one point), and the multi-target
filters' part-evidence questions (HISTOGRAMS, SIMILARITY: :mod:`common.part_evidence_queries`,
one integral histogram per frame). Each query is
answered with the same functions an in-process run calls (:mod:`common.detector.client`), on
the same kept per-frame observation (regions prepared once per client and frame), so the
numbers are bit-identical. Publishes a copy of every query and reply for the recorder (Zenoh
queries are invisible to subscribers). Run: ``python -m services.detector --help``.
"""

from __future__ import annotations

import argparse
import logging
import math
import time
from collections import OrderedDict

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from common.detector import FrameCache, PolarMatcher, Template
from common.detector.client import frame_observation, make_template, one_off_grid
from common.detector.layout import N_ANGLES
from common.detector.observation import DetectorObservation
from common.msgs import ScoreQuery, ScoreReply, pack, unpack
from common.msgs import Template as TemplateMsg
from common.msgs.convert import msg_to_template, template_to_msg
from common.part_evidence_queries import PART_KINDS, EvidenceCache, answer_part_query
from services import options
from common.validation import MAX_CLIENT_CHARS, FrameOrder, Invalid, Rejects, check_query, decode
from services.bus import (BusConfig, Counters, Inbox, StatusTicker, Stopper, attachment_sender, make_guard,
                          ns_attachment, open_session, payload_bytes, publisher)
from services.frame_images import decode_image
from services.shm_populate import SegmentPopulator

log = logging.getLogger("polartrack.detector")


class DetectorSettings(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    max_frames: int = Field(24, ge=1, description="Frames held (oldest dropped): bounds memory. Ten more than the "
                            "tracker's max_lag_frames: frames reach the detector before the tracker learns of them")
    wait_frame_s: float = Field(1.0, ge=0, description="How long a query waits for its frame's image to arrive "
                                "(meanwhile the detector answers the other queries)")
    max_clients: int = Field(8, ge=1, le=1024, description="Queriers whose prepared regions are kept (least "
                             "recently used dropped): each holds up to a frame's pyramid (~10 MB at 1280x720)")
    max_pending: int = Field(64, ge=1, le=10_000, description="Queries waiting for their frame or template at "
                             "most (beyond: answered UNKNOWN_FRAME at once)")


MIN_FACTOR, MAX_FACTOR = 1.0 / 64.0, 64.0
"""Resampling factors a query may ask for (beyond them a malformed query could ask for a huge crop)."""

WIDTHS = {ScoreQuery.AT: 3, ScoreQuery.GRID: 2, ScoreQuery.TEMPLATE: 6, ScoreQuery.PEAK: 2}
"""Values per hypothesis of each query kind."""


def query_factor(q: ScoreQuery) -> float:
    """The query's resampling factor (0, unset: 1); ValueError outside [MIN_FACTOR, MAX_FACTOR]."""
    k = 1.0 if q.factor == 0 else float(q.factor)
    if not (math.isfinite(k) and MIN_FACTOR <= k <= MAX_FACTOR):
        raise ValueError(f"resampling factor {q.factor} is outside [{MIN_FACTOR:g}, {MAX_FACTOR:g}]")
    return k


OBSERVATIONS_KEPT = 4
"""Prepared observations kept (per client, frame, factor and template): the scale search and the
template adaptation ask about the frame the filter's query just prepared, so a few are enough,
and each can hold a full frame's pyramid (about 11 MB at 1280x720), fewer than the frames held."""


class DetectorCore:
    """The detector without the bus: frames in, queries in, replies out."""

    def __init__(self, settings: DetectorSettings | None = None):
        self.settings = settings or DetectorSettings()
        self.frames: OrderedDict[int, tuple[np.ndarray, float]] = OrderedDict()
        self.templates: OrderedDict[int, PolarMatcher] = OrderedDict()
        self.caches: OrderedDict[str, FrameCache] = OrderedDict()
        """Per querier (its sender id and client name), least recently used first, at most ``max_clients``."""
        self.rejects = Rejects()
        """Malformed queries per reason (also counted in ``malformed``)."""
        self.observations: OrderedDict[tuple, object] = OrderedDict()
        """(client, frame, factor, template version) -> the frame's observation, kept so the
        template adaptation's PEAK reuses the region the filter's query prepared (as in-process)."""
        self.counters = Counters("detector")
        self.evidence = EvidenceCache(min(4, self.settings.max_frames))
        """The latest frames' integral histograms (multi-target part evidence; tens of MB each, so
        fewer than the frames held: an older frame's is computed again if asked for)."""

    def add_frame(self, index: int, image: np.ndarray, time_s: float) -> None:
        self.frames[index] = (image, time_s)
        while len(self.frames) > self.settings.max_frames:
            self.frames.popitem(last=False)

    def install_template(self, version: int, template: Template) -> None:
        self.templates[version] = PolarMatcher(template)
        while len(self.templates) > 4:
            self.templates.popitem(last=False)

    def _bad(self, reason: str) -> None:
        self.counters.add("malformed")
        self.rejects.add("detector/score", reason)

    def cache_for(self, client: str) -> FrameCache:
        """The querier's region cache (least recently used ones dropped beyond ``max_clients``,
        with their kept observations)."""
        cache = self.caches.get(client)
        if cache is None:
            cache = self.caches[client] = FrameCache()
            while len(self.caches) > self.settings.max_clients:
                gone, _ = self.caches.popitem(last=False)
                for key in [key for key in self.observations if key[0] == gone]:
                    del self.observations[key]
        self.caches.move_to_end(client)
        return cache

    def observation(self, q: ScoreQuery, k: float, matcher: PolarMatcher, image: np.ndarray, time_s: float,
                    querier: str = ""):
        """The frame's observation for the query's client, factor and template (kept for later queries)."""
        client = f"{querier}/{q.client}"
        key = (client, q.frame_index, k, q.template_version)
        obs = self.observations.get(key)
        if obs is None:
            cache = self.cache_for(client)
            obs = self.observations[key] = frame_observation(q.frame_index, time_s, image, matcher, cache, k)
            while len(self.observations) > min(OBSERVATIONS_KEPT, self.settings.max_frames):
                self.observations.popitem(last=False)
        return obs

    @staticmethod
    def parse(q: ScoreQuery) -> tuple[np.ndarray, float]:
        """(hypotheses, factor) of an AT / GRID / TEMPLATE / PEAK query; ValueError when malformed."""
        width = WIDTHS.get(q.kind)
        if width is None:
            raise ValueError(f"unknown query kind {q.kind}")
        hyps = unpack(q.hypotheses, np.float64, (q.count, width))
        if not np.all(np.isfinite(hyps)):
            raise ValueError("hypotheses contain NaN or infinite coordinates")
        k = query_factor(q)
        if q.kind in (ScoreQuery.TEMPLATE, ScoreQuery.PEAK) and q.count != 1:
            raise ValueError(f"a {ScoreQuery.Kind.Name(q.kind)} query has exactly one row")
        return hyps, k

    def precheck(self, q: ScoreQuery) -> ScoreReply | None:
        """The error reply to a query no frame can make answerable (caps, sizes, NaNs, kind,
        factor), counted; None when it may wait for its frame."""
        try:
            check_query(q, PART_KINDS)
            if q.kind not in PART_KINDS:
                self.parse(q)
            elif not np.all(np.isfinite(unpack(q.hypotheses, np.float64, (q.count, 4)))):
                raise ValueError("boxes contain NaN or infinite values")
        except ValueError as exc:
            self._bad(exc.reason if isinstance(exc, Invalid) else "bad_request")
            return ScoreReply(request_id=q.request_id, client=q.client[:MAX_CLIENT_CHARS], frame_index=q.frame_index,
                              status=ScoreReply.BAD_REQUEST, error=str(exc)[:300])
        return None

    def handle(self, q: ScoreQuery, querier: str = "") -> tuple[ScoreReply, TemplateMsg | None]:
        """Answer one query (from sender ``querier``: each querier's regions are its own). Never
        raises: problems become an error status."""
        rep = ScoreReply(request_id=q.request_id, client=q.client[:MAX_CLIENT_CHARS], frame_index=q.frame_index)
        try:
            check_query(q, PART_KINDS)
        except Invalid as exc:
            self._bad(exc.reason)
            rep.status, rep.error = ScoreReply.BAD_REQUEST, str(exc)
            return rep, None
        frame = self.frames.get(q.frame_index)
        if frame is None:
            if q.kind in PART_KINDS:
                self._bad("unknown_frame")
            rep.status, rep.error = ScoreReply.UNKNOWN_FRAME, f"frame {q.frame_index} is not held"
            return rep, None
        image, time_s = frame
        if q.kind in PART_KINDS:
            return self.handle_part(q, image, rep), None
        try:
            hyps, k = self.parse(q)
        except ValueError as exc:
            self._bad("bad_request")
            rep.status, rep.error = ScoreReply.BAD_REQUEST, str(exc)
            return rep, None
        t0 = time.perf_counter()
        try:
            if q.kind == ScoreQuery.TEMPLATE:
                cx, cy, bx, by, bw, bh = (float(v) for v in hyps[0])
                template = make_template(image, (cx, cy), (bx, by, bw, bh), k)
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
            if q.one_off:
                if q.kind != ScoreQuery.GRID:
                    raise ValueError("one_off is for GRID queries only")
                scores, valid = one_off_grid(time_s, image, matcher, k, hyps)
                rep.angles = N_ANGLES
            else:
                obs = self.observation(q, k, matcher, image, time_s, querier)
                if q.kind == ScoreQuery.AT:
                    scores, valid = obs.score_at(hyps)
                    rep.angles = 1
                elif q.kind == ScoreQuery.GRID:
                    scores, valid = obs.score_grid(hyps)
                    rep.angles = N_ANGLES
                else:  # PEAK: the refined angle and score, then the P-matrix, as Tracker._adapt asks them
                    x, y = float(hyps[0, 0]), float(hyps[0, 1])
                    theta, score = obs.refine_peak(x, y)
                    pm = obs.pmatrix_at(x, y)
                    scores, valid = np.array([theta, score], np.float64), np.array([pm is not None])
                    rep.angles = 2
                    if pm is not None:
                        rep.pmatrix = np.ascontiguousarray(pm, np.complex64).tobytes()
                        rep.pmatrix_columns = pm.shape[1]
        except ValueError as exc:
            self._bad("bad_request")
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


    def handle_part(self, q: ScoreQuery, image: np.ndarray, rep: ScoreReply) -> ScoreReply:
        """A HISTOGRAMS or SIMILARITY query (never raises: problems become an error status)."""
        t0 = time.perf_counter()
        try:
            answer_part_query(q, image, self.evidence, rep)
        except ValueError as exc:
            self._bad("bad_request")
            rep.status, rep.error = ScoreReply.BAD_REQUEST, str(exc)
            return rep
        except Exception as exc:  # noqa: BLE001 - a service never stops on one bad query
            log.exception("query %s failed", q.request_id)
            self.counters.add("errors")
            rep.status, rep.error = ScoreReply.INTERNAL_ERROR, f"{type(exc).__name__}: {exc}"
            return rep
        rep.score_ms = 1e3 * (time.perf_counter() - t0)
        return rep


def warm_up() -> None:
    """Compile the numba sampler and start the sampling threads before joining the bus (first
    compilation takes seconds)."""
    rng = np.random.default_rng(0)
    img = (rng.random((160, 160, 3)) * 255).astype(np.float32)
    matcher = PolarMatcher(Template.from_image(img, (80.0, 80.0)))
    obs = DetectorObservation(0, 0.0, img, matcher, FrameCache())
    obs.score_at(np.array([[80.0, 80.0, 0.0]]))
    obs.score_grid(np.array([[80.0, 80.0]]))
    # a batch large enough for the sampling threads (the pool starts here, not on the first frame)
    obs.score_at(np.c_[rng.uniform(70.0, 90.0, (256, 2)), np.zeros(256)])


def serve(bus: BusConfig, settings: DetectorSettings, stopper: Stopper) -> Counters:
    warm_up()
    core = DetectorCore(settings)
    c = core.counters
    guard = make_guard(bus, "detector", c, log)
    core.rejects = guard.rejects  # the core's malformed queries in the same table
    inbox = Inbox()
    capture_ns: OrderedDict[int, int] = OrderedDict()
    image_order = FrameOrder()
    with open_session(bus) as session:
        subs = [
            session.declare_subscriber(bus.key("frame/image"), inbox.callback("image", maxlen=settings.max_frames)),
            session.declare_subscriber(bus.key("template"), inbox.callback("template", maxlen=64)),
        ]
        queryable = session.declare_queryable(bus.key("detector/score"),
                                              inbox.callback("query", maxlen=4 * settings.max_pending))
        pub_query = publisher(session, bus.key("detector/query"))
        pub_reply = publisher(session, bus.key("detector/reply"))
        pub_template = publisher(session, bus.key("template"))
        pub_status = publisher(session, bus.key("status/detector"))
        pub_health = publisher(session, bus.key("health/detector"))
        token = session.liveliness().declare_token(bus.key("alive/detector"))
        log.info("detector up on %s", bus.key("detector/score"))

        segments = SegmentPopulator()

        def drain_images() -> None:
            got = False
            while (s := inbox.pop("image")) is not None:
                got = True
                c.add("received")
                if not guard.accept("frame/image", attachment_sender(s), len(s.payload)):
                    continue
                try:
                    idx, img, ns = decode_image(s)
                    image_order.check(idx)
                except Invalid as exc:
                    guard.reject("frame/image", exc)
                    continue
                except Exception as exc:  # noqa: BLE001
                    guard.reject("frame/image", "undecodable", f"{type(exc).__name__}: {exc}")
                    continue
                image_order.accept(idx)
                capture_ns[idx] = ns
                while len(capture_ns) > settings.max_frames:
                    capture_ns.popitem(last=False)
                core.add_frame(idx, img, capture_ns[idx] * 1e-9)
            if got:
                segments.populate()  # the frames' shared memory, once it is mapped

        def drain_templates() -> None:
            while (s := inbox.pop("template")) is not None:
                m = guard.decode("template", TemplateMsg, payload_bytes(s), attachment_sender(s))
                if m is None:
                    continue
                try:
                    if m.version not in core.templates:
                        core.install_template(m.version, msg_to_template(m))
                except Exception as exc:  # noqa: BLE001
                    guard.reject("template", "bad_template", f"{type(exc).__name__}: {exc}")

        def reply_now(query, payload: bytes, att: bytes | None = None) -> None:
            try:
                query.reply(query.key_expr, payload, **({"attachment": att} if att is not None else {}))
            except Exception as exc:  # noqa: BLE001 - the querier may have gone
                guard.log.warning("reply", f"reply not sent: {exc}")
            query.drop()

        def take_query(query) -> tuple | None:
            """A new query: (query, raw, ScoreQuery, sender, deadline) to answer, or None (answered with an error)."""
            raw = payload_bytes(query)
            sender = attachment_sender(query)
            try:
                guard.senders.check("detector/score/query", sender)
                q = decode(ScoreQuery, raw, "detector/query")
            except Invalid as exc:
                guard.reject("detector/score" if exc.reason != "foreign_sender" else "detector/score/query", exc)
                err = ScoreReply(status=ScoreReply.BAD_REQUEST, error=str(exc)[:200])
                reply_now(query, err.SerializeToString(), ns_attachment(time.time_ns()))
                return None
            bad = core.precheck(q)
            if bad is not None:  # never answerable: at once, and not recorded
                reply_now(query, bad.SerializeToString(), ns_attachment(time.time_ns()))
                return None
            return query, raw, q, sender, time.monotonic() + settings.wait_frame_s

        def ready(item) -> bool:
            """Whether a waiting query can be answered now (its frame and template are here, its
            frame is gone for good, or it waited ``wait_frame_s``)."""
            _query, _raw, q, _sender, deadline = item
            if time.monotonic() >= deadline or stopper.stopped:
                return True
            if q.frame_index not in core.frames:
                return bool(core.frames) and q.frame_index < next(iter(core.frames))  # dropped already
            # an adapted template travels on the template key: the query asking for it may overtake it
            return q.kind == ScoreQuery.TEMPLATE or q.kind in PART_KINDS or q.template_version in core.templates

        def answer(item) -> None:
            query, raw, q, sender, _deadline = item
            reply, new_template = core.handle(q, sender)
            ns = capture_ns.get(q.frame_index, time.time_ns())
            att = ns_attachment(ns)
            payload = reply.SerializeToString()
            reply_now(query, payload, att)
            if reply.status != ScoreReply.BAD_REQUEST:  # the recording holds the queries a replay would ask
                pub_query.put(raw, attachment=att)
                pub_reply.put(payload, attachment=att)
            if new_template is not None:
                pub_template.put(new_template.SerializeToString(), attachment=att)
            c.add("published")

        pending: list[tuple] = []
        """Queries waiting for their frame's image or template, in arrival order: they never hold up
        the others (a query for an unknown frame had held the detector for a second)."""
        status = StatusTicker(pub_status, c, guard=guard, health_pub=pub_health)
        while not stopper.stopped:
            inbox.wait(0.2 if not pending else 0.002)
            drain_images()
            drain_templates()
            c.values["dropped"] = inbox.dropped["image"]
            status.tick()
            while (query := inbox.pop("query")) is not None:
                item = take_query(query)
                if item is None:
                    continue
                if len(pending) >= settings.max_pending:
                    q = item[2]
                    guard.rejects.add("detector/score", "too_many_waiting")
                    busy = ScoreReply(request_id=q.request_id, client=q.client[:MAX_CLIENT_CHARS],
                                      frame_index=q.frame_index, status=ScoreReply.UNKNOWN_FRAME,
                                      error=f"{len(pending)} queries already wait for their frames")
                    reply_now(query, busy.SerializeToString(), ns_attachment(time.time_ns()))
                    continue
                pending.append(item)
            if pending:
                drain_images()
                drain_templates()
                still = []
                for item in pending:
                    if ready(item):
                        answer(item)
                        drain_images()  # frames keep coming while queries are answered
                        drain_templates()
                    else:
                        still.append(item)
                pending = still
        for item in pending:
            answer(item)
        c.values["dropped"] = inbox.dropped["image"]
        status.final()
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
