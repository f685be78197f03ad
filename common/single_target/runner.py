"""In-process tracking: source frames -> detector observations -> filter steps.

:class:`Tracker` is the single-target tracker every way of running uses: the filter with its
template and the per-frame mechanisms (stabilisation, matching at the target's scale, template
adaptation, turning the particles with the camera, the moving-target cue, re-acquisition, the
template re-registered on the target's segment), each switched in the settings. What needs
the frame's pixels and the template goes through a detector client
(:mod:`common.detector.client`): in-process here (``track_frames``), queries to the detector
service in the tracker service, recorded replies on offline replay. The same source, seed and
settings therefore give bit-identical estimates in-process, multi-process and on replay.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from typing import Iterable, Iterator

import numpy as np
from scipy.stats import beta as beta_dist

from common.single_target.adaptation import TemplateAdapter, registered_point
from common.detector import Template
from common.detector.template import FlatTemplateError, rotate_pmatrix
from common.detector.client import DetectorClient, LocalDetector
from common.single_target.motion_cue import MotionCue
from common.single_target.reacquire import Detection, Reacquirer
from common.single_target.scale import ScaleTracker
from common.single_target.segment import Registrar
from common.settings import SYNTHETIC_BETA, TrackerSettings
from common.sources import Frame
from common.single_target.stabilise import CameraMotionEstimator, grey
from common.single_target.target_flow import measure_scale_change
from common.tracking import RBPF, SIR, BetaRatioLikelihood, InitialState, TrackState, WindowedML, wrap_degrees
from common.tracking.state import box_axes
from common.tracking.camera import apply_homography, homography_jacobian, image_to_world, invert_homography
from common.tracking.motion import NearConstantVelocity
from common.tracking.state import Estimate, InitError
from common.tracking.observation import CuedObservation, ObservationUnavailable


def check_init_box(box: tuple[float, float, float, float], width: int, height: int) -> None:
    """InitError unless ``box`` (x, y, w, h) is finite, of positive size, with its centre in the
    ``width`` x ``height`` frame. A centre nearer the edge than the template's footprint is allowed:
    the template reads the frame reflected across its edge there (:func:`common.detector.client.make_template`),
    as the filter's scores of a target near the edge do."""
    x, y, w, h = box
    if not all(np.isfinite(v) for v in box):
        raise InitError(f"--init {box}: values must be finite")
    if w <= 0 or h <= 0:
        raise InitError(f"--init {x:g},{y:g},{w:g},{h:g}: width and height must be positive")
    cx, cy = x + w / 2, y + h / 2
    if not (0 <= cx < width and 0 <= cy < height):
        raise InitError(f"--init {x:g},{y:g},{w:g},{h:g}: the box centre ({cx:g}, {cy:g}) is outside the "
                        f"{width}x{height} frame")


def length_in_world(length_px: float, image_xy, homography: np.ndarray | None) -> float:
    """``length_px`` image pixels at ``image_xy`` in world units (through ``homography``'s local scale)."""
    if homography is None:
        return float(length_px)
    c = image_to_world(homography, np.asarray(image_xy, float))
    d = float(abs(np.linalg.det(homography_jacobian(homography, c))))
    return length_px / np.sqrt(d) if d > 0 and np.isfinite(d) else float(length_px)


def target_length_world(init_box: tuple[float, float, float, float], homography: np.ndarray | None) -> float:
    """The initial box's long side in world units (pixels through ``homography``'s local scale)."""
    x, y, w, h = init_box
    return length_in_world(max(float(w), float(h)), (x + w / 2, y + h / 2), homography)


def initial_vel_std(settings: TrackerSettings, length_world: float) -> float:
    """The prior's velocity spread: ``init_vel_lengths`` target lengths per second if set, else ``init_vel_std``."""
    return settings.init_vel_std if settings.init_vel_lengths is None else settings.init_vel_lengths * length_world


