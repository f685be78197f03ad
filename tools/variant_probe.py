"""Variants and bounds probed on real footage (stops 31-34), none of them in the product.

A diagnostic for docs/real-footage.md ("Probed in stop 31" to "Probed in stop 34"). It runs the
in-process tracker (the real-footage profile, ``--set`` overrides) on one UAV123/OTB sequence for
the given seeds and prints precision@20 over the run and per hundred frames, with a variant or an
oracle patched in:

- ``--colour-cue ZCAP``: a colour cue added to the moving-target cue. The target's colour
  histogram (16 bins a channel) from the ellipse inscribed in the first box, the background's from
  the whole current frame (a quarter size; ``--colour-background local``: the cue's region less a
  disc of 1.5 target lengths about the estimate, averaged over a second); each pixel's p(target | colour) = h_f / (h_f + h_b); the
  mean of p over target-sized boxes scored against the region's boxes as the motion cue scores its
  energy (robust z, spread floored at 0.05 and a quarter of the median), log ratio
  -log(2 P(N(0,1) >= clip(z, 0, ZCAP))).
- ``--footprint-frames W``: a hypothesis stays scorable while the footprint is up to W frames
  wide (the product: 1, no wider than the frame's short side: the matcher cannot score a target
  longer than 719 * 48 / 128 = 270 px in a 720-px-high frame).
- ``--cue-relative-cap``: the motion cue's cap slid to the region's strongest box (a box's z less
  the region's best z less the cap), so that near a strongly moving target the boxes beside it get
  less than the box on it (the product caps both).
- ``--oracle-restart FRAME``: not a variant but a bound: the filter restarted at the ground truth
  (centre and scale) on that frame, as a re-acquisition would; what bridging a loss before it is worth.
  With ``--oracle-template-from F``, the template is also put back to the one the track had after
  frame F: what a memory of the views it held would be worth; with ``--oracle-no-restart`` only the
  template is put back (the filter and the search go on from where they are); with
  ``--oracle-retemplate`` a new template is built from that frame's truth box, as at the start.
- ``--segment-recentre N``: not a bound: every N frames while held, a new template at the centre
  of a GrabCut segment of the target about the estimate (no ground truth), the template's
  registration taken from the target's extent.
  The product's form of this is the ``segment`` settings (``--set segment.score_quantile=1.0`` to
  register whatever the score).
- ``--oracle-template-every N``: a bound too: every N frames a new template built at the truth's
  box (the filter, the scale and the search left alone): what a recent view kept registered on the
  target would be worth.
- ``--oracle-register-every N``: the same bound through the product's own re-registration
  (``Tracker._register``, the truth in place of the target's segment): the template and the matching
  scale set from the truth's box every N frames (stop 62).

Each run is scored as ``polartrack benchmark`` scores it: the reported box's centre (since stop 58
fitted to the target's segment, ``segment.centre_box``), over the frames with a truth (until stop
62 the probe scored the MAP; figures of earlier stops were measured so). Folders and the built-in
scenes alike (each frame's own truth).

    uv run python tools/variant_probe.py ../shared/data/uav123-car16 --seeds 0,1,2,3,4
    uv run python tools/variant_probe.py ../shared/data/uav123-car16 --seeds 0,1,2,3,4 --colour-cue 5
    uv run python tools/variant_probe.py ../shared/data/uav123-car16 --seeds 0,1,2,3,4 --footprint-frames 2
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import cv2
import numpy as np
from scipy.stats import norm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import common.detector.resample as resample  # noqa: E402
from common.evaluation.benchmark import score_boxes  # noqa: E402
from common.settings import SegmentRegistration, profile_for  # noqa: E402
from common.single_target import runner  # noqa: E402
from common.single_target.adaptation import TemplateAdapter  # noqa: E402
from common.single_target.motion_cue import _RELATIVE_FLOOR, MotionCue  # noqa: E402
from common.single_target.reacquire import Detection  # noqa: E402
from common.single_target.segment import segment_target  # noqa: E402
from common.sources import open_source  # noqa: E402
from common.tracking.observation import CuedObservation  # noqa: E402
from common.tracking.state import InitError  # noqa: E402
from services.commands.common_args import apply_overrides  # noqa: E402

BINS = 16
FLOOR = 0.05


def _bin_index(rgb: np.ndarray) -> np.ndarray:
    q = (rgb >> (8 - int(math.log2(BINS)))).astype(np.int32)
    return (q[..., 0] * BINS + q[..., 1]) * BINS + q[..., 2]


class ColourCue(MotionCue):
    """The colour cue (module docstring), on the motion cue's box statistics."""

    def __init__(self, cfg, box_size, image0: np.ndarray, centre, z_cap: float, local: bool = False):
        super().__init__(cfg, box_size)
        self.z_cap = z_cap
        self.local = local
        self.h_local: np.ndarray | None = None
        self.time: float | None = None
        mask = np.zeros(image0.shape[:2], np.uint8)
        axes = (max(1, int(box_size[0] / 2)), max(1, int(box_size[1] / 2)))
        cv2.ellipse(mask, (int(round(centre[0])), int(round(centre[1]))), axes, 0, 0, 360, 255, -1)
        self.h_target = np.bincount(_bin_index(image0)[mask > 0], minlength=BINS**3).astype(float)
        self.h_target /= max(self.h_target.sum(), 1.0)

    def prepare_colour(self, image: np.ndarray, centre, scale: float, time: float) -> None:
        cfg = self.cfg
        self._integral, self._stats, self._scale = None, None, float(scale)
        length = max(self.box_size) * self._scale
        r = cfg.region_lengths * length + 2 * length
        height, width = image.shape[:2]
        x0, y0 = max(0, int(centre[0] - r)), max(0, int(centre[1] - r))
        x1, y1 = min(width, int(math.ceil(centre[0] + r))), min(height, int(math.ceil(centre[1] + r)))
        level = max(0, int(math.ceil(math.log2(max(length / cfg.analysis_length_px, 1.0)) - 1e-9)))
        f = 0.5**level
        out_w, out_h = int((x1 - x0) * f), int((y1 - y0) * f)
        if out_w < 8 or out_h < 8:
            return
        crop = np.ascontiguousarray(image[y0:y1, x0:x1])
        if level:
            crop = cv2.resize(crop, (out_w, out_h), interpolation=cv2.INTER_AREA)
        if self.local:
            # the region less a disc of 1.5 lengths about the estimate, averaged over a second
            yy, xx = np.mgrid[0:out_h, 0:out_w]
            away = np.hypot(xx / f + x0 - centre[0], yy / f + y0 - centre[1]) > 1.5 * length
            h_now = np.bincount(_bin_index(crop)[away], minlength=BINS**3).astype(float)
            h_now /= max(h_now.sum(), 1.0)
            a = 1.0 if self.h_local is None else min(1.0, (time - self.time) / 1.0)
            self.h_local = h_now if self.h_local is None else (1 - a) * self.h_local + a * h_now
            self.time = time
            h_bg = self.h_local
        else:
            small = cv2.resize(image, None, fx=0.25, fy=0.25, interpolation=cv2.INTER_AREA)
            h_bg = np.bincount(_bin_index(small).ravel(), minlength=BINS**3).astype(float)
            h_bg /= h_bg.sum()
        eps = 1e-3 / BINS**3
        table = ((self.h_target + eps) / (self.h_target + h_bg + 2 * eps)).astype(np.float32)
        self._integral = cv2.integral(table[_bin_index(crop)], sdepth=cv2.CV_64F)
        self._seen = np.ones(crop.shape[:2], bool)  # a colour needs no past frame: every pixel is seen
        self._seen_integral = cv2.integral(self._seen.astype(np.uint8), sdepth=cv2.CV_64F)
        self._origin, self._factor = (float(x0), float(y0)), f
        bw, bh = self._box()
        step = max(bw, bh) / 2
        gx, gy = np.meshgrid(np.arange(x0 + bw / 2, x1 - bw / 2 + 1e-9, step),
                             np.arange(y0 + bh / 2, y1 - bh / 2 + 1e-9, step))
        e = self._box_means(np.stack([gx.ravel(), gy.ravel()], axis=1))
        e = e[np.isfinite(e)]
        if len(e) < cfg.min_boxes:
            self._integral = None
            return
        med = float(np.median(e))
        self._stats = (med, max(1.4826 * float(np.median(np.abs(e - med))), _RELATIVE_FLOOR * med, FLOOR))

    def log_ratio(self, image_xy: np.ndarray) -> np.ndarray:
        z = np.clip(self.z_scores(image_xy), 0.0, self.z_cap)
        return -(norm.logsf(z) + math.log(2.0))


