"""Run the full multi-process pipeline on a source.

Starts ingest, detector, tracker, recorder and viewer as separate processes on a private
loopback Zenoh network, shows progress, shuts everything down cleanly on Ctrl-C or when the
source ends, and leaves ``recordings/<time>-<source>.mcap`` and ``.rrd``, printing their paths
and how well it tracked (against the ground truth, when the source has one).

With a multi-target filter (``--filter epmcmc-elpda|epmcmc-pda|jpda-pf``) the tracker follows
several articulated people from their first-frame boxes (``--init X,Y,W,H;X,Y,W,H``, repeated
``--init``, or ``--init-file``; on ``people[:SEED]`` the scene's truth by default), asking the
detector service for the colour histograms; the mean error is then the mean part-centre error
against the people scene's truth.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import sys

from services.commands.common_args import add_overrides_argument, add_run_flags, apply_overrides

HELP = "run the multi-process pipeline (ingest, detector, tracker, recorder, viewer)"


def add_arguments(p: argparse.ArgumentParser, demo: bool = False) -> None:
    if not demo:
        from services.commands.common_args import add_multi_arguments

        p.add_argument("--source", required=True, metavar="SRC",
                       help="video file, UAV123-format folder, camera:N, synthetic[:SEED] or people[:SEED] "
                       "(the synthetic people scene, multi-target filters)")
        add_multi_arguments(p)
        add_run_flags(p, "particles", "profile", "seed")
        add_overrides_argument(p)
    add_run_flags(p, "frames", "pace")
    p.add_argument("--no-viewer", action="store_true", help="do not write the Rerun file")
    p.add_argument("--out-dir", default="recordings", help="where the recordings go")
    p.add_argument("--max-size", type=float, metavar="MB", help="split the recording into files of about MB "
                   "megabytes (NAME.split1.mcap, ...), each readable and replayable alone")
    p.add_argument("--max-duration", type=float, metavar="S", help="split the recording every S seconds")
    p.add_argument("--compression", choices=["lz4", "zstd", "none"], help="the recording's chunk compression "
                   "(default lz4; none for the synthetic scenes, whose noise does not compress)")
    add_run_flags(p, "image_format")
    p.add_argument("--rerun", nargs="+", metavar="MODE", help="live Rerun beside the .rrd (Rerun's examples' "
                   "modes): spawn (a viewer), connect [URL] (a running viewer or server; default "
                   f"{DEFAULT_RERUN_URL}), serve [PORT] (viewers connect to the run; default port 9876), "
                   "save PATH (the .rrd at PATH, with every frame image)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def execute(args: argparse.Namespace, source_spec: str, init, filter_name: str, particles, seed: int,
            multi=None) -> int:
    """Run the pipeline; ``multi`` (a MultiRun) for the multi-target filters."""
    from services.commands.errors import UsageError
    from common.single_target.runner import InitError, check_init_box
    from common.settings import profile_for
    from common.sources import SourceError, open_source

    try:
        source = open_source(source_spec, n_frames=args.frames)
        first = next(iter(source))
    except (SourceError, StopIteration) as exc:
        raise UsageError(str(exc) or f"{source_spec}: no frames") from None
    if multi is not None:
        from common.settings import TrackerSettings

        return _launch(args, source_spec, None, TrackerSettings(seed=seed), multi)
    if init is None:
        if first.truth is None or first.truth.box is None:
            raise UsageError(f"{source_spec}: no ground truth for the first frame; give --init X,Y,W,H")
        init = first.truth.box
    try:
        check_init_box(init, *first.size)
    except InitError as exc:
        raise UsageError(str(exc)) from None
    if particles is not None and particles < 1:
        raise UsageError("--particles must be at least 1")
    settings = profile_for(source, filter=filter_name, seed=seed, particles=particles,
                           preset=getattr(args, "profile", None))
    if getattr(args, "overrides", None):
        settings = apply_overrides(settings, args.overrides)
    return _launch(args, source_spec, init, settings, None)


DEFAULT_RERUN_URL = "rerun+http://127.0.0.1:9876/proxy"


def rerun_options(words: list[str] | None) -> dict:
    """The viewer service's settings for ``--rerun MODE [ARG]``; UsageError for anything else."""
    from services.commands.errors import UsageError

    if not words:
        return {}
    mode, rest = words[0], words[1:]
    usage = "--rerun spawn | connect [URL] | serve [PORT] | save PATH.rrd"
    if len(rest) > 1:
        raise UsageError(f"{usage}: one argument at most after {mode}")
    if mode == "spawn" and not rest:
        return {"spawn": True}
    if mode == "connect":
        url = rest[0] if rest else DEFAULT_RERUN_URL
        if not url.startswith(("rerun://", "rerun+http://", "rerun+https://")):
            raise UsageError(f"--rerun connect {url}: a Rerun gRPC URL, e.g. {DEFAULT_RERUN_URL}")
        return {"rerun_connect": url}
    if mode == "serve":
        if rest and not (rest[0].isdigit() and 0 < int(rest[0]) < 65536):
            raise UsageError(f"--rerun serve {rest[0]}: a port number (1-65535)")
        return {"rerun_serve_port": int(rest[0]) if rest else 9876}
    if mode == "save" and rest:
        if not rest[0].endswith(".rrd"):
            raise UsageError(f"--rerun save {rest[0]}: the file name must end in .rrd")
        return {"out": rest[0], "max_image_hz": 0.0}
    raise UsageError(f"{usage} (got --rerun {' '.join(words)})")