def make_filter(settings: TrackerSettings, init_box: tuple[float, float, float, float],
                homography: np.ndarray | None, t0: float):
    """The configured filter, started on the centre of ``init_box`` (x, y, w, h) of the first frame.

    With ``settings.motion_noise_lengths`` / ``init_vel_lengths`` / ``jump_std_lengths`` set, the
    driving noise, the initial velocity spread and the RBPF's jump are taken in target lengths (the
    box's long side in world units)."""
    x, y, w, h = init_box
    length = target_length_world(init_box, homography)
    initial = InitialState.from_image_point((x + w / 2, y + h / 2), homography, time=t0,
                                            pos_std=settings.init_pos_std, vel_std=initial_vel_std(settings, length))
    upd = {}
    if settings.motion_noise_lengths is not None:
        q = (settings.motion_noise_lengths * length) ** 2
        upd["motion"] = NearConstantVelocity(q_x=q, q_y=q)
    if settings.filter == "rbpf":
        rupd = dict(upd)
        if settings.jump_std_lengths is not None:
            rupd["jump_std"] = settings.jump_std_lengths * length
        return RBPF(settings.rbpf.model_copy(update=rupd) if rupd else settings.rbpf, initial, seed=settings.seed)
    if settings.filter == "sir":
        return SIR(settings.sir.model_copy(update=upd) if upd else settings.sir, initial, seed=settings.seed)
    return WindowedML(settings.ml, initial)


def _likelihood_beta(settings: TrackerSettings, visible: bool) -> tuple[float, float]:
    """(a, b) of the likelihood's Beta for the scores of a visible target (``visible``) or of the
    background (the synthetic fit by default)."""
    lik = getattr(getattr(settings, settings.filter, None), "likelihood", None)
    if isinstance(lik, BetaRatioLikelihood):
        return (float(lik.a1), float(lik.b1)) if visible else (float(lik.a0), float(lik.b0))
    return (SYNTHETIC_BETA["a1"], SYNTHETIC_BETA["b1"]) if visible else (SYNTHETIC_BETA["a0"], SYNTHETIC_BETA["b0"])


def _interframe(h_prev: np.ndarray | None, h_cur: np.ndarray | None) -> np.ndarray | None:
    """The map from the previous frame's pixels to this frame's, from the two world -> image
    homographies (None: identity)."""
    if h_prev is None and h_cur is None:
        return None
    try:
        inv = invert_homography(np.eye(3) if h_prev is None else h_prev)
    except np.linalg.LinAlgError:
        return None
    return (np.eye(3) if h_cur is None else np.asarray(h_cur, float)) @ inv


def _rotation_deg(j: np.ndarray) -> float:
    """Rotation (degrees, anticlockwise as displayed, image y down) of a 2x2 linear map."""
    return float(np.rad2deg(np.arctan2(j[0, 1] - j[1, 0], j[0, 0] + j[1, 1])))


_SOURCE = object()


def _shared_grey(image: np.ndarray) -> np.ndarray:
    """A uint8 colour frame as the grey image the stabiliser and the moving-target cue both take
    (each would convert it the same way: converted once a frame); any other frame as it is."""
    img = np.asarray(image)
    return grey(img) if img.dtype == np.uint8 and img.ndim == 3 else image


def stabilises(settings: TrackerSettings, first_homography: np.ndarray | None) -> bool:
    """Whether a run estimates the camera motion itself (and so needs every frame's pixels)."""
    return settings.stabilise == "on" or (settings.stabilise == "auto" and first_homography is None)


