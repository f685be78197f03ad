"""Tracker service: runs the configured filter, querying the detector once per frame.

Receives frame infos (time, homography; never pixels), asks the detector for the template on
the first frame, then per frame makes one batched query with all hypotheses through
:class:`RemoteObservation`, and publishes the estimate and the particle cloud. A missing reply
(detector down, timeout) is "no observation": the filter predicts only. With ``skip_stale``
(live sources) it skips to the newest frame when it falls behind, counting the skipped ones.
Run: ``python -m services.tracker --help``.
"""

from __future__ import annotations

import argparse
import itertools
import logging
import time

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from common.detector.matcher import check_hypotheses
from common.msgs import FrameInfo, ScoreQuery, ScoreReply, pack, unpack
from common.msgs.convert import estimate_msg, particles_msg
from common.runner import make_filter
from common.settings import TrackerSettings
from common.tracking.observation import ObservationUnavailable
from services import options
from services.bus import BusConfig, Counters, Inbox, Presence, Stopper, ns_attachment, open_session, payload_bytes, publisher

log = logging.getLogger("polartrack.tracker")


class TrackerServiceSettings(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    init_box: tuple[float, float, float, float] = Field(description="target box x, y, w, h in the first frame")
    settings: TrackerSettings = Field(default_factory=TrackerSettings, description="the filter's settings")
    client: str = Field("tracker", description="name in queries (the detector caches regions per client)")
    query_timeout_s: float = Field(2.0, gt=0, description="querier timeout: no reply by then = no observation")
    skip_stale: bool = Field(False, description="live source: skip to the newest frame when behind")
    publish_particles: bool = Field(True, description="publish the particle cloud every frame")
    detector_wait_s: float = Field(30.0, ge=0, description="wait this long for the detector at start")
    template_timeout_s: float = Field(30.0, gt=0, description="timeout of the template query (first frame)")


class RemoteObservation:
    """A :class:`common.tracking.observation.FrameObservation` answered by the detector service."""

    _ids = itertools.count(1)

    def __init__(self, info: FrameInfo, ask, client: str, template_version: int, resend_template=None):
        self.info = info
        self.time = info.time_s
        self.homography = np.asarray(info.homography, float).reshape(3, 3) if len(info.homography) == 9 else None
        self.image_size = (int(info.width), int(info.height))
        self.ask = ask
        self.client = client
        self.template_version = template_version
        self.resend_template = resend_template

    def _query(self, kind: int, hyps: np.ndarray) -> ScoreReply:
        q = ScoreQuery(request_id=next(self._ids), client=self.client, frame_index=self.info.index, kind=kind,
                       count=len(hyps), hypotheses=pack(hyps), template_version=self.template_version)
        rep = self.ask(q)
        if rep is not None and rep.status == ScoreReply.NO_TEMPLATE and self.resend_template is not None:
            self.resend_template()  # a restarted detector lost the template: give it again, retry once
            rep = self.ask(q)
        if rep is None:
            raise ObservationUnavailable(f"no reply for frame {self.info.index}")
        if rep.status != ScoreReply.OK:
            raise ObservationUnavailable(f"detector: {ScoreReply.Status.Name(rep.status)}: {rep.error}")
        return rep

    def score_at(self, hyps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        hyps = check_hypotheses(hyps, 3)
        rep = self._query(ScoreQuery.AT, hyps)
        return unpack(rep.scores, np.float64, (len(hyps),)), unpack(rep.valid, np.uint8, (len(hyps),)).astype(bool)

    def score_grid(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xy = check_hypotheses(xy, 2)
        rep = self._query(ScoreQuery.GRID, xy)
        n = len(xy)
        return unpack(rep.scores, np.float64, (n, rep.angles)), unpack(rep.valid, np.uint8, (n,)).astype(bool)


def serve(bus: BusConfig, cfg: TrackerServiceSettings, stopper: Stopper) -> Counters:
    c = Counters("tracker")
    inbox = Inbox()
    st = cfg.settings
    with open_session(bus) as session:
        sub = session.declare_subscriber(bus.key("frame/info"), inbox.callback("info"))
        querier = session.declare_querier(bus.key("detector/score"), timeout=cfg.query_timeout_s)
        pub_est = publisher(session, bus.key("track/estimate"))
        pub_cloud = publisher(session, bus.key("track/particles"))
        pub_status = publisher(session, bus.key("status/tracker"))
        token = session.liveliness().declare_token(bus.key("alive/tracker"))
        presence = Presence(session, bus)
        if not presence.wait("detector", cfg.detector_wait_s, stopper):
            log.warning("no detector on the bus after %.0f s", cfg.detector_wait_s)

        def ask(q: ScoreQuery, timeout: float | None = None) -> ScoreReply | None:
            if "detector" not in presence:
                return None  # detector down: no observation now, not after a timeout
            replies = (querier.get(payload=q.SerializeToString()) if timeout is None else
                       session.get(bus.key("detector/score"), payload=q.SerializeToString(), timeout=timeout))
            for reply in replies:
                if reply.ok is not None:
                    try:
                        return ScoreReply.FromString(reply.ok.payload.to_bytes())
                    except Exception as exc:  # noqa: BLE001
                        c.add("malformed")
                        log.warning("malformed reply: %s", exc)
            return None

        filt = None
        template_version = 0
        template_bytes = b""
        pub_template = publisher(session, bus.key("template"))

        def resend_template() -> None:
            pub_template.put(template_bytes)
            time.sleep(0.05)  # let the detector install it before the retry
        skipped = 0
        last_status = time.monotonic()
        log.info("tracker up (%s)", st.filter)
        while not stopper.stopped:
            if not inbox.wait(0.2):
                continue
            sample = inbox.pop("info")
            if sample is None:
                continue
            if cfg.skip_stale:
                while inbox.pending("info") and not stopper.stopped:
                    newer = inbox.pop("info")
                    try:
                        if FrameInfo.FromString(payload_bytes(newer)).end_of_stream:
                            sample = newer
                            break
                    except Exception:  # noqa: BLE001
                        pass
                    sample = newer
                    skipped += 1
                    c.add("dropped")
            c.add("received")
            try:
                info = FrameInfo.FromString(payload_bytes(sample))
            except Exception as exc:  # noqa: BLE001
                c.add("malformed")
                log.warning("malformed frame info: %s", exc)
                continue
            if info.end_of_stream:
                log.info("end of stream after %d frames", info.index)
                break
            att = ns_attachment(info.capture_ns)
            if filt is None:
                x, y, w, h = cfg.init_box
                tq = ScoreQuery(request_id=0, client=cfg.client, frame_index=info.index, kind=ScoreQuery.TEMPLATE,
                                count=1, hypotheses=pack(np.array([[x + w / 2, y + h / 2, x, y, w, h]])))
                rep = ask(tq, timeout=cfg.template_timeout_s)
                if rep is None or rep.status != ScoreReply.OK:
                    c.add("errors")
                    log.error("no template from the detector for frame %d: %s", info.index,
                              "no reply" if rep is None else rep.error)
                    continue
                template_version = rep.template.version
                template_bytes = rep.template.SerializeToString()
                H = np.asarray(info.homography, float).reshape(3, 3) if len(info.homography) == 9 else None
                filt = make_filter(st, cfg.init_box, H, info.time_s)
            t0 = time.perf_counter()
            state = filt.step(info.time_s, RemoteObservation(info, ask, cfg.client, template_version, resend_template))
            step_ms = 1e3 * (time.perf_counter() - t0)
            est = estimate_msg(info.index, info.capture_ns, state, st.filter, skipped, step_ms)
            pub_est.put(est.SerializeToString(), attachment=att)
            if cfg.publish_particles and (cloud := particles_msg(info.index, state)) is not None:
                pub_cloud.put(cloud.SerializeToString(), attachment=att)
            c.add("published")
            if time.monotonic() - last_status > 1.0:
                pub_status.put(c.status().SerializeToString())
                last_status = time.monotonic()
        pub_status.put(c.status(final=True).SerializeToString())
        presence.close()
        token.undeclare()
        sub.undeclare()
    return c


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m services.tracker", description=__doc__)
    options.add_bus_arguments(p)
    p.add_argument("--init", dest="init_box", type=lambda t: tuple(float(v) for v in t.split(",")),
                   metavar="X,Y,W,H", help="target box in the first frame")
    p.add_argument("--client", help="client name in queries")
    p.add_argument("--skip-stale", dest="skip_stale", action="store_const", const=True, help="live source")
    args = p.parse_args(argv)
    bus, cfg = options.load("tracker", args, TrackerServiceSettings, ["init_box", "client", "skip_stale"])
    from services.bus import setup_logging

    setup_logging("tracker", args.log_level)
    serve(bus, cfg, Stopper())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
