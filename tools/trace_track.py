"""Trace one run of the real-footage tracker frame by frame: where a track is lost, and why.

A diagnostic for docs/real-footage.md (stop 40). It runs the in-process tracker (the profile
`polartrack benchmark` uses, ``--set`` overrides) on one UAV123/OTB folder for one seed and prints:

- for the frames in ``--frames A:B``, one row each: the MAP estimate and the truth's centre, the
  centre error, p(V=1|Z), the box and the truth's size, the scale s and the matching factor k, the
  estimate's own score, the target's own change of size measured from its pixels (``common.single_target.target_flow``:
  change of log size, its standard deviation and the points tracked; ``-`` where not measured), and
  with ``--movers`` on a searched frame the movers' test
  (:class:`common.single_target.reacquire.MoverGate`: the strongest mover, its z, the background
  boxes expected as strong, what the frame allows) and, on a frame the template's registration
  segmented the target (``common.single_target.segment``), whether it registered;
- for the whole run, its stretches: frames within 20 px of the truth (``hit``), beyond (``miss``),
  and without a truth (``out``: the target out of view), each with its last frame's figures;
- the run's precision@20 (as ``polartrack benchmark`` scores it, over the frames with a truth).

    uv run python tools/trace_track.py ../shared/data/uavdt-S1001 --seed 5 --frames 240:270
    uv run python tools/trace_track.py /tmp/stress/uavdt-S1001-away --seed 1 --frames 155:185 --movers

Nothing in the run is changed: the flow measurement is read as the tracker makes it.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common.settings import profile_for  # noqa: E402
from common.single_target import runner  # noqa: E402
from common.sources import open_source  # noqa: E402
from services.commands.common_args import apply_overrides  # noqa: E402

HIT_PX = 20.0


def _frames(text: str | None) -> range:
    if not text:
        return range(0)
    a, _, b = text.partition(":")
    return range(int(a), int(b) + 1 if b else int(a) + 1)


def _searched(r) -> int:
    """Frames the re-acquisition searched so far, lost or in doubt (0 without it)."""
    return 0 if r is None else r.searches + r.doubt_searches


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sequence")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--frames", metavar="A:B", help="print one row for each of these frames (0-based, inclusive)")
    ap.add_argument("--movers", action="store_true", help="print the movers' test on searched frames")
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
    stretches: list[list] = []
    hits = []
    for i, frame in enumerate(src):  # one frame at a time: a long sequence is not held in memory
        box = None if frame.truth is None else frame.truth.box  # a folder's box, or a synthetic scene's
        if tracker is None:
            if box is None:
                raise SystemExit(f"error: {a.sequence} has no ground truth for its first frame: the trace starts "
                                 "from it (a UAV123/OTB folder with groundtruth_rect.txt, or a synthetic scene "
                                 "such as exit:0)")
            tracker = runner.Tracker.start(frame, box, settings)
        measured.clear()
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
            err = math.hypot(m.image_x - tx, m.image_y - ty)
            kind = "hit" if err <= HIT_PX else "miss"
            hits.append(kind == "hit")
        w, h = state.size if state.size is not None else (float("nan"), float("nan"))
        figures = (f"est {m.image_x:6.1f},{m.image_y:6.1f} truth {tx:6.1f},{ty:6.1f} err {err:6.1f} "
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
    print(f"{Path(a.sequence).name} seed {a.seed}: stretches")
    for kind, first, last, figures in stretches:
        print(f"  {kind:4s} f{first}-f{last}  last: {figures}")
    print(f"precision20 {np.mean(hits) if hits else float('nan'):.4f} over {len(hits)} frames with a truth")


if __name__ == "__main__":
    main()
