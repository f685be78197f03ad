"""The tracker service's multi-target mode (``--filter epmcmc-elpda | epmcmc-pda | jpda-pf``).

Runs :class:`common.multitarget_runner.MultiTracker` on the frame infos (no pixels: the tracker
never touches them); every question of the filter about a frame's colours goes to the detector
service as a HISTOGRAMS or SIMILARITY query (:mod:`common.part_evidence_queries`). Publishes one
``track/multi_estimate`` per frame. A frame whose evidence does not come (detector down, timeout,
error reply) is counted in ``errors`` and gets an ``observed=false`` estimate of the particles as
the filter left them (predicted, not weighed); before the filter has started (no reference
histograms yet) it gets none.
Started by :mod:`services.tracker` when its config has ``multi``.
"""

from __future__ import annotations

import itertools
import logging
import time

from common.msgs import ScoreQuery, ScoreReply
from common.multitarget import InitError
from common.multitarget_runner import MultiRun, MultiTracker, multi_estimate_msg
from common.part_evidence_queries import EvidenceUnavailable, QueryPartEvidence
from services.bus import (BusConfig, Counters, Inbox, Presence, StatusTicker, Stopper, make_guard, ns_attachment,
                          open_session, publisher, query_options)
from services.frame_infos import InfoQueue, ReplyPicker

log = logging.getLogger("polartrack.tracker")


def serve_multi(bus: BusConfig, cfg, stopper: Stopper) -> Counters:
    """``cfg``: :class:`services.tracker.TrackerServiceSettings` with ``multi`` set."""
    run = MultiRun.from_json(cfg.multi)
    c = Counters("tracker")
    guard = make_guard(bus, "tracker", c, log)
    picker = ReplyPicker(c, log, guard)
    inbox = Inbox()
    ids = itertools.count(1)
    with open_session(bus) as session:
        sub = session.declare_subscriber(bus.key("frame/info"), inbox.callback("info"))
        infos = InfoQueue(inbox, cfg.skip_stale, cfg.lag_frames(), c, log, guard)
        querier = session.declare_querier(bus.key("detector/score"), timeout=cfg.query_timeout_s, **query_options())
        pub_est = publisher(session, bus.key("track/multi_estimate"))
        pub_status = publisher(session, bus.key("status/tracker"))
        pub_health = publisher(session, bus.key("health/tracker"))
        token = session.liveliness().declare_token(bus.key("alive/tracker"))
        presence = Presence(session, bus)
        if not presence.wait("detector", cfg.detector_wait_s, stopper):
            log.warning("no detector on the bus after %.0f s", cfg.detector_wait_s)

        def ask(q: ScoreQuery) -> ScoreReply | None:
            if "detector" not in presence:
                return None
            return picker.first(querier.get(payload=q.SerializeToString(), attachment=ns_attachment(time.time_ns())), q)

        tracker = None
        status = StatusTicker(pub_status, c, guard=guard, health_pub=pub_health)
        log.info("tracker up (%s, %d targets, %d parts, %d particles)", run.method, len(run.boxes),
                 run.config.n_parts, run.config.n_particles)
        skipped = 0
        while not stopper.stopped:
            info, n_skipped = infos.next(stopper)
            skipped += n_skipped
            if info is None:
                continue
            if info.end_of_stream:
                log.info("end of stream after %d frames", info.index)
                break
            size = (int(info.width), int(info.height))
            ev = QueryPartEvidence(ask, cfg.client, int(info.index), size, run.config.histogram, ids)
            t0 = time.perf_counter()
            try:
                if tracker is None:
                    tracker = MultiTracker(run, ev)
                state = tracker.step(info.time_s, ev)
                msg = multi_estimate_msg(int(info.index), state, run, info.capture_ns,
                                         1e3 * (time.perf_counter() - t0))
            except EvidenceUnavailable as exc:
                c.add("errors")
                if tracker is None:
                    log.error("frame %d: no reference histograms (%s): not started", info.index, exc)
                    continue
                log.warning("frame %d: no evidence (%s): prediction only", info.index, exc)
                msg = tracker.prediction_msg(int(info.index), info.time_s, info.capture_ns,
                                             1e3 * (time.perf_counter() - t0))
            except (InitError, ValueError) as exc:
                c.add("errors")
                log.error("cannot start on frame %d: %s", info.index, exc)
                continue
            except Exception as exc:  # noqa: BLE001 - nothing a message holds stops the service
                c.add("errors")
                guard.rejects.add("step", type(exc).__name__)
                guard.log.warning("step", f"frame {info.index}: step failed ({type(exc).__name__}: {exc}): no estimate")
                continue
            msg.frames_skipped = skipped
            pub_est.put(msg.SerializeToString(), attachment=ns_attachment(info.capture_ns))
            c.add("published")
            status.tick()
        picker.drain()
        status.final()
        presence.close()
        token.undeclare()
        sub.undeclare()
    return c
