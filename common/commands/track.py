"""Track a target through a source, in-process, and write one CSV row per frame.

Columns: frame (from 0, source order), x, y (image pixel centre of the estimate: the MAP for
the particle filters), theta_deg (rotation relative to the first frame's template,
anticlockwise as displayed), p_visible (posterior probability that the target is visible).
"""

from __future__ import annotations

import argparse
import csv
import sys

from common.commands.common_args import add_tracking_arguments, open_checked, point_estimate, settings_for

HELP = "track a target through a video, folder or the synthetic scene (CSV out)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_tracking_arguments(p)
    p.add_argument("--out", metavar="FILE.csv", help="write the CSV here (default: stdout)")


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from common.cli import UsageError
    from common.runner import InitError, track_frames
    from common.sources import SourceError

    source, init = open_checked(args)
    settings = settings_for(args, source, args.filter)
    out = open(args.out, "w", newline="") if args.out else sys.stdout
    try:
        writer = csv.writer(out)
        writer.writerow(["frame", "x", "y", "theta_deg", "p_visible"])
        total = len(source) if not source.live else None
        for frame, state in tqdm(track_frames(source, init, settings), total=total, unit="frame",
                                 disable=args.no_progress, file=sys.stderr, desc=source.name):
            x, y = point_estimate(state)
            writer.writerow([frame.index, f"{x:.3f}", f"{y:.3f}", f"{state.map_estimate.theta:.3f}",
                             f"{state.p_visible:.6f}"])
    except (InitError, SourceError) as exc:
        raise UsageError(str(exc)) from None
    finally:
        if args.out:
            out.close()
    return 0
