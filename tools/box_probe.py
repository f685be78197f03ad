"""Which box and which point to score: the same runs scored several ways (stop 37).

A diagnostic for docs/real-footage.md ("The benchmarks' box", stop 37). It runs the in-process
tracker (the real-footage profile, ``--set`` overrides) once per sequence and seed, keeps every
frame's estimate, and scores the same estimates with the benchmark's scorer
(:func:`common.evaluation.benchmark.score_boxes`) as:

- ``extent``: the product's box (:meth:`TrackState.axis_aligned_box`, the oriented box's extent turned);
- ``envelope``: the smallest axis-aligned box holding the turned box (the product before stop 37);
- ``envelope-mmse-angle``: the same, turned by the MMSE's (circular mean) angle;
- ``envelope-smooth-S``: turned by the MAP's angle low-passed with a time constant of S seconds;
- ``unturned``: the first box times the scale, never turned;
- ``extent-at-mmse``: the product's box about the MMSE estimate's image position instead of the MAP's.

The tracking is the same in every row (only the scoring differs), so the rows compare frame for
frame. Prints per sequence and in the mean: precision20 / success AUC.

    uv run python tools/box_probe.py ../shared/data/uav* --seeds 5 --jobs 2
"""

from __future__ import annotations

import argparse
import math
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common.evaluation.benchmark import score_boxes  # noqa: E402
from common.tracking.state import oriented_to_axis_aligned, oriented_to_moment_box  # noqa: E402

SMOOTHING_S = (1.0, 0.3)


def _variants(rows: list[tuple]) -> dict[str, list]:
    """Per variant, the per-frame (x, y, w, h) boxes (NaN rows without a box) of one run's
    ``rows`` (time, oriented box, MMSE angle, MMSE image point)."""
    nan = (math.nan,) * 4
    out: dict[str, list] = {k: [] for k in ("extent", "envelope", "envelope-mmse-angle", "unturned", "extent-at-mmse")}
    for s in SMOOTHING_S:
        out[f"envelope-smooth-{s:g}"] = []
    smooth = {s: None for s in SMOOTHING_S}
    last_t = None
    for t, ob, mmse_theta, (mx, my) in rows:
        if ob is None:
            for v in out.values():
                v.append(nan)
            continue
        cx, cy, w, h, th = ob
        out["extent"].append(oriented_to_moment_box(cx, cy, w, h, th))
        out["envelope"].append(oriented_to_axis_aligned(cx, cy, w, h, th))
        out["envelope-mmse-angle"].append(oriented_to_axis_aligned(cx, cy, w, h, mmse_theta))
        out["unturned"].append(oriented_to_axis_aligned(cx, cy, w, h, 0.0))
        out["extent-at-mmse"].append(oriented_to_moment_box(mx, my, w, h, th))
        a = math.radians(th)
        for s in SMOOTHING_S:
            c = smooth[s]
            if c is None or last_t is None:
                c = [math.cos(a), math.sin(a)]
            else:
                g = 1.0 - math.exp(-(t - last_t) / s)
                c = [c[0] + g * (math.cos(a) - c[0]), c[1] + g * (math.sin(a) - c[1])]
            smooth[s] = c
            out[f"envelope-smooth-{s:g}"].append(oriented_to_axis_aligned(cx, cy, w, h, math.degrees(math.atan2(c[1], c[0]))))
        last_t = t
    return out


def _run(spec: str, seed: int, overrides: list[str]) -> dict[str, list]:
    from common.settings import profile_for
    from common.single_target.runner import Tracker
    from common.sources import open_source
    from services.commands.common_args import apply_overrides

    src = open_source(spec)
    st = profile_for(src, seed=seed)
    if overrides:
        st = apply_overrides(st, overrides)
    tracker, rows = None, []
    for frame in src:
        if tracker is None:
            tracker = Tracker.start(frame, tuple(float(v) for v in src.truth[0]), st)
        state = tracker.step(frame)
        rows.append((state.time, state.oriented_box(), state.mmse_estimate.theta,
                     (state.mmse_estimate.image_x, state.mmse_estimate.image_y)))
    return _variants(rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sequences", nargs="+")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", dest="overrides")
    a = ap.parse_args(argv)
    from common.sources import open_source

    truth = {spec: list(open_source(spec).truth) for spec in a.sequences}
    tasks = [(spec, seed) for spec in a.sequences for seed in range(a.seeds)]
    with ProcessPoolExecutor(max_workers=max(1, a.jobs)) as pool:
        runs = list(pool.map(_run, *zip(*tasks), [a.overrides] * len(tasks)))
    table: dict[str, dict[str, tuple[float, float]]] = {}
    for spec in a.sequences:
        mine = [r for (s, _), r in zip(tasks, runs) if s == spec]
        for variant in mine[0]:
            scores = [score_boxes(r[variant], truth[spec]) for r in mine]
            table.setdefault(variant, {})[Path(spec).name] = (float(np.mean([x.precision20 for x in scores])),
                                                              float(np.mean([x.success_auc for x in scores])))
    names = [Path(s).name for s in a.sequences]
    print("variant".ljust(22) + "".join(n[-14:].rjust(16) for n in names) + "mean".rjust(16))
    for variant, per in table.items():
        cells = [per[n] for n in names]
        mean = (float(np.mean([c[0] for c in cells])), float(np.mean([c[1] for c in cells])))
        print(variant.ljust(22) + "".join(f"{p:.3f} / {s:.3f}".rjust(16) for p, s in cells + [mean]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