def patch_colour_cue(z_cap: float, local: bool) -> None:
    start, with_motion_cue = runner.Tracker.start.__func__, runner.Tracker._with_motion_cue

    def patched_start(cls, frame, box, settings, *args, **kwargs):
        tracker = start(cls, frame, box, settings, *args, **kwargs)
        x, y, w, h = box
        tracker.colour_cue = ColourCue(settings.motion_cue, (float(w), float(h)), np.asarray(frame.image),
                                       (x + w / 2, y + h / 2), z_cap, local)
        return tracker

    def patched_with_motion_cue(self, frame, obs, det):
        cued = with_motion_cue(self, frame, obs, det)
        if det is not None:
            centre = (det.x, det.y)
        elif self.last_state is not None:
            centre = (self.last_state.map_estimate.image_x, self.last_state.map_estimate.image_y)
        else:
            centre = self.template.centre
        self.colour_cue.prepare_colour(np.asarray(frame.image), centre, self.scale.s, frame.time)
        motion, colour = self.motion_cue.log_ratio, self.colour_cue.log_ratio
        return CuedObservation(cued.base, lambda xy: motion(xy) + colour(xy))

    runner.Tracker.start = classmethod(patched_start)
    runner.Tracker._with_motion_cue = patched_with_motion_cue


