"""Arguments and helpers shared by the tracking commands (track, eval, run, benchmark).

Multi-target arguments of ``run`` and ``track`` (``--filter epmcmc-elpda|epmcmc-pda|jpda-pf``): the
targets are person boxes in the first frame: ``--init X,Y,W,H;X,Y,W,H`` (or ``--init`` repeated) or
``--init-file BOXES.txt`` (one ``x,y,w,h`` per line, as ``track-multi``); on the synthetic people
scene (``people[:SEED]``) they default to its ground truth. A single-target filter takes exactly
one box.
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np


def _int_at_least(low: int, what: str):
    """An argparse type: a whole number of at least ``low``; ``what`` names it in the error."""

    def parse(text: str) -> int:
        try:
            n = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
        if n < low:
            raise argparse.ArgumentTypeError(f"{what} at least {low}, got {n}")
        return n

    return parse


positive_int = _int_at_least(1, "must be")
"""``--frames``, ``--particles``: at least 1."""
seed_int = _int_at_least(0, "a seed is")
"""A random generator's seed: at least 0."""


def box_arg(text: str) -> tuple[float, float, float, float]:
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected X,Y,W,H (four numbers), got {text!r}") from None
    if len(vals) != 4:
        raise argparse.ArgumentTypeError(f"expected X,Y,W,H (four numbers), got {text!r}")
    return vals  # type: ignore[return-value]


def add_tracking_arguments(p: argparse.ArgumentParser, multi_filter: bool = False, multi_target: bool = False) -> None:
    """``multi_target``: also the multi-target filters (several ``--init`` boxes, ``--init-file``, ``--parts``)."""
    p.add_argument("source", metavar="SOURCE",
                   help="video file, UAV123-format folder (img/ + groundtruth_rect.txt), camera:N, or synthetic[:SEED]"
                   + (", or people[:SEED] (the synthetic people scene, multi-target filters)" if multi_target else ""))
    if multi_target:
        add_multi_arguments(p)
    else:
        p.add_argument("--init", type=box_arg, metavar="X,Y,W,H",
                       help="target box in the first frame (default: the source's ground truth)")
    if multi_target:
        pass
    elif multi_filter:
        p.add_argument("--filter", default="rbpf", metavar="F[,F...]",
                       help="filters to run side by side: rbpf, sir, ml (comma separated)")
    else:
        p.add_argument("--filter", default="rbpf", choices=["rbpf", "sir", "ml"], help="tracking filter")
    add_run_flags(p, "particles", "profile", "seed", "frames")
    p.add_argument("--ml-threshold", type=float, metavar="T", help="windowed ML detection threshold (default 0.6)")
    add_overrides_argument(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")


RUN_FLAGS = {
    "particles": {"type": positive_int, "metavar": "N"},
    "seed": {"type": seed_int, "default": 0},
    "frames": {"type": positive_int, "metavar": "N"},
    "pace": {"default": "consumer"},
    "image_format": {"default": "auto", "metavar": "F"},
    "profile": {},  # its choices: the field's type
}
"""The run's flags (``common.settings.RunSpec`` fields, their documentation the help) with what a
command line adds to the field's type: the checks, the defaults shown, the metavars."""


def add_run_flags(p: argparse.ArgumentParser, *names: str) -> None:
    """The flags of the run's ``names`` (``--image-format`` for ``image_format``), generated from
    :class:`common.settings.RunSpec` (one declaration for the CLI, the run file and compose)."""
    from common.settings import RunSpec
    from services.options import field_help, flag_type

    for name in names:
        field = RunSpec.model_fields[name]
        kw = dict(flag_type(field.annotation) or {})
        kw |= RUN_FLAGS[name]
        p.add_argument("--" + name.replace("_", "-"), dest=name, help=field_help(field), **kw)


def add_overrides_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", dest="overrides",
                   help="override a tracker setting by its dotted name (repeatable), e.g. --set stabilise=off "
                        "--set adaptation.enabled=false --set scale.mode=off --set scale.target_size_px=null; "
                        "VALUE is JSON (numbers, true/false, null) or else a string")


