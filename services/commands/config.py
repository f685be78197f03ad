"""Settings files from the settings models, each key documented.

- ``config run --source SRC [--init X,Y,W,H] [--as PATH] ...``: the run file that compose's
  ingest and tracker read (``deploy/run.toml``): the source, the first box (default: the
  source's first ground-truth box), the filter, and the source's frame rate, read here once.
- ``config dump SERVICE [--deploy]``: a service's keys with their defaults (``--deploy``: the
  compose deployment's ``deploy/SERVICE.toml``).
- ``config deploy [--check] [--dir DIR]``: write every ``deploy/*.toml`` (``--check``: exit 1
  when a committed file differs, naming it).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

HELP = "write settings files: the run file compose tracks with, a service's keys, deploy/*.toml"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from services.commands.common_args import add_overrides_argument, add_run_flags, box_arg

    sub = p.add_subparsers(dest="what", required=True, metavar="WHAT")
    r = sub.add_parser("run", help="the run file (deploy/run.toml): source, first box, filter, settings")
    r.add_argument("--source", required=True, help="video file, image folder, camera:N or synthetic[:SEED]")
    r.add_argument("--init", type=box_arg, metavar="X,Y,W,H",
                   help="the target's box in the first frame (default: the source's first ground-truth box)")
    r.add_argument("--as", dest="as_path", metavar="PATH",
                   help="the source as the services see it (e.g. /data/clip.mp4 in compose), when not --source")
    r.add_argument("--filter", choices=["rbpf", "sir", "ml"], default="rbpf", help="tracking filter")
    add_run_flags(r, "seed", "particles", "profile", "frames", "pace", "image_format")
    add_overrides_argument(r)
    r.add_argument("--out", metavar="FILE.toml", help="write here (default: standard output)")
    d = sub.add_parser("dump", help="a service's keys with their defaults and documentation")
    d.add_argument("service", choices=["ingest", "detector", "tracker", "recorder", "viewer"])
    d.add_argument("--deploy", action="store_true", help="the compose deployment's file (deploy/SERVICE.toml)")
    g = sub.add_parser("deploy", help="write every deploy/*.toml from the models and services/deploy.py")
    g.add_argument("--dir", default="deploy", help="the folder (default: deploy)")
    g.add_argument("--check", action="store_true", help="write nothing; exit 1 if a file differs")


def run(args: argparse.Namespace) -> int:
    from services import deploy

    if args.what == "dump":
        sys.stdout.write(deploy.service_file(args.service, deploy=args.deploy))
        return 0
    if args.what == "deploy":
        return _deploy(Path(args.dir), args.check)
    from services.commands.errors import UsageError

    try:
        text = deploy.run_file(_run_spec(args), _command(args))
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if args.out:
        Path(args.out).write_text(text)
        print(f"wrote {args.out}", file=sys.stderr)
    else:
        sys.stdout.write(text)
    return 0


def _run_spec(args: argparse.Namespace):
    from pydantic import ValidationError

    from common.settings import RunSpec
    from common.sources import SourceError, open_source
    from services.commands.common_args import apply_overrides
    from services.commands.errors import UsageError

    try:
        source = open_source(args.source, n_frames=args.frames)
    except (SourceError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    box = args.init
    if box is None:
        truth = next(iter(source)).truth
        if truth is None or truth.box is None:
            raise UsageError(f"{args.source}: no ground truth for the first frame; give --init X,Y,W,H")
        box = truth.box
    try:
        spec = RunSpec(source=args.as_path or args.source, init_box=tuple(float(v) for v in box), fps=source.fps,
                       frames=args.frames, pace=args.pace, image_format=args.image_format, filter=args.filter,
                       seed=args.seed, particles=args.particles, profile=args.profile)
        if args.overrides:  # checked against the profile, kept as overrides
            base = spec.tracker_settings()
            changed = apply_overrides(base, args.overrides)
            spec = spec.model_copy(update={"settings": _difference(changed.model_dump(), base.model_dump())})
            spec.tracker_settings()
    except ValidationError as exc:
        err = exc.errors()[0]
        raise UsageError(f"{'.'.join(str(v) for v in err['loc'])}: {err['msg']}") from None
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    return spec


def _command(args: argparse.Namespace) -> str:
    """The ``config run`` command line that ``args`` came from (for the file's header)."""
    import shlex

    words = ["uv run polartrack config run", "--source", args.source]
    if args.init is not None:
        words += ["--init", ",".join(f"{v:g}" for v in args.init)]
    for flag, key, default in (("--as", "as_path", None), ("--filter", "filter", "rbpf"), ("--seed", "seed", 0),
                               ("--particles", "particles", None), ("--profile", "profile", None),
                               ("--frames", "frames", None),
                               ("--pace", "pace", "consumer"), ("--image-format", "image_format", "auto")):
        if getattr(args, key) != default:
            words += [flag, str(getattr(args, key))]
    for item in args.overrides:
        words += ["--set", item]
    return " ".join(words[:1] + [shlex.quote(w) for w in words[1:]])


def _difference(new: dict, old: dict) -> dict:
    """The nested keys of ``new`` whose values differ from ``old``'s."""
    out = {}
    for k, v in new.items():
        if isinstance(v, dict) and isinstance(old.get(k), dict):
            sub = _difference(v, old[k])
            if sub:
                out[k] = sub
        elif old.get(k) != v:
            out[k] = v
    return out


def _deploy(folder: Path, check: bool) -> int:
    from services import deploy

    files = deploy.deploy_files(deploy.compose_run_spec())
    if check:
        stale = [n for n, text in files.items() if not (folder / n).is_file() or (folder / n).read_text() != text]
        if stale:
            print(f"polartrack config deploy: {', '.join(stale)} in {folder} differ from the settings models; "
                  f"run `uv run polartrack config deploy`", file=sys.stderr)
            return 1
        print(f"{folder}: {len(files)} files up to date")
        return 0
    folder.mkdir(parents=True, exist_ok=True)
    for name, text in files.items():
        (folder / name).write_text(text)
        print(folder / name)
    return 0