def patch_footprint(frames_wide: float) -> None:
    def footprint_valid(xy, k, size):
        if 2 * resample.SUPPORT_RADIUS_PX / k > frames_wide * min(size) - 1:
            return np.zeros(len(xy), bool)
        return resample._inside_by(xy, resample.EDGE_SUPPORT_PX / k, size)

    resample.footprint_valid = footprint_valid


def patch_oracle_restart(frame_index: int, truth, template_from: int | None = None, restart: bool = True,
                         retemplate: bool = False) -> None:
    """Restart the filter at the ground truth on ``frame_index`` (centre and scale; the angle the
    MAP's): what bridging a loss before that frame would be worth; with ``template_from``, also
    match from then on with the template (and adaptive part) the track had after that frame; with
    ``restart`` False, only that (the filter and the search go on as they are)."""
    search, step = runner.Tracker._search, runner.Tracker.step
    first = max(truth[0][2], truth[0][3])

    def patched_step(self, frame):
        state = step(self, frame)
        if template_from is not None and frame.index == template_from:
            self._snapshot = (self.template, self.adapter._a.copy())
        return state

    def patched_search(self, frame, h):
        if frame.index != frame_index:
            return search(self, frame, h)
        if template_from is not None:  # the restart below touches the scale and the filter only
            self.template, a = self._snapshot
            self.adapter._a = a.copy()
            self.detector.use_template(self.template)
        if not restart:
            return search(self, frame, h)
        x, y, w, hh = truth[frame_index]
        theta = 0.0 if self.last_state is None else self.last_state.map_estimate.theta
        det = Detection(x=x + w / 2, y=y + hh / 2, theta_deg=theta, score=1.0, scale=max(w, hh) / first)
        self._restart_on(det, frame.time, h)
        if retemplate:  # a fresh template of this frame's view at the truth, as at the start
            _retemplate(self, frame, (x + w / 2, y + hh / 2), (x, y, w, hh))
        return det

    runner.Tracker._search = patched_search
    runner.Tracker.step = patched_step


def _retemplate(tracker, frame, centre: tuple[float, float], box: tuple[float, float, float, float]) -> bool:
    """A new template built on ``frame`` at ``centre`` and ``box`` at the track's matching scale, as
    at the start (building it puts it in use), the adaptation started again from it; False where
    its footprint is not whole in the frame (the template kept)."""
    try:
        tracker.template = tracker.detector.build_template(frame, centre, box, tracker.factor)
    except (ValueError, InitError):
        return False
    ad = tracker.settings.adaptation
    tracker.adapter = TemplateAdapter(tracker.template, ad.rate, ad.anchor) if ad.enabled else None
    return True


def patch_oracle_template_every(every: int, truth) -> None:
    """Every ``every`` frames, a new template built at the ground truth's box on that frame (its view,
    registered on the target), at the track's own matching scale, the adaptation started again from
    it; the filter, the scale and the search go on as they are: what a recent view kept registered
    on the target would be worth."""
    step = runner.Tracker.step

    def patched_step(self, frame):
        state = step(self, frame)
        t = truth[frame.index] if frame.index < len(truth) else None
        if frame.index > 0 and frame.index % every == 0 and t is not None:
            x, y, w, hh = t
            _retemplate(self, frame, (x + w / 2, y + hh / 2), (x, y, w, hh))
        return state

    runner.Tracker.step = patched_step