def published_source(source, spec: str):
    """``source`` as the bus carries it with image format ``spec`` (UsageError when unknown)."""
    from services.commands.errors import UsageError
    from common.sources.published import PublishedSource

    try:
        return PublishedSource(source, spec)
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def open_checked(args):
    """Open the source and the initial box, turning bad input into UsageError."""
    from services.commands.errors import UsageError
    from common.sources import SourceError, open_source

    try:
        source = open_source(args.source, n_frames=args.frames)
    except (SourceError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    init = args.init
    if isinstance(init, list) or getattr(args, "init_file", None):  # the multi-target-capable --init / --init-file
        init = single_box(args)
    if init is None:
        first_truth = None
        try:
            first = next(iter(source))
            first_truth = first.truth
        except SourceError as exc:
            raise UsageError(str(exc)) from None
        if first_truth is None or first_truth.box is None:
            raise UsageError(f"{args.source}: no ground truth for the first frame; give --init X,Y,W,H")
        init = first_truth.box
    return source, tuple(float(v) for v in init)


def settings_for(args, source, filter_name: str):
    from services.commands.errors import UsageError
    from common.settings import profile_for

    if args.particles is not None and args.particles < 1:
        raise UsageError("--particles must be at least 1")
    st = profile_for(source, filter=filter_name, seed=args.seed, particles=args.particles,
                     preset=getattr(args, "profile", None))
    if getattr(args, "ml_threshold", None) is not None:
        st = st.model_copy(update={"ml": st.ml.model_copy(update={"threshold": args.ml_threshold})})
    if getattr(args, "overrides", None):
        st = apply_overrides(st, args.overrides)
    return st


def apply_overrides(settings, overrides: list[str]):
    """``settings`` (a pydantic model: the tracker settings, or a multi-target filter's config) with
    ``KEY=VALUE`` overrides applied (dotted keys, JSON values), validated."""
    import json

    from common.settings import with_overrides
    from services.commands.errors import UsageError

    for item in overrides:
        key, sep, text = item.partition("=")
        if not sep or not key:
            raise UsageError(f"--set {item!r}: expected KEY=VALUE")
        try:
            value = json.loads(text)
        except ValueError:
            value = text
        nested: dict = {}
        node = nested
        parts = key.split(".")
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = value
        try:
            settings = with_overrides(settings, nested)
        except ValueError as exc:
            raise UsageError(f"--set {item!r}: {exc}") from None
    return settings


def point_estimate(state) -> tuple[float, float]:
    e = state.map_estimate
    return float(e.image_x), float(e.image_y)


def truth_centre(source, frame) -> tuple[float, float]:
    """Ground-truth centre: the synthetic scene knows it even while the target is hidden."""
    if hasattr(source, "true_centre"):
        return source.true_centre(frame.index)
    c = frame.truth.centre if frame.truth is not None else None
    return (np.nan, np.nan) if c is None else c


MULTI_METHODS = ("epmcmc-elpda", "epmcmc-pda", "jpda-pf")
"""common.multitarget.METHODS, spelt out so that building the parser imports no filter code (tested equal)."""


def boxes_arg(text: str) -> list[tuple[float, float, float, float]]:
    """``X,Y,W,H`` or several separated by ';'."""
    parts = [t for t in text.split(";") if t.strip()]
    if not parts:
        raise argparse.ArgumentTypeError(f"expected X,Y,W,H[;X,Y,W,H...], got {text!r}")
    return [box_arg(t.strip()) for t in parts]


def add_multi_arguments(p: argparse.ArgumentParser) -> None:
    """``--init`` (one box or several), ``--filter`` (single- and multi-target), ``--init-file``,
    ``--parts``, ``--people``: what ``run`` and ``track`` take to track one target or several."""
    p.add_argument("--init", type=boxes_arg, action="append", metavar="X,Y,W,H[;X,Y,W,H]",
                   help="target box in the first frame (default: the source's ground truth); the "
                   "multi-target filters take several (';'-separated or repeated)")
    p.add_argument("--filter", default="rbpf", choices=["rbpf", "sir", "ml", *MULTI_METHODS],
                   help="tracking filter: rbpf, sir, ml (one target) or epmcmc-elpda, epmcmc-pda, jpda-pf "
                   "(several articulated people)")
    p.add_argument("--init-file", metavar="BOXES.txt",
                   help="multi-target filters: first-frame person boxes, one x,y,w,h per line")
    p.add_argument("--parts", type=int, default=10, choices=[1, 2, 6, 10],
                   help="multi-target filters: body-model parts (default 10)")
    p.add_argument("--people", type=int, metavar="K",
                   help="people[:SEED] source: number of people, 1-5 (default 3)")


def is_people(spec: str) -> bool:
    return spec == "people" or spec.startswith("people:")


def source_spec(args) -> str:
    """The source string, with ``--people K`` folded into a people source (``people:SEED:K``)."""
    spec = args.source
    if getattr(args, "people", None) is not None:
        from services.commands.errors import UsageError

        if not is_people(spec):
            raise UsageError("--people is for the people[:SEED] source only")
        fields = spec.split(":")
        seed = fields[1] if len(fields) > 1 and fields[1] else "0"
        spec = f"people:{seed}:{args.people}"
    return spec


def given_boxes(args) -> np.ndarray | None:
    """(T, 4) boxes from ``--init`` (flattened) or ``--init-file``; None when neither is given."""
    from services.commands.errors import UsageError
    from common.multitarget import InitError, read_boxes

    init = getattr(args, "init", None)
    init_file = getattr(args, "init_file", None)
    if init and init_file:
        raise UsageError("give the boxes either with --init-file or with --init, not both")
    if init_file:
        try:
            return read_boxes(init_file)
        except InitError as exc:
            raise UsageError(str(exc)) from None
    if init:
        flat = [b for group in init for b in (group if isinstance(group, list) else [group])]
        return np.array(flat, float)
    return None


def single_box(args):
    """The single-target filters' one box (None: the source's ground truth)."""
    from services.commands.errors import UsageError

    boxes = given_boxes(args)
    if boxes is None:
        return None
    if len(boxes) != 1:
        raise UsageError(f"--filter {args.filter} tracks one target: give one --init X,Y,W,H "
                         f"(got {len(boxes)} boxes; several boxes are for {', '.join(MULTI_METHODS)})")
    return tuple(float(v) for v in boxes[0])


def multi_run(args, source, seed: int, particles: int | None):
    """The :class:`common.multitarget.runner.MultiRun` of the arguments, its boxes checked against the
    first frame (UsageError otherwise)."""
    from services.commands.errors import UsageError
    from common.multitarget import InitError, MultiInit, body_model
    from common.multitarget.runner import MultiRun
    from common.sources import SourceError

    boxes = given_boxes(args)
    if boxes is None:
        if hasattr(source, "person_boxes"):
            boxes = source.person_boxes()
        else:
            raise UsageError(f"{args.source}: give the people's first-frame boxes with --init-file BOXES.txt "
                             "(one x,y,w,h line per person) or --init X,Y,W,H;X,Y,W,H")
    if particles is not None and particles < 2:
        raise UsageError("--particles must be at least 2 for the multi-target filters")
    try:
        first = next(iter(source))
    except (SourceError, StopIteration) as exc:
        raise UsageError(str(exc) or f"{args.source}: no frames") from None
    try:
        run = MultiRun.make(args.filter, boxes, seed=seed, n_parts=args.parts, particles=particles)
        MultiInit.from_boxes(np.array(run.boxes), body_model(args.parts), first.size)
    except (InitError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    if getattr(args, "overrides", None):  # --set KEY=VALUE on the filter's config (common/multitarget/config.py)
        run = dataclasses.replace(run, config=apply_overrides(run.config, args.overrides))
    return run