@dataclass
class Tracker:
    """A filter with its template: ``step(frame) -> TrackState`` for frames in source order.

    Per frame, before the filter step: the camera motion (stabiliser, for sources without a
    homography), the camera's rotation of the particles' orientation, the matching scale, the
    re-acquisition's search while the target is lost and the moving-target cue on the observation;
    after it: the scale search, the lost state, the template adaptation and the template's
    re-registration on the target's segment, or the box's centring on it (each switched in the
    settings).

    A frame is anything with ``index``, ``time``, ``homography``, ``size`` and, when stabilising,
    ``image`` (:class:`common.sources.Frame`; :class:`common.msgs.convert.InfoFrame` on the bus).
    """

    settings: TrackerSettings
    detector: DetectorClient
    template: Template
    """The template matched now (the adapted one, with adaptation)."""
    filter: object
    stabiliser: CameraMotionEstimator | None = None
    scale: ScaleTracker | None = None
    adapter: TemplateAdapter | None = None
    reacquirer: Reacquirer | None = None
    motion_cue: MotionCue | None = None
    registrar: Registrar | None = None
    last_state: TrackState | None = None
    homography: np.ndarray | None = None
    """World -> image homography of the latest frame stepped (None: identity)."""
    factor: float = 1.0
    """Resampling factor the latest frame was matched at."""
    frames: int = 0
    adaptations: int = 0
    _last_adapt_time: float = -np.inf
    _obs: object = None
    _world_xy: np.ndarray | None = None
    _local: bool = False
    _first_h: np.ndarray | None = None
    _box_size: tuple[float, float] = (0.0, 0.0)
    _prev_image: np.ndarray | None = None
    _restart_time: float = -np.inf
    _cloud: tuple[float, float] | None = None
    """Where the filter's cloud is: its previous MAP carried into this frame's pixels (the search's prior)."""
    _box_fit: tuple[float, float, float, float] | None = None
    """The box from the target's segment (``segment.centre_box``), in the target's axes and in the
    box's sides: its centre from the MAP (u, v) and its extent (a, b). Applied to the state returned
    only, never to ``last_state``, which the tracking reads."""

    @classmethod
    def start(cls, first: Frame, init_box: tuple[float, float, float, float], settings: TrackerSettings,
              detector: DetectorClient | None = None) -> "Tracker":
        """The tracker on ``first`` (not yet stepped); ``detector`` defaults to in-process matching."""
        check_init_box(init_box, *first.size)
        x, y, w, h = init_box
        centre = (x + w / 2, y + h / 2)
        stabilise = stabilises(settings, first.homography)
        local = stabilise and settings.filter in ("rbpf", "sir") and settings.stabilised_world == "previous_frame"
        if local:
            length = max(float(w), float(h))
            h0 = np.diag([length, length, 1.0])  # world unit = the target's length, origin at pixel 0
        else:
            h0 = None if stabilise else first.homography
        world0 = image_to_world(h0, np.asarray(centre, float))
        scale = ScaleTracker(settings.scale, init_box, metric_homography=h0 is not None and not stabilise,
                             first_homography=h0, first_world_xy=world0, t0=first.time)
        k0 = scale.factor()
        detector = LocalDetector() if detector is None else detector
        try:
            template = detector.build_template(first, centre, init_box, k0)
        except FlatTemplateError as exc:
            raise InitError(f"--init {x:g},{y:g},{w:g},{h:g}: {exc}: the first frame shows nothing there to "
                            f"match (start from a frame where the target is visible)") from None
        ad = settings.adaptation
        adapter = TemplateAdapter(template, ad.rate, ad.anchor) if ad.enabled else None
        stab = CameraMotionEstimator(settings.stabiliser) if stabilise else None
        tracker = cls(settings, detector, template, make_filter(settings, init_box, h0, first.time),
                      stabiliser=stab, scale=scale, adapter=adapter, factor=k0)
        tracker._local = local
        tracker._first_h = h0
        tracker._box_size = (float(w), float(h))
        if settings.motion_cue.enabled and stab is not None:
            tracker.motion_cue = MotionCue(settings.motion_cue, (float(w), float(h)))
        if settings.segment.enabled and stab is not None:
            max_score = float(beta_dist.ppf(settings.segment.score_quantile, *_likelihood_beta(settings, True)))
            tracker.registrar = Registrar(settings.segment, settings.seed, max_score)
            tracker.registrar.start(np.asarray(first.image), first.index, first.time, init_box)
        if settings.reacquisition.enabled and hasattr(tracker.filter, "restart"):
            tracker.reacquirer = Reacquirer(settings.reacquisition, _likelihood_beta(settings, False), first.size)
        return tracker

    def observation(self, frame: Frame, homography=_SOURCE, factor: float | None = None):
        """The detector's observation of ``frame`` at the current matching scale, with ``homography``
        (default: the frame's own)."""
        h = frame.homography if homography is _SOURCE else homography
        return self.detector.observation(frame, h, self.factor if factor is None else factor)

    def _frame_homography(self, frame: Frame, image: np.ndarray | None) -> np.ndarray | None:
        """World -> image homography of ``frame`` (the stabiliser's on ``image``, the frame's pixels
        or their grey, when stabilising)."""
        if self.stabiliser is None:
            return frame.homography
        if self.frames == 0:
            self.stabiliser.start(image)
            return self._first_h  # the first frame's pixels are the world (in target lengths if local)
        prev = self.last_state
        ex, radius = None, 0.0  # exclude the target's last estimate from the background features
        if prev is not None:
            ex = (prev.map_estimate.image_x, prev.map_estimate.image_y)
            cfg = self.settings.stabiliser
            radius = max(cfg.min_exclusion_px, cfg.exclusion_lengths * self.scale.target_length_px)
        acc = self.stabiliser.update(image, ex, radius)
        if self._local:
            # world = the previous frame's pixels in target lengths: seen through the frame-to-frame map
            return self.stabiliser.last.interframe @ self.homography
        return acc

    def step(self, frame: Frame) -> TrackState:
        pixels = None if self.stabiliser is None else _shared_grey(frame.image)
        h = self._frame_homography(frame, pixels)
        particles = getattr(self.filter, "particles", None)
        world = self._world_xy
        if self.frames > 0 and world is not None and (h is not None or self.homography is not None):
            if self.settings.compensate_camera_rotation and particles is not None:
                j_prev = homography_jacobian(self.homography, world)
                j_cur = homography_jacobian(h, world)
                rot = _rotation_deg(j_cur @ np.linalg.inv(j_prev))
                if np.isfinite(rot) and rot != 0.0:
                    particles[:, 4] = wrap_degrees(particles[:, 4] + rot)
        self._cloud = None
        if self.frames > 0 and self.reacquirer is not None:
            m = _interframe(self.homography, h)
            self.reacquirer.carry(m)
            if self._searches(self.reacquirer) and self.last_state is not None:  # a held track never searches
                e = self.last_state.map_estimate
                self._cloud = self.reacquirer.carried(m, (e.image_x, e.image_y))
        if self.frames > 0:
            # the camera's zoom at the target is read where the target is: not at an estimate that has
            # left the frame (the homography extrapolated there), and with re-acquisition only while the
            # posterior holds the target: an estimate it does not hold may be the last held point carried
            # to the frame's edge, or on the background, and the zoom there is not the target's (an
            # oblique view's can run the scale to the matcher's limit in a second, where nothing is
            # scored: docs/real-footage.md, stop 43)
            m = self.last_state.map_estimate if self.last_state is not None else None
            w, hgt = frame.size
            seen = m is not None and 0 <= m.image_x < w and 0 <= m.image_y < hgt
            if self.reacquirer is not None and not self.reacquirer.held:
                seen = False
            own = self._own_scale_change(frame) if seen else None
            self.scale.predict(self.homography, h, world if seen else None, frame.time, own)
        self.factor = self.scale.factor()
        if self.motion_cue is not None:
            self.motion_cue.push(frame.time, pixels, self.stabiliser.homography)
        det = self._search(frame, h)
        obs = self.observation(frame, h)
        if self.motion_cue is not None:
            obs = self._with_motion_cue(frame, obs, det)
        self._obs = obs
        state = self.filter.step(frame.time, obs)
        self.frames += 1
        self.last_state = state
        try:
            self.scale.maybe_search(frame.time, lambda k, xy: self.detector.scale_grid(frame, k, xy), state)
        except ObservationUnavailable:
            pass  # a remote detector did not answer: no correction this time
        state = replace(state, size=(self._box_size[0] * self.scale.s, self._box_size[1] * self.scale.s),
                        reacquired=det is not None)
        if self.reacquirer is not None:
            if det is not None:
                self.reacquirer.relocked(det)
            self.reacquirer.observe(frame.time, state, self.scale.s)
        self.last_state = state
        old_world = self._first_h if self.homography is None else self.homography
        self.homography = None if h is None else np.asarray(h, float)
        if self._local:
            # carry the particles into this frame's pixels, in the target's (new) length
            length = self.scale.target_length_px
            anchor = np.diag([length, length, 1.0])
            w, hgt = frame.size
            corners = image_to_world(old_world, np.array([[0.0, 0.0], [w - 1.0, hgt - 1.0]]))
            self._reanchor(np.linalg.inv(anchor) @ self.homography, corners.min(axis=0), corners.max(axis=0))
            self.homography = anchor
        held_point = self._left_the_frame(state, frame.size)
        if held_point:
            state = self._holding(state)
            self.last_state = state
        img = np.array([state.map_estimate.image_x, state.map_estimate.image_y])
        self._world_xy = image_to_world(self.homography, img)
        if not held_point:
            self._adapt(frame, state)
            self._register(frame, state)
        if self.stabiliser is not None:
            self._prev_image = frame.image
        if self._box_fit is not None and not held_point and state.size is not None:
            u, v, a, b = self._box_fit
            w, hgt = state.size
            dx, dy = box_axes(state.map_estimate.theta) @ (u * w, v * hgt)
            state = replace(state, box_offset=(float(dx), float(dy)), size=(a * w, b * hgt))
        return state

    def _own_scale_change(self, frame: Frame):
        """The target's own change of size from the previous frame to ``frame``, measured on its pixels
        in the previous estimate's box (:mod:`common.single_target.target_flow`); None where not used, and
        while the previous estimate's p(V=1|Z) is below ``scale.flow.min_p_visible`` (the box is not known
        to hold the target)."""
        cfg = self.settings.scale.flow
        if (not cfg.enabled or self.stabiliser is None or self.scale.mode != "search" or self._prev_image is None
                or self.last_state is None or self.last_state.p_visible < cfg.min_p_visible):
            return None
        box = self.last_state.oriented_box()
        if box is None:
            return None
        last = self.stabiliser.last
        return measure_scale_change(cfg, self._prev_image, frame.image, box, None if last is None else last.interframe)

    def _left_the_frame(self, state: TrackState, size: tuple[int, int]) -> bool:
        """Whether the filter's MAP has left the frame of a track that was held before (see :meth:`_holding`)."""
        r = self.reacquirer
        if r is None or r.last_held is None:
            return False
        m = state.map_estimate
        return not (0 <= m.image_x < size[0] and 0 <= m.image_y < size[1])

    def _holding(self, state: TrackState) -> TrackState:
        """``state`` with the estimates replaced by where the target was last held, carried with the
        camera (:meth:`Reacquirer.carry`), at rest, once the filter's MAP has left the frame (a frame
        that does not hold the target, :meth:`Reacquirer.observe`). Only then: inside the frame the
        cloud can still follow the target on its motion and the moving-target cue (uav123-truck4's
        last 40 frames, where the template no longer matches: p(V=1|Z) is 0 but the MAP stays within
        a few target lengths); outside it nothing holds the cloud, which drifts on at its last
        velocity."""
        r = self.reacquirer
        xy = np.asarray(r.last_held, float)
        wx, wy = image_to_world(self.homography, xy)
        held = Estimate(x=float(wx), y=float(wy), vx=0.0, vy=0.0, theta=r.last_theta,
                        image_x=float(xy[0]), image_y=float(xy[1]))
        return replace(state, map_estimate=held, mmse_estimate=held, speed=0.0, orientation=r.last_theta)

    def _with_motion_cue(self, frame: Frame, obs, det: Detection | None) -> CuedObservation:
        """``obs`` with the moving-target cue of this frame (:mod:`common.single_target.motion_cue`),
        prepared about the last estimate (or the re-acquisition's detection)."""
        if det is not None:
            centre = (det.x, det.y)
        elif self.last_state is not None:
            centre = (self.last_state.map_estimate.image_x, self.last_state.map_estimate.image_y)
        else:
            centre = self.template.centre  # the first frame: the first box's centre
        self.motion_cue.prepare(centre, self.scale.s)
        return CuedObservation(obs, self.motion_cue.log_ratio)

    def _searches(self, r: Reacquirer) -> bool:
        """Whether this frame is searched: the target is lost, or (``movers_in_doubt``, with the
        moving-target cue) its hold is in doubt."""
        return r.lost or (self.settings.reacquisition.movers_in_doubt and self.motion_cue is not None
                          and r.in_doubt)

    def _search(self, frame: Frame, h: np.ndarray | None) -> Detection | None:
        """While the target is lost, search this frame (:mod:`common.single_target.reacquire`), and while
        its hold is in doubt the movers near the cloud (``movers_in_doubt``); on a confident detection
        restart the filter there, at the detection's scale and angle."""
        r = self.reacquirer
        if r is None or not self._searches(r):
            return None
        t0 = time.perf_counter()
        try:
            grid_at = lambda k, xy, crop=None: self.detector.scale_grid(frame, k, xy, crop)  # noqa: E731
            if r.lost:
                det = r.search(frame.time, grid_at, self.scale, self.motion_cue, self._cloud)
            else:
                det = r.search_in_doubt(frame.time, grid_at, self.scale, self.motion_cue, self._cloud)
        except ObservationUnavailable:
            return None  # a remote detector did not answer: search again next frame
        finally:
            r.seconds += time.perf_counter() - t0  # a statistic only: never read by the tracking
        if det is not None:
            self._restart_on(det, frame.time, h)
        return det

    def _restart_on(self, det: Detection, time: float, h: np.ndarray | None) -> None:
        """Restart the scale and the filter on ``det`` (image pixels, scale and angle) at ``time``."""
        self.scale.restart(det.scale)
        self.factor = self.scale.factor()
        length_world = length_in_world(self.scale.target_length_px, (det.x, det.y), h)
        initial = InitialState.from_image_point(
            (det.x, det.y), h, time=None, theta=det.theta_deg, p_visible=1.0,
            pos_std=self.settings.reacquisition.restart_pos_lengths * length_world,
            vel_std=initial_vel_std(self.settings, length_world), theta_std=3.75)
        self.filter.restart(initial)
        self._restart_time = time
        self._box_fit = None

    def _reanchor(self, m: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> None:
        """Move the particles to a new world frame: positions through ``m`` (old world -> new
        world), velocities through its Jacobian. ``m`` is fitted to the frame's features, the old
        world's box ``lo``-``hi``: a particle beyond it moves by ``m``'s first-order expansion at the
        box's nearest point (the camera's local motion at the frame's edge), not by ``m`` itself, whose
        perspective terms grow without bound away from the frame."""
        p = self.filter.particles
        pos = p[:, [0, 2]]
        near = np.clip(pos, lo, hi)
        jac = homography_jacobian(m, near)
        vel = np.einsum("nij,nj->ni", jac, p[:, [1, 3]])
        new = apply_homography(m, near) + np.einsum("nij,nj->ni", jac, pos - near)
        ok = np.all(np.isfinite(new), axis=1) & np.all(np.isfinite(vel), axis=1)
        p[ok, 0], p[ok, 2] = new[ok, 0], new[ok, 1]
        p[ok, 1], p[ok, 3] = vel[ok, 0], vel[ok, 1]

    def _settled(self, time_s: float) -> bool:
        """Whether ``adaptation.hold_after_restart_s`` has passed since a re-acquisition's restart:
        until then the cloud has not settled on the target, and neither the adaptation nor the
        registration takes the template from where it is."""
        return time_s - self._restart_time >= self.settings.adaptation.hold_after_restart_s - 1e-9

    def _register(self, frame: Frame, state: TrackState) -> None:
        """Every ``segment.interval_s`` while held: the template built again at the target's segment
        (:mod:`common.single_target.segment`) and turned back by the MAP's orientation to the first
        template's (the particles' angles are relative to it), the scale set from the segment's
        length, the adaptation started again from the new template."""
        r = self.registrar
        if r is None or frame.image is None:
            return
        if not r.due(frame.time, state.p_visible, state.score):
            self._centre_box(frame, state)
            return
        if not self._settled(frame.time):
            return
        m = state.map_estimate
        found = r.measure(np.asarray(frame.image), frame.index, frame.time, (m.image_x, m.image_y),
                          state.size, self.scale.target_length_px)
        if found is None:
            return
        (x, y), s = found
        if self.scale.mode != "search":
            s = self.scale.s  # the scale is the source's homography's, or fixed: re-centred only
        s = float(np.clip(s, *self.scale.scale_range()))
        k = self.scale.factor(s)
        bw, bh = self._box_size[0] * s, self._box_size[1] * s
        try:
            built = self.detector.build_template(frame, (x, y), (x - bw / 2, y - bh / 2, bw, bh), k)
        except (ValueError, InitError, ObservationUnavailable):
            return  # its footprint is not whole in the frame, or the detector did not answer: kept as it is
        template = Template(pmatrix=rotate_pmatrix(built.pmatrix, -m.theta), centre=built.centre, box=built.box)
        self._box_fit = None  # the new template is centred on the segment, and the scale set from it
        self.detector.use_template(template)
        if self.scale.mode == "search":
            self.scale.restart(s, swept=False)
            self.factor = self.scale.factor()
        self.template = template
        ad = self.settings.adaptation
        if ad.enabled:
            self.adapter = TemplateAdapter(template, ad.rate, ad.anchor)

    def _centre_box(self, frame: Frame, state: TrackState) -> None:
        """Every ``segment.interval_s`` while held, where the template is not re-registered: the box
        from the target's segment (``segment.centre_box``), its centre kept as an offset from the MAP
        and its extent (a filled rectangle's sides from the segment's second moments), both in the
        target's axes and in the track's box sides, so that they turn and grow with the track; kept
        while the MAP lies inside the box so centred."""
        r = self.registrar
        if not r.centre_due(frame.time, state.p_visible) or state.size is None or not self._settled(frame.time):
            return
        m = state.map_estimate
        seg = r.centre(np.asarray(frame.image), frame.index, frame.time, (m.image_x, m.image_y),
                       state.size, self.scale.target_length_px)
        if seg is None:
            return  # nothing plausible segmented: the box stays as it was
        w, hgt = state.size
        axes = box_axes(m.theta)  # the target's axes: the track's box's, turned by the MAP's angle
        u, v = axes.T @ (seg.x - m.image_x, seg.y - m.image_y)
        cxx, cxy, cyy = seg.cov
        muu, mvv = np.diag(axes.T @ np.array([[cxx, cxy], [cxy, cyy]]) @ axes)  # the moments along them
        a, b = math.sqrt(12 * max(muu, 0.0)) / w, math.sqrt(12 * max(mvv, 0.0)) / hgt
        inside = abs(u) <= 0.5 * a * w and abs(v) <= 0.5 * b * hgt
        self._box_fit = (float(u) / w, float(v) / hgt, a, b) if inside and a > 0 and b > 0 else None

    def _adapt(self, frame: Frame, state: TrackState) -> None:
        ad = self.settings.adaptation
        if self.adapter is None or state.score is None:
            return
        if state.p_visible < ad.min_p_visible or state.score < ad.min_score:
            return
        if frame.time - self._last_adapt_time < ad.interval_s - 1e-9:
            return
        if not self._settled(frame.time):
            return
        # sample at the frame's matching scale, where the template registers the target near the
        # MAP, turned back by the refined angle there
        obs = self._obs
        x, y = state.map_estimate.image_x, state.map_estimate.image_y
        try:
            if ad.align_lengths > 0:
                at = registered_point(obs, (x, y), self.scale.target_length_px, ad.align_lengths)
                if at is None:
                    return  # the template's best match lies beyond the MAP's neighbourhood: no update
                x, y = at
            theta, score = obs.refine_peak(x, y)
            if score < ad.min_score:
                return
            sample = obs.pmatrix_at(x, y)
        except ObservationUnavailable:
            return  # a remote detector did not answer: no update this time
        if sample is None:
            return
        self.template = self.adapter.blend(sample, theta)
        self.detector.use_template(self.template)
        self._last_adapt_time = frame.time
        self.adaptations += 1


def track_frames(frames: Iterable[Frame], init_box: tuple[float, float, float, float],
                 settings: TrackerSettings) -> Iterator[tuple[Frame, TrackState]]:
    """Track through ``frames``; the template is built on the first frame at ``init_box``."""
    tracker = None
    for frame in frames:
        if tracker is None:
            tracker = Tracker.start(frame, init_box, settings)
        yield frame, tracker.step(frame)