class _TruthRegistrar:
    """The tracker's segment registrar with the truth's box in place of the segment, due every
    ``every`` frames whatever the score: :meth:`measure` gives the truth's centre and its scale (the
    square root of its area over the first box's), which the tracker's own re-registration
    (``Tracker._register``) builds the template at and sets the matching scale to."""

    def __init__(self, inner, every: int, truth):
        self.inner, self.every, self.truth = inner, every, truth
        self.index = 0

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def due(self, time_s, p_visible, score) -> bool:
        return self.index > 0 and self.index % self.every == 0

    def measure(self, image, frame_index, time_s, centre, box_size, length_px):
        box, first = self.truth[frame_index], self.truth[0]
        if box is None:
            return None
        x, y, w, h = box
        return (x + w / 2, y + h / 2), math.sqrt(w * h / (first[2] * first[3]))


def patch_oracle_register_every(every: int, truth) -> None:
    """Every ``every`` frames the product's re-registration at the truth's box (:class:`_TruthRegistrar`):
    the template built again there, turned back by the MAP's angle, the matching scale set from the
    truth, the adaptation started again; the filter and the search left alone. A bound: what a
    registration on the target as good as the truth, as often, would be worth. Needs the
    ``segment`` settings on (the real-footage profile)."""
    start, step = runner.Tracker.start, runner.Tracker.step

    def patched_start(cls, first, init_box, settings, *args, **kwargs):
        tracker = start.__func__(cls, first, init_box, settings, *args, **kwargs)
        if tracker.registrar is not None:
            tracker.registrar = _TruthRegistrar(tracker.registrar, every, truth)
        return tracker

    def patched_step(self, frame):
        if isinstance(self.registrar, _TruthRegistrar):
            self.registrar.index = frame.index
        return step(self, frame)

    runner.Tracker.start = classmethod(patched_start)
    runner.Tracker.step = patched_step


def _segment_centre(img: np.ndarray, cx: float, cy: float, length: float, box_area: float,
                    reach: float = 1.0) -> tuple[float, float] | None:
    """The centre of the target's segment about (cx, cy) by the product's segmentation
    (:func:`common.single_target.segment.segment_target`: GrabCut in the square ``reach`` lengths
    either side, its area 0.2-2 times ``box_area``), without its shape guard, as the probe had it
    before the product's ``segment`` settings; None where nothing plausible is found. (Until stop
    36 the probe had its own copy of the segmentation, seeded with 0: figures measured with it may
    differ in the last digits.)"""
    cfg = SegmentRegistration(enabled=True, reach_lengths=reach, min_solidity=0.0)
    seg = segment_target(img, (cx, cy), length, cfg, seed=0, box_area_px=box_area)
    return None if seg is None else (seg.x, seg.y)


def patch_segment_recentre(every: int, agree: float | None = None, consistent: float | None = None) -> None:
    """Every ``every`` frames while p(V=1|Z) >= 0.5, a new template built at the centre of a GrabCut
    segment of the target about the estimate (``_segment_centre``; no ground truth), at the track's
    box and matching scale, the adaptation restarted from it: the template's registration taken
    from the target's extent instead of from the template's own match."""
    step = runner.Tracker.step

    def patched_step(self, frame):
        state = step(self, frame)
        if frame.index > 0 and frame.index % every == 0 and state.p_visible >= 0.5:
            m = state.map_estimate
            bw, bh = state.size
            length = self.scale.target_length_px
            c = _segment_centre(np.asarray(frame.image), m.image_x, m.image_y, length, bw * bh)
            if c is None:
                self._segment_offset = None
                return state
            if consistent is not None:  # the segment's offset from the MAP, in lengths, as at the last attempt
                off = ((c[0] - m.image_x) / length, (c[1] - m.image_y) / length)
                last, self._segment_offset = getattr(self, "_segment_offset", None), off
                if last is None or math.hypot(off[0] - last[0], off[1] - last[1]) > consistent:
                    return state
            if agree is not None:  # a second segmentation, its rectangle a quarter smaller, must agree
                c2 = _segment_centre(np.asarray(frame.image), m.image_x, m.image_y, length, bw * bh, reach=0.75)
                if c2 is None or math.hypot(c[0] - c2[0], c[1] - c2[1]) > agree * length:
                    return state
            _retemplate(self, frame, c, (c[0] - bw / 2, c[1] - bh / 2, bw, bh))
        return state

    runner.Tracker.step = patched_step


