"""Tracker service: one shell, two modes.

- **Single target** (``init_box``): runs :class:`common.single_target.runner.Tracker`, querying the detector
  service. Receives frame infos (time, homography), and the frame images too when (and only when)
  the settings stabilise (the camera motion is estimated here, from the pixels). The Tracker is the
  in-process one with a detector client that sends queries (:mod:`common.detector.remote`): the
  template on the first frame, one batched query with all hypotheses per frame, and, as the
  settings ask, the scale search's and the re-acquisition's queries and the template adaptation's
  PEAK, the adapted template going out on the ``template`` key with a new version. Publishes the
  estimate and the particle cloud. A missing reply (detector down, timeout) is "no observation":
  the filter predicts only.
- **Several articulated targets** (``multi``, ``--filter epmcmc-elpda | epmcmc-pda | jpda-pf``):
  runs :class:`common.multitarget.runner.MultiTracker` on the frame infos (no pixels); every
  question of the filter about a frame's colours goes to the detector as a HISTOGRAMS or
  SIMILARITY query (:mod:`common.detector.remote`). Publishes one ``track/multi_estimate``
  per frame. A frame whose evidence does not come is counted in ``errors`` and gets an
  ``observed=false`` estimate of the particles as the filter left them; before the filter has
  started (no reference histograms yet) it gets none.

Both share the shell (:func:`serve`): the subscriptions, the detector's presence, the queries
and their replies, the status, and the teardown. With ``skip_stale`` (live sources) frames are
tracked in order while at most ``max_lag_frames`` behind, the stale ones beyond that skipped and
counted (:class:`services.frame_infos.InfoQueue`). Run: ``python -m services.tracker --help``.
"""

from __future__ import annotations

import itertools
import logging
import time

from pydantic import BaseModel, ConfigDict, Field, model_validator

from common.detector.template import Template
from common.detector.remote import QueryDetector
from common.msgs import ScoreQuery, ScoreReply
from common.msgs.convert import estimate_msg, info_frame, info_homography, particles_msg, template_to_msg
from common.single_target.runner import InitError, Tracker, stabilises
from common.settings import TrackerSettings
from common.tracking.observation import ObservationUnavailable
from services import options
from services.bus import (BusConfig, Counters, Inbox, Presence, ServiceShell, Stopper, ns_attachment,
                          publisher, query_options)
from services.frame_infos import InfoQueue, ReplyPicker
from services.frame_images import FrameImages

log = logging.getLogger("polartrack.tracker")


