"""Trace one run of the real-footage tracker frame by frame: where a track is lost, and why.

A diagnostic for docs/real-footage.md (stop 40). It runs the in-process tracker (the profile
`polartrack benchmark` uses, ``--set`` overrides) on one UAV123/OTB folder for one seed and prints:

- for the frames in ``--frames A:B``, one row each: the MAP estimate and the truth's centre, the
  centre error (of the reported box's centre, as the benchmark scores it; the MAP's beside it where
  the box is centred elsewhere, ``segment.centre_box``), p(V=1|Z), the box and the truth's size,
  the scale s and the matching factor k, the estimate's own score, the target's own change of size
  measured from its pixels (``common.single_target.target_flow``: change of log size, its standard
  deviation and the points tracked; ``-`` where not measured), and
  with ``--movers`` on a searched frame the movers' test
  (:class:`common.single_target.reacquire.MoverGate`: the strongest mover, its z, the background
  boxes expected as strong, what the frame allows) and, on a frame the template's registration
  segmented the target (``common.single_target.segment``), whether it registered;
- with ``--restarts``, every restart of the filter by the re-acquisition, on whatever frame: on a
  mover or a tile, lost or in doubt, where (inside the truth's box or how far from it), the
  detection's score beside the scores the track had while it last held the target (their median and
  10th percentile over its last 30 held frames), and the detection's scale beside the truth's (the
  square root of the truth's box area over the first box's);
- for the whole run, its stretches: frames within 20 px of the truth (``hit``), beyond (``miss``),
  and without a truth (``out``: the target out of view), each with its last frame's figures;
- the run's precision@20 (as ``polartrack benchmark`` scores it, over the frames with a truth).

    uv run python tools/trace_track.py ../shared/data/uavdt-S1001 --seed 5 --frames 240:270
    uv run python tools/trace_track.py /tmp/stress/uavdt-S1001-away --seed 1 --frames 155:185 --movers
    uv run python tools/trace_track.py ../shared/data/uav123-car16 --seed 0 --restarts

Nothing in the run is changed: the flow measurement is read as the tracker makes it.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections import deque
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common.settings import profile_for  # noqa: E402
from common.single_target import runner  # noqa: E402
from common.sources import open_source  # noqa: E402
from services.commands.common_args import apply_overrides  # noqa: E402

HIT_PX = 20.0
HELD_SCORES = 30
"""Held frames whose scores a restart's is set beside (the last this many)."""


def _frames(text: str | None) -> range:
    if not text:
        return range(0)
    a, _, b = text.partition(":")
    return range(int(a), int(b) + 1 if b else int(a) + 1)


def _searched(r) -> int:
    """Frames the re-acquisition searched so far, lost or in doubt (0 without it)."""
    return 0 if r is None else r.searches + r.doubt_searches