def patch_cue_relative_cap() -> None:
    """The motion cue's cap slid to the region's strongest box: a box's z less (the region's best z
    less the cap), so the best box gets the cap and a box beside it less, where both now saturate."""
    def log_ratio(self, image_xy):
        z = self.z_scores(image_xy)
        if self._integral is not None and len(self._grid):
            z = z - max(0.0, float(np.max(self.z_scores(self._grid))) - self.cfg.z_cap)
        z = np.clip(z, 0.0, self.cfg.z_cap)
        return -(norm.logsf(z) + math.log(2.0))

    MotionCue.log_ratio = log_ratio


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sequence")
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--colour-cue", type=float, metavar="ZCAP")
    ap.add_argument("--colour-background", choices=("frame", "local"), default="frame")
    ap.add_argument("--footprint-frames", type=float, metavar="W")
    ap.add_argument("--cue-relative-cap", action="store_true")
    ap.add_argument("--oracle-restart", type=int, metavar="FRAME")
    ap.add_argument("--oracle-template-from", type=int, metavar="FRAME")
    ap.add_argument("--oracle-no-restart", action="store_true",
                    help="with --oracle-template-from: only put the template back at --oracle-restart's frame")
    ap.add_argument("--oracle-retemplate", action="store_true",
                    help="with --oracle-restart: also build a new template from that frame's truth box")
    ap.add_argument("--oracle-template-every", type=int, metavar="N",
                    help="a new template at the truth's box every N frames (the filter left alone)")
    ap.add_argument("--oracle-register-every", type=int, metavar="N",
                    help="every N frames the product's re-registration (template and matching scale) at the "
                         "truth's box in place of the segment (the filter left alone)")
    ap.add_argument("--segment-recentre", type=int, metavar="N",
                    help="every N frames a new template at a GrabCut segment's centre about the estimate")
    ap.add_argument("--segment-agree", type=float, metavar="LENGTHS",
                    help="with --segment-recentre: a second segmentation (a rectangle a quarter smaller) must "
                         "put the centre within LENGTHS target lengths of the first")
    ap.add_argument("--segment-consistent", type=float, metavar="LENGTHS",
                    help="with --segment-recentre: the segment's offset from the MAP must be within LENGTHS "
                         "target lengths of the offset at the previous attempt")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", dest="overrides",
                    help="override a tracker setting by its dotted name (repeatable), as on benchmark")
    a = ap.parse_args()
    if a.colour_cue is not None:
        patch_colour_cue(a.colour_cue, a.colour_background == "local")
    if a.cue_relative_cap:
        patch_cue_relative_cap()
    if a.footprint_frames is not None:
        patch_footprint(a.footprint_frames)
    src = open_source(a.sequence)
    frames = list(src)
    truth = [None if f.truth is None else f.truth.box for f in frames]  # each frame's own (built-in scenes too)
    if a.oracle_restart is not None:
        patch_oracle_restart(a.oracle_restart, truth, a.oracle_template_from, not a.oracle_no_restart,
                             a.oracle_retemplate)
    if a.oracle_template_every is not None:
        patch_oracle_template_every(a.oracle_template_every, truth)
    if a.oracle_register_every is not None:
        patch_oracle_register_every(a.oracle_register_every, truth)
    if a.segment_recentre is not None:
        patch_segment_recentre(a.segment_recentre, a.segment_agree, a.segment_consistent)
    for seed in (int(s) for s in a.seeds.split(",")):
        tracker = runner.Tracker.start(frames[0], truth[0], apply_overrides(profile_for(src, seed=seed), a.overrides))
        # the reported boxes, scored by the benchmark's own scorer (a frame without a box is a miss)
        score = score_boxes([tracker.step(frame).axis_aligned_box() for frame in frames], truth)
        visible = np.array([box is not None for box in truth])
        hit = score.errors <= 20  # NaN (no box) is a miss
        per100 = [round(float(hit[lo:lo + 100][visible[lo:lo + 100]].mean()), 2)
                  for lo in range(0, len(frames), 100) if visible[lo:lo + 100].any()]
        print(f"{Path(a.sequence).name} seed {seed} p20 {score.precision20:.3f} over {score.visible_frames} frames "
              f"per 100 frames {per100}", flush=True)


if __name__ == "__main__":
    main()
