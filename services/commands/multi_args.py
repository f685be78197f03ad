"""Multi-target arguments of ``run`` and ``track`` (``--filter epmcmc-elpda|epmcmc-pda|jpda-pf``).

The targets are person boxes in the first frame: ``--init X,Y,W,H;X,Y,W,H`` (or ``--init``
repeated) or ``--init-file BOXES.txt`` (one ``x,y,w,h`` per line, as ``track-multi``); on the
synthetic people scene (``people[:SEED]``) they default to its ground truth. A single-target filter
takes exactly one box.
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

from services.commands.common_args import box_arg

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
        from services.cli import UsageError

        if not is_people(spec):
            raise UsageError("--people is for the people[:SEED] source only")
        fields = spec.split(":")
        seed = fields[1] if len(fields) > 1 and fields[1] else "0"
        spec = f"people:{seed}:{args.people}"
    return spec


def given_boxes(args) -> np.ndarray | None:
    """(T, 4) boxes from ``--init`` (flattened) or ``--init-file``; None when neither is given."""
    from services.cli import UsageError
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
    from services.cli import UsageError

    boxes = given_boxes(args)
    if boxes is None:
        return None
    if len(boxes) != 1:
        raise UsageError(f"--filter {args.filter} tracks one target: give one --init X,Y,W,H "
                         f"(got {len(boxes)} boxes; several boxes are for {', '.join(MULTI_METHODS)})")
    return tuple(float(v) for v in boxes[0])


def multi_run(args, source, seed: int, particles: int | None):
    """The :class:`common.multitarget_runner.MultiRun` of the arguments, its boxes checked against the
    first frame (UsageError otherwise)."""
    from services.cli import UsageError
    from common.multitarget import InitError, MultiInit, body_model
    from common.multitarget_runner import MultiRun
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
        from services.commands.common_args import apply_overrides

        run = dataclasses.replace(run, config=apply_overrides(run.config, args.overrides))
    return run