def _restart_row(i: int, det, in_doubt: bool, on_mover: bool, box, first_box, held) -> str:
    """One restart: where, its score beside the held scores, its scale beside the truth's."""
    kind = ("mover" if on_mover else "tile") + (" in doubt" if in_doubt else "")
    head = f"  restart f{i} on a {kind}: at {det.x:.0f},{det.y:.0f}"
    if box is None or not all(math.isfinite(v) for v in box):
        where, scale = "the target out of view", f"scale {det.scale:.2f}"
    else:
        x, y, w, h = box
        inside = x <= det.x <= x + w and y <= det.y <= y + h
        off = math.hypot(det.x - (x + w / 2), det.y - (y + h / 2))
        where = f"{'inside' if inside else 'off'} the truth's box, {off:.0f} px from its centre"
        truth_s = math.sqrt(w * h / (first_box[2] * first_box[3]))
        scale = f"scale {det.scale:.2f}, the truth's {truth_s:.2f} (x{det.scale / truth_s:.2f})"
    if held:
        last = np.asarray(held)
        scores = (f"score {det.score:.3f}, held before {np.median(last):.3f} median, "
                  f"{np.quantile(last, 0.1):.3f} 10th percentile ({len(last)} frames)")
    else:
        scores = f"score {det.score:.3f}, never held before"
    return f"{head}, {where}; {scores}; {scale}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sequence")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--frames", metavar="A:B", help="print one row for each of these frames (0-based, inclusive)")
    ap.add_argument("--movers", action="store_true", help="print the movers' test on searched frames")
    ap.add_argument("--restarts", action="store_true",
                    help="print every restart of the filter: where, its score beside the held scores, its scale "
                         "beside the truth's")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", dest="overrides",
                    help="override a tracker setting by its dotted name (repeatable), as on benchmark")
    a = ap.parse_args()
    rows = _frames(a.frames)

    measured: list = []
    measure = runner.measure_scale_change

    def recorded(*args, **kwargs):
        m = measure(*args, **kwargs)
        measured.append(m)
        return m

    runner.measure_scale_change = recorded
    src = open_source(a.sequence)
    settings = apply_overrides(profile_for(src, seed=a.seed), a.overrides)
    tracker = None
    first_box = None
    stretches: list[list] = []
    hits = []
    held_scores: deque[float] = deque(maxlen=HELD_SCORES)  # the scores of the last frames counted as held
    restarts: list = []  # the detections the filter restarted on, this frame

    def recording(relocked):
        def wrapped(det):
            restarts.append(det)
            return relocked(det)
        return wrapped

    for i, frame in enumerate(src):  # one frame at a time: a long sequence is not held in memory
        box = None if frame.truth is None else frame.truth.box  # a folder's box, or a synthetic scene's
        if tracker is None:
            if box is None:
                raise SystemExit(f"error: {a.sequence} has no ground truth for its first frame: the trace starts "
                                 "from it (a UAV123/OTB folder with groundtruth_rect.txt, or a synthetic scene "
                                 "such as exit:0)")
            tracker = runner.Tracker.start(frame, box, settings)
            first_box = box
            if tracker.reacquirer is not None:  # seen, not changed: the restart goes on as it would
                tracker.reacquirer.relocked = recording(tracker.reacquirer.relocked)
        measured.clear()
        restarts.clear()
        r = tracker.reacquirer
        movers_before, doubt_before = (r.mover_detections, r.doubt_detections) if r is not None else (0, 0)
        searches = _searched(tracker.reacquirer)
        doubt = tracker.reacquirer.doubt_searches if tracker.reacquirer is not None else 0
        reg = tracker.registrar
        attempts, registrations = (reg.attempts, reg.registrations) if reg is not None else (0, 0)
        state = tracker.step(frame)
        m = state.map_estimate
        if box is None or not all(math.isfinite(v) for v in box):
            kind, err, tx, ty, tw, th = "out", float("nan"), float("nan"), float("nan"), float("nan"), float("nan")
        else:
            x, y, tw, th = box
            tx, ty = x + tw / 2, y + th / 2
            ab = state.axis_aligned_box()  # scored as the benchmark scores it: the reported box's centre
            bx, by = (m.image_x, m.image_y) if ab is None else (ab[0] + ab[2] / 2, ab[1] + ab[3] / 2)
            err = math.hypot(bx - tx, by - ty)
            kind = "hit" if err <= HIT_PX else "miss"
            hits.append(kind == "hit")
        w, h = state.size if state.size is not None else (float("nan"), float("nan"))
        map_err = math.hypot(m.image_x - tx, m.image_y - ty)
        moved = "" if not math.isfinite(err) or abs(map_err - err) < 0.05 else f" (MAP {map_err:.1f})"
        figures = (f"est {m.image_x:6.1f},{m.image_y:6.1f} truth {tx:6.1f},{ty:6.1f} err {err:6.1f}{moved} "
                   f"p(V=1|Z) {state.p_visible:.2f} box {w:.0f}x{h:.0f} truth {tw:.0f}x{th:.0f}")
        if stretches and stretches[-1][0] == kind:
            stretches[-1][2:] = [i, figures]
        else:
            stretches.append([kind, i, i, figures])
        if i in rows:
            fm = measured[0] if measured else None
            flow = f"flow {fm.dlog:+.3f} sd {math.sqrt(fm.var):.3f} n {fm.points}" if fm is not None else "flow -"
            score = "-" if state.score is None else f"{state.score:.2f}"
            segment = ""
            if reg is not None and reg.attempts > attempts:
                segment = " segment: " + ("registered" if reg.registrations > registrations else "none plausible")
            print(f"f{i} {figures} s {tracker.scale.s:.3f} k {tracker.factor:.2f} score {score} {flow}{segment}")
            r = tracker.reacquirer
            if a.movers and r is not None and _searched(r) > searches:
                g = r.mover_gate
                head = "    searched in doubt: " if r.doubt_searches > doubt else "    searched: "
                print(head + (("no mover" if tracker.motion_cue is not None else "movers not searched")
                                          if g is None else
                      f"mover {g.x:.0f},{g.y:.0f} z {g.z:.2f} at s {g.scale:.2f}: background boxes as strong "
                      f"{g.false_alarms:.3g}, allowed {g.allowed:.3g} ({'passes' if g.false_alarms <= g.allowed else 'fails'})"))
        if a.restarts:
            for det in restarts:
                print(_restart_row(i, det, tracker.reacquirer.doubt_detections > doubt_before,
                                   tracker.reacquirer.mover_detections > movers_before, box, first_box, held_scores))
        if tracker.reacquirer is not None and tracker.reacquirer.held and state.score is not None:
            held_scores.append(float(state.score))
    print(f"{Path(a.sequence).name} seed {a.seed}: stretches")
    for kind, first, last, figures in stretches:
        print(f"  {kind:4s} f{first}-f{last}  last: {figures}")
    print(f"precision20 {np.mean(hits) if hits else float('nan'):.4f} over {len(hits)} frames with a truth")


if __name__ == "__main__":
    main()
