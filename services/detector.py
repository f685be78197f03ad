"""Detector service: answers batched polar-match queries over Zenoh.

Holds the last few frames and the recent templates (by version); answers "frame F, these N
hypotheses, at resampling factor k" with scores, the template query of the first frame, and the
template adaptation's PEAK (refined angle, score and P-matrix at one point), and the multi-target
filters' part-evidence questions (HISTOGRAMS, SIMILARITY: :mod:`common.detector.remote`,
one integral histogram per frame). Each query is
answered with the same functions an in-process run calls (:mod:`common.detector.client`), on
the same kept per-frame observation (regions prepared once per client and frame), so the
numbers are bit-identical. Publishes a copy of every query and reply for the recorder (Zenoh
queries are invisible to subscribers). Run: ``python -m services.detector --help``.
"""

from __future__ import annotations

import logging
import time
from collections import OrderedDict


from common.msgs import ScoreQuery, ScoreReply
from common.msgs import Template as TemplateMsg
from common.msgs.convert import msg_to_template
from common.detector.server import PART_KINDS
from common.detector.server import DetectorCore, DetectorSettings, warm_up
from services import options
from common.validation import MAX_CLIENT_CHARS, FrameOrder, Invalid, decode
from services.bus import (BusConfig, Counters, Inbox, ServiceShell, Stopper, attachment_sender, ns_attachment, payload_bytes)
from services.frame_images import decode_image
from services.shm_populate import SegmentPopulator

log = logging.getLogger("polartrack.detector")


def serve(bus: BusConfig, settings: DetectorSettings, stopper: Stopper) -> Counters:
    warm_up()
    core = DetectorCore(settings)
    shell = ServiceShell(bus, "detector", log, core.counters)
    c, guard = shell.counters, shell.guard
    core.rejects = guard.rejects  # the core's malformed queries in the same table
    inbox = Inbox()
    capture_ns: OrderedDict[int, int] = OrderedDict()
    image_order = FrameOrder()
    with shell:
        shell.subscribe("frame/image", inbox.callback("image", maxlen=settings.max_frames))
        shell.subscribe("template", inbox.callback("template", maxlen=64))
        shell.queryable("detector/score", inbox.callback("query", maxlen=4 * settings.max_pending))
        pub_query = shell.publisher("detector/query")
        pub_reply = shell.publisher("detector/reply")
        pub_template = shell.publisher("template")
        status = shell.alive()
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
            frame is gone for good, no template is held at all, or it waited ``wait_frame_s``)."""
            _query, _raw, q, _sender, deadline = item
            if time.monotonic() >= deadline or stopper.stopped:
                return True
            if q.frame_index not in core.frames:
                return bool(core.frames) and q.frame_index < next(iter(core.frames))  # dropped already
            # an adapted template travels on the template key: the query asking for it may overtake it;
            # a detector holding none (restarted) waits for nothing: the querier re-sends its template
            # only once told NO_TEMPLATE, so that must come at once, not after a wait the querier may
            # not outlast (a restarted detector's late NO_TEMPLATE had left a run unobserved to its end)
            return (q.kind == ScoreQuery.TEMPLATE or q.kind in PART_KINDS or q.template_version in core.templates
                    or not core.templates)

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
    return c


def main(argv: list[str] | None = None) -> int:
    bus, settings, _ = options.start("detector", __doc__, DetectorSettings, argv)
    serve(bus, settings, Stopper())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
