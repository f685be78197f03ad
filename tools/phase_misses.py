"""Where a sequence's frames are missed: frames with a centre error above 20 px (or no box) per
stretch of frames and per seed, from a ``polartrack benchmark`` run's per-frame CSV.

A diagnostic for docs/real-footage.md (stop 38): a seed's precision20 says how many frames were
missed, not where; the stretches (``--bounds``, frame numbers from 0) are read off the sequence's
events (car16: the approach, the close pass, the car driving away and turning).

    uv run polartrack benchmark ../shared/data/uav123-car16 --seeds 10 --jobs 2 --out /tmp/car16
    uv run python tools/phase_misses.py /tmp/car16/frames-uav123-car16.csv --bounds 0,86,112,200,300,400,500,600,665
"""

from __future__ import annotations

import argparse
import csv
from collections import defaultdict

import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("frames_csv")
    ap.add_argument("--bounds", required=True, help="comma-separated frame numbers: the stretches' edges")
    ap.add_argument("--tracker", default="polartrack")
    ap.add_argument("--threshold", type=float, default=20.0)
    a = ap.parse_args(argv)
    bounds = [int(v) for v in a.bounds.split(",")]
    missed: dict[str, dict[int, bool]] = defaultdict(dict)
    with open(a.frames_csv, newline="") as f:
        for row in csv.DictReader(f):
            if row["tracker"] != a.tracker or not row["truth_x"]:
                continue  # another tracker's run, or a frame without a visible target (not scored)
            err = float(row["centre_error"]) if row["centre_error"] else float("inf")
            missed[row["seed"] or "-"][int(row["frame"])] = err > a.threshold
    stretches = list(zip(bounds, bounds[1:]))
    print("seed", *[f"{lo}-{hi}" for lo, hi in stretches], "precision20", sep="\t")
    totals = np.zeros(len(stretches))
    for seed, frames in missed.items():
        counts = [sum(m for i, m in frames.items() if lo <= i < hi) for lo, hi in stretches]
        totals += counts
        print(seed, *counts, f"{1 - sum(frames.values()) / len(frames):.3f}", sep="\t")
    print("mean", *[f"{t / len(missed):.1f}" for t in totals], sep="\t")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
