"""Track a target through a source, in-process, and write one CSV row per frame.

Columns: frame (from 0, source order), x, y (image pixel centre of the estimate: the MAP for
the particle filters), theta_deg (rotation relative to the first frame's template,
anticlockwise as displayed), p_visible (posterior probability that the target is visible),
w, h (the target's box in pixels before the rotation by theta_deg), box_x, box_y (the box's
centre: x, y, unless the target's centre was measured apart from the point the filter holds,
``segment.centre_box``): an oriented box.

With a multi-target filter (``--filter epmcmc-elpda|epmcmc-pda|jpda-pf``) it tracks several
articulated people from their first-frame boxes (``--init X,Y,W,H;X,Y,W,H``, ``--init`` repeated or
``--init-file``; on ``people[:SEED]`` the scene's ground truth by default), as ``track-multi``,
and writes ``frame,target,part,x,y`` (part centres, pixels): the same estimates, bit for bit, as
``polartrack run`` with the same source, seed and settings.
"""

from __future__ import annotations

import argparse
import csv
import sys

from services.commands.common_args import (add_run_flags, add_tracking_arguments, open_checked,
                                           point_estimate, published_source, settings_for)

HELP = "track a target through a video, folder or the synthetic scene (CSV out)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_tracking_arguments(p, multi_target=True)
    p.add_argument("--out", metavar="FILE.csv", help="write the CSV here (default: stdout)")
    add_run_flags(p, "image_format")


def run(args: argparse.Namespace) -> int:
    from services.commands.common_args import MULTI_METHODS
    from common.single_target.runner import track_frames

    if args.filter in MULTI_METHODS:
        return run_multi(args)
    source, init = open_checked(args)
    source = published_source(source, args.image_format)  # the frames as `run` publishes them
    settings = settings_for(args, source, args.filter)

    def rows():
        for frame, state in track_frames(source, init, settings):
            x, y = point_estimate(state)
            w, h = state.size if state.size is not None else (float("nan"), float("nan"))
            dx, dy = state.box_offset or (0.0, 0.0)
            yield [[frame.index, f"{x:.3f}", f"{y:.3f}", f"{state.map_estimate.theta:.3f}", f"{state.p_visible:.6f}",
                    f"{w:.3f}", f"{h:.3f}", f"{x + dx:.3f}", f"{y + dy:.3f}"]]

    return _write_csv(args, ["frame", "x", "y", "theta_deg", "p_visible", "w", "h", "box_x", "box_y"], rows(), source)


def _write_csv(args: argparse.Namespace, header: list[str], rows, source) -> int:
    """Write ``header`` then, per frame, the row lists ``rows`` yields, to ``--out`` or stdout, with
    a progress bar; a bad initialisation or source met on the way is a usage error."""
    from tqdm import tqdm

    from services.commands.errors import UsageError
    from common.tracking.state import InitError
    from common.sources import SourceError

    total = None if source.live else len(source)
    bar = tqdm(total=total, unit="frame", disable=args.no_progress, file=sys.stderr, desc=source.name)
    it = iter(rows)
    try:
        # the first frame starts the tracker (a bad box or source fails there): nothing is written,
        # not even the header, until it has worked
        first = next(it, None)
        out = open(args.out, "w", newline="") if args.out else sys.stdout
        try:
            writer = csv.writer(out)
            writer.writerow(header)
            if first is not None:
                writer.writerows(first)
                bar.update(1)
            for frame_rows in it:
                writer.writerows(frame_rows)
                bar.update(1)
        finally:
            if args.out:
                out.close()
    except (InitError, SourceError) as exc:
        raise UsageError(str(exc)) from None
    finally:
        bar.close()
    return 0


def run_multi(args: argparse.Namespace) -> int:
    """In-process multi-target tracking (:func:`common.multitarget.runner.track_frames`)."""
    from services.commands.errors import UsageError
    from services.commands.common_args import multi_run, source_spec
    from common.multitarget import body_model
    from common.multitarget.runner import track_frames as track_multi_frames
    from common.sources import SourceError, open_source

    try:
        source = open_source(source_spec(args), n_frames=args.frames)
    except (SourceError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    run = multi_run(args, source, args.seed, args.particles)
    names = body_model(run.config.n_parts).names

    def rows():
        for frame, state in track_multi_frames(source, run):
            yield [[frame.index, t, name, f"{x:.6f}", f"{y:.6f}"]
                   for t, parts in enumerate(state.parts) for name, (x, y) in zip(names, parts)]

    return _write_csv(args, ["frame", "target", "part", "x", "y"], rows(), source)