def _launch(args, source_spec: str, init, settings, multi) -> int:
    from services.launcher import Interrupted, Pipeline

    from services.commands.errors import UsageError

    split = {}
    for flag, key, value in (("--max-size", "max_size_mb", args.max_size), ("--max-duration", "max_duration_s",
                                                                             args.max_duration)):
        if value is not None:
            if not value > 0:
                raise UsageError(f"{flag} must be positive")
            split[key] = value
    if args.compression:
        split["compression"] = args.compression
    live = rerun_options(args.rerun)
    from common.sources.published import parse_image_format

    try:
        parse_image_format(args.image_format)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if live and args.no_viewer:
        raise UsageError("--rerun needs the viewer: drop --no-viewer")
    with Pipeline(source_spec, init, settings, out_dir=args.out_dir, frames=args.frames, pace=args.pace,
                  viewer=not args.no_viewer, multi=multi, recorder_options=split or None,
                  viewer_options=live or None, image_format=args.image_format) as pipe:
        if "rerun_serve_port" in live:
            print(f"serving the run to Rerun viewers: rerun --connect rerun+http://127.0.0.1:{live['rerun_serve_port']}/proxy",
                  file=sys.stderr if args.json else sys.stdout, flush=True)
        try:
            result = pipe.run(progress=not args.no_progress)
        except KeyboardInterrupt as exc:
            pipe.close()
            signum = exc.signum if isinstance(exc, Interrupted) else 2
            print(f"interrupted ({'SIG' + str(exc) if isinstance(exc, Interrupted) else 'SIGINT'}): services stopped",
                  flush=True)
            return 128 + signum
        failed = {s: c for s, c in result.returncodes.items() if c not in (0, None)}
        logs = {s: pipe.log_text(s)[-2000:] for s in failed}
    out = result.as_dict()
    if args.json:
        print(json.dumps(out))
    else:
        print(f"recording: {result.mcap}")
        for part in result.recordings[1:]:
            why = "split" if ".split" in Path(part).name else "after a restart of the recorder"
            print(f"           {part}   ({why})")
        if result.rrd:
            parts = sorted(Path(result.rrd).parent.glob(Path(result.rrd).stem + ".split*.rrd"),
                           key=lambda q: int(q.stem.rsplit(".split", 1)[1]))
            if parts:  # the viewer's parts of one Rerun recording (ViewerSettings.rotate_frames)
                print(f"rerun:     {result.rrd} and {len(parts)} more parts   "
                      f"(open together: rerun {result.rrd} {Path(result.rrd).with_name(Path(result.rrd).stem + '.split*.rrd')})")
            else:
                print(f"rerun:     {result.rrd}   (open with: rerun {result.rrd})")
            if result.rrd_images is not None:
                thinned = (" (at most 10 a second; --rerun save PATH.rrd keeps every one)"
                           if result.rrd_images < result.frames else "")
                print(f"           {result.rrd_images} of {result.frames} frame images kept{thinned}")
        err = "n/a" if result.mean_err is None else f"{result.mean_err:.2f} px"
        if multi is not None:
            err += " (mean part-centre error)"
        verb = "tracked" if result.ok else "estimated (the run FAILED, see below)"
        print(f"{result.estimates} of {result.frames} frames {verb} at {result.fps:.1f} fps; mean error {err}; "
              f"frames lost (error > 20 px): {result.frames_lost if result.frames_lost is not None else 'n/a'}")
        for service, table in result.rejected.items():
            print(f"dropped by {service}: " + ", ".join(f"{k} {r} {n}" for k, v in table.items() for r, n in v.items()))
    for r in result.restarts:
        print(f"service {r['service']} exited with status {r['status']} after {r['died_after_frames']} frames: restarted",
              file=sys.stderr)
    for s, code in failed.items():
        print(f"service {s} exited with status {code}; last log lines:\n{logs[s]}", file=sys.stderr)
    if result.failure:
        print(f"run failed: {result.failure}", file=sys.stderr)
    return 0 if result.ok else 1


def run(args: argparse.Namespace) -> int:
    from services.commands.common_args import MULTI_METHODS, multi_run, single_box, source_spec

    if args.filter in MULTI_METHODS:
        from services.commands.errors import UsageError
        from common.sources import SourceError, open_source

        spec = source_spec(args)
        try:
            source = open_source(spec, n_frames=args.frames)
        except (SourceError, ValueError) as exc:
            raise UsageError(str(exc)) from None
        run_ = multi_run(args, source, args.seed, args.particles)
        return execute(args, spec, None, args.filter, args.particles, args.seed, multi=run_)
    return execute(args, args.source, single_box(args), args.filter, args.particles, args.seed)
