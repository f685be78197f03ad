"""Fit the Beta likelihoods of the detector's scores (Pang et al. 2010 section 5, Fig. 5).

Samples scores within 5 px of the true target and at random background positions over the
first frames with the target fully visible, fits Beta(a, b) to each by maximum likelihood,
prints the parameters and writes a PNG of the two histograms with the fitted densities.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from services.commands.common_args import seed_int

HELP = "fit Beta likelihood parameters from a source with ground truth (Pang Fig. 5)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("source", metavar="SOURCE", help="UAV123-format folder or synthetic[:SEED]")
    p.add_argument("--frames", type=int, default=100, help="frames to sample (default 100)")
    p.add_argument("--per-frame", type=int, default=20, help="visible samples per frame (5x as many background)")
    p.add_argument("--seed", type=seed_int, default=0, help="seed of the sampling positions")
    p.add_argument("--out", metavar="FILE.png", help="histogram plot (default recordings/calibration-SOURCE.png)")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def run(args: argparse.Namespace) -> int:
    from common.evaluation.calibration import calibrate, plot_calibration
    from services.commands.errors import UsageError
    from common.sources import SourceError, open_source

    if args.frames < 1 or args.per_frame < 1:
        raise UsageError("--frames and --per-frame must be at least 1")
    try:
        source = open_source(args.source)
        cal = calibrate(source, seed=args.seed, frames=args.frames, per_frame=args.per_frame)
    except (SourceError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    out = Path(args.out) if args.out else Path("recordings") / f"calibration-{source.name}.png"
    out.parent.mkdir(parents=True, exist_ok=True)
    plot_calibration(cal, str(out), title=source.name)
    result = {**cal.as_dict(), "plot": str(out)}
    if args.json:
        print(json.dumps(result))
    else:
        v, b = result["visible"], result["background"]
        print(f"visible target: Beta({v['a']:.3f}, {v['b']:.3f})  (n={v['n']}, mean {v['mean']:.3f})")
        print(f"background:     Beta({b['a']:.3f}, {b['b']:.3f})  (n={b['n']}, mean {b['mean']:.3f})")
        print(f"plot: {out}")
    return 0