class TrackerServiceSettings(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", use_attribute_docstrings=True)

    init_box: tuple[float, float, float, float] | None = None
    """target box x, y, w, h in the first frame (single-target filters)"""
    multi: str | None = None
    """a multi-target run (common.multitarget.runner.MultiRun as JSON: method, config, first-frame
    person boxes, seed); set: the multi-target mode"""
    settings: TrackerSettings = Field(default_factory=TrackerSettings)
    """the filter's settings"""
    client: str = "tracker"
    """name in queries (the detector caches regions per client)"""
    query_timeout_s: float = Field(2.0, gt=0)
    """querier timeout: no reply by then = no observation"""
    skip_stale: bool = False
    """live source: skip stale frames (see max_lag_frames)"""
    max_lag_frames: int | None = Field(None, ge=0)
    """live source: frames are tracked in order while at most this many newer ones wait; older ones are
    stale, skipped and counted (0: always the newest). Default: 14 for the single-target filters, which
    keep up with 30 fps on average, so that a burst of slow frames is caught up; 0 for the multi-target
    ones, slower than the frame rate, where a lag would only add latency. Keep it well below the
    detector's max_frames (24): a query must reach the detector before its frame is dropped there"""
    publish_particles: bool = True
    """publish the particle cloud every frame"""
    detector_wait_s: float = Field(30.0, ge=0)
    """wait this long for the detector at start"""
    template_timeout_s: float = Field(30.0, gt=0)
    """timeout of the template query (first frame)"""
    image_timeout_s: float = Field(5.0, gt=0)
    """stabilising: how long a frame info waits for its image (a frame whose image never comes is
    skipped and counted in errors)"""

    @model_validator(mode="after")
    def _one_mode(self):
        if self.init_box is None and not self.multi:
            raise ValueError("give init_box (X,Y,W,H of the target in the first frame) or multi (a multi-target run)")
        return self

    def lag_frames(self) -> int:
        """``max_lag_frames``, or this mode's default."""
        return self.max_lag_frames if self.max_lag_frames is not None else (0 if self.multi else 14)


def warm_up() -> None:
    """Load the compiled kernel density (the MAP estimate) before the first frame, not during it."""
    import numpy as np

    from common.tracking.state import kernel_mode_index

    rng = np.random.default_rng(0)
    kernel_mode_index(rng.normal(size=(8, 2)), np.full(8, 0.125))
    kernel_mode_index(rng.normal(size=(8, 2)), np.full(8, 0.125), max_points=4)  # the loop for large clouds


class SingleTarget:
    """The single-target mode: :class:`common.single_target.runner.Tracker` with a detector client over queries."""

    def __init__(self, cfg: TrackerServiceSettings, shell: "DetectorLink"):
        if cfg.init_box is None:
            raise ValueError("the tracker needs init_box (single target) or multi (multi-target)")
        warm_up()
        self.cfg, self.shell, self.st = cfg, shell, cfg.settings
        session, bus = shell.session, shell.bus
        # subscribed before any frame can arrive; dropped on the first frame if the source's
        # homography makes stabilisation unnecessary ("auto")
        self.images = (FrameImages(session, bus.key("frame/image"), shell.c, keep=cfg.lag_frames() + 3,
                                   guard=shell.guard) if self.st.stabilise != "off" else None)
        self.pub_est = publisher(session, bus.key("track/estimate"))
        self.pub_cloud = publisher(session, bus.key("track/particles"))
        self.frame_index = 0
        self.att = b""
        self.detector = QueryDetector(shell.ask, cfg.client, self._publish_template)
        self.tracker: Tracker | None = None
        log.info("tracker up (%s)", self.st.filter)

    def _publish_template(self, template: Template, version: int) -> None:
        data = template_to_msg(template, version, self.frame_index).SerializeToString()
        self.shell.template_bytes = data
        self.shell.pub_template.put(data, attachment=self.att)

    def step(self, info, skipped: int, stopper: Stopper) -> bool:
        """Track one frame and publish its estimate; False when nothing was published."""
        c, cfg, st = self.shell.c, self.cfg, self.st
        self.att = ns_attachment(info.capture_ns)
        self.frame_index = int(info.index)
        if self.tracker is None and self.images is not None and not stabilises(st, info_homography(info)):
            self.images.close()
            self.images = None
        image = None
        if self.images is not None:
            image = self.images.get(info.index, cfg.image_timeout_s, stopper)
            if image is None:
                c.add("errors")
                log.error("no image for frame %d after %.1f s: frame skipped", info.index, cfg.image_timeout_s)
                return False
        frame = info_frame(info, image)
        t0 = time.perf_counter()
        if self.tracker is None:
            try:
                self.tracker = Tracker.start(frame, cfg.init_box, st, self.detector)
            except (ObservationUnavailable, InitError, ValueError) as exc:
                c.add("errors")
                log.error("cannot start on frame %d: %s", info.index, exc)
                return False
            except Exception as exc:  # noqa: BLE001 - nothing a message holds stops the service
                c.add("errors")
                self.shell.guard.log.warning("start", f"cannot start on frame {info.index}: {type(exc).__name__}: {exc}")
                return False
        state = self.tracker.step(frame)
        step_ms = 1e3 * (time.perf_counter() - t0)
        est = estimate_msg(info.index, info.capture_ns, state, st.filter, skipped, step_ms)
        self.pub_est.put(est.SerializeToString(), attachment=self.att)
        if cfg.publish_particles and (cloud := particles_msg(info.index, state)) is not None:
            self.pub_cloud.put(cloud.SerializeToString(), attachment=self.att)
        return True

    def close(self) -> None:
        if self.images is not None:
            self.images.close()


class MultiTarget:
    """The multi-target mode: :class:`common.multitarget.runner.MultiTracker`, its colour evidence over queries."""

    def __init__(self, cfg: TrackerServiceSettings, shell: "DetectorLink"):
        from common.multitarget.runner import MultiRun

        self.cfg, self.shell = cfg, shell
        self.run = MultiRun.from_json(cfg.multi)
        self.pub_est = publisher(shell.session, shell.bus.key("track/multi_estimate"))
        self.ids = itertools.count(1)
        self.tracker = None
        log.info("tracker up (%s, %d targets, %d parts, %d particles)", self.run.method, len(self.run.boxes),
                 self.run.config.n_parts, self.run.config.n_particles)

    def step(self, info, skipped: int, stopper: Stopper) -> bool:
        from common.msgs.convert import multi_estimate_msg
        from common.multitarget.runner import MultiTracker
        from common.detector.remote import EvidenceUnavailable, QueryPartEvidence

        c, run = self.shell.c, self.run
        size = (int(info.width), int(info.height))
        ev = QueryPartEvidence(self.shell.ask, self.cfg.client, int(info.index), size, run.config.histogram, self.ids)
        t0 = time.perf_counter()
        try:
            if self.tracker is None:
                self.tracker = MultiTracker(run, ev)
            state = self.tracker.step(info.time_s, ev)
            msg = multi_estimate_msg(int(info.index), state, run, info.capture_ns, 1e3 * (time.perf_counter() - t0))
        except EvidenceUnavailable as exc:
            c.add("errors")
            if self.tracker is None:
                log.error("frame %d: no reference histograms (%s): not started", info.index, exc)
                return False
            log.warning("frame %d: no evidence (%s): prediction only", info.index, exc)
            msg = self.tracker.prediction_msg(int(info.index), info.time_s, info.capture_ns,
                                              1e3 * (time.perf_counter() - t0))
        except ValueError as exc:  # InitError among them
            c.add("errors")
            log.error("cannot start on frame %d: %s", info.index, exc)
            return False
        msg.frames_skipped = skipped
        self.pub_est.put(msg.SerializeToString(), attachment=ns_attachment(info.capture_ns))
        return True

    def close(self) -> None:
        pass


class DetectorLink:
    """What both modes share on the bus: the session, the detector querier and its presence, the
    template kept for a detector that lost it, the counters and the message guard (the service's
    own start and teardown: :class:`services.bus.ServiceShell`)."""

    def __init__(self, session, bus: BusConfig, cfg: TrackerServiceSettings, c: Counters, guard):
        self.session, self.bus, self.cfg, self.c, self.guard = session, bus, cfg, c, guard
        self.picker = ReplyPicker(c, log, guard)
        self.querier = session.declare_querier(bus.key("detector/score"), timeout=cfg.query_timeout_s,
                                               **query_options())
        self.pub_template = publisher(session, bus.key("template"))
        self.presence = Presence(session, bus)
        self.template_bytes = b""
        """The current template, re-sent to a detector that lost it."""

    def _get(self, q: ScoreQuery) -> ScoreReply | None:
        if "detector" not in self.presence:
            return None  # detector down: no observation now, not after a timeout
        payload = q.SerializeToString()
        att = ns_attachment(time.time_ns())  # the sender's id: the detector answers the run's tracker only
        # the first template waits for a detector that is still starting; a later one (the template
        # re-registered on the target's segment) is a frame's query like the others
        first = q.kind == ScoreQuery.TEMPLATE and not self.template_bytes
        replies = (self.session.get(self.bus.key("detector/score"), payload=payload,
                                    timeout=self.cfg.template_timeout_s, attachment=att, **query_options())
                   if first else self.querier.get(payload=payload, attachment=att))
        return self.picker.first(replies, q)

    def ask(self, q: ScoreQuery) -> ScoreReply | None:
        """The detector's reply to ``q`` (None: no detector, or no reply in time)."""
        rep = self._get(q)
        if rep is not None and rep.status == ScoreReply.NO_TEMPLATE and self.template_bytes:
            self.pub_template.put(self.template_bytes)  # a restarted detector lost the template: give it again
            time.sleep(0.05)  # let the detector install it before the one retry
            rep = self._get(q)
        if q.kind == ScoreQuery.TEMPLATE and rep is not None and rep.status == ScoreReply.OK:
            self.template_bytes = rep.template.SerializeToString()
        return rep


def serve(bus: BusConfig, cfg: TrackerServiceSettings, stopper: Stopper) -> Counters:
    """Track every frame info until the end of stream or ``stopper``, in the mode ``cfg`` sets."""
    service = ServiceShell(bus, "tracker", log)
    c, guard = service.counters, service.guard
    inbox = Inbox()
    with service:
        service.subscribe("frame/info", inbox.callback("info"))
        infos = InfoQueue(inbox, cfg.skip_stale, cfg.lag_frames(), c, log, guard)
        shell = DetectorLink(service.session, bus, cfg, c, guard)
        mode = None
        try:
            mode = (MultiTarget if cfg.multi else SingleTarget)(cfg, shell)
            status = service.alive()
            if not shell.presence.wait("detector", cfg.detector_wait_s, stopper):
                log.warning("no detector on the bus after %.0f s", cfg.detector_wait_s)
            skipped = 0
            while not stopper.stopped:
                info, n_skipped = infos.next(stopper)
                skipped += n_skipped
                if info is None:
                    continue
                if info.end_of_stream:
                    log.info("end of stream after %d frames", info.index)
                    break
                try:
                    published = mode.step(info, skipped, stopper)
                except Exception as exc:  # noqa: BLE001 - nothing a message holds stops the service
                    c.add("errors")
                    guard.rejects.add("step", type(exc).__name__)
                    guard.log.warning("step", f"frame {info.index}: step failed ({type(exc).__name__}: {exc}): "
                                      "no estimate")
                    continue
                if published:
                    c.add("published")
                    status.tick()
            shell.picker.drain()
            status.final()
        finally:
            if mode is not None:
                mode.close()
            shell.presence.close()
    return c


def run_keys(spec, settings, path: str) -> dict:
    """The tracker's keys from the run file (``--run``): the first box, the resolved settings,
    and skipping stale frames unless every frame waits for its estimate (consumer pacing)."""
    return {"init_box": spec.init_box, "settings": settings, "skip_stale": spec.pace != "consumer"}


def main(argv: list[str] | None = None) -> int:
    bus, cfg, _ = options.start("tracker", __doc__, TrackerServiceSettings, argv, run=run_keys)
    serve(bus, cfg, Stopper())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
