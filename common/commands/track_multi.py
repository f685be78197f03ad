"""Track several people through a video, a folder of frames or the synthetic people scene (no scoring).

The targets are given as person boxes in the first frame (``--init-file``: one ``x,y,w,h`` line per
person, pixels, head top to feet; or ``--init X,Y,W,H`` repeated); each becomes a standing
pictorial structure of ``--parts`` parts whose colour histograms are taken from the first frame.
For ``people[:SEED]`` the boxes default to the scene's ground truth. Writes one CSV row per frame,
target and part: ``frame,target,part,x,y`` (part centre, pixels).
"""

from __future__ import annotations

import argparse
import csv
import sys

from common.commands.common_args import box_arg

HELP = "track several articulated people (EPMCMC+ELPDA, EPMCMC+PDA or JPDA-PF), CSV out"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("source", metavar="SOURCE", help="video file, folder of frames, or people[:SEED] (the synthetic scene)")
    p.add_argument("--init-file", metavar="BOXES.txt", help="first-frame person boxes, one x,y,w,h per line")
    p.add_argument("--init", type=box_arg, action="append", metavar="X,Y,W,H", help="a person box (repeatable)")
    p.add_argument("--filter", default="epmcmc-elpda", choices=["epmcmc-elpda", "epmcmc-pda", "jpda-pf"],
                   help="tracker (default epmcmc-elpda)")
    p.add_argument("--parts", type=int, default=10, choices=[1, 2, 6, 10], help="body-model parts (default 10)")
    p.add_argument("--particles", type=int, metavar="N", help="particles per target (default 200)")
    p.add_argument("--people", type=int, default=3, help="people[:SEED] only: number of people, 1-5 (default 3)")
    p.add_argument("--seed", type=int, default=0, help="seed of the tracker's generators")
    p.add_argument("--frames", type=int, metavar="N", help="only the first N frames")
    p.add_argument("--out", metavar="FILE.csv", help="write the CSV here (default: stdout)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")


def _people_frames(spec: str, people: int, n_frames: int | None):
    from common.cli import UsageError
    from common.scene.people import PeopleScene, PeopleSceneConfig

    try:
        seed = int(spec.split(":", 1)[1]) if ":" in spec else 0
        cfg = PeopleSceneConfig(n_people=people, **({"n_frames": n_frames} if n_frames else {}))
    except ValueError as exc:
        raise UsageError(f"bad synthetic people source {spec!r} ({exc}); use people or people:SEED, --people 1..5") from None
    scene = PeopleScene(cfg, seed=seed)
    return (scene.frame(i) for i in range(len(scene))), len(scene), scene.frame(0).truth.boxes


def run(args: argparse.Namespace) -> int:
    import numpy as np
    from tqdm import tqdm

    from common.cli import UsageError
    from common.multitarget import HistogramEvidence, InitError, MultiInit, body_model, make_filter, method_config, read_boxes
    from common.sources import SourceError, open_source

    boxes = None
    try:
        if args.init_file and args.init:
            raise UsageError("give the boxes either with --init-file or with --init, not both")
        if args.init_file:
            boxes = read_boxes(args.init_file)
        elif args.init:
            boxes = np.array(args.init, float)
    except InitError as exc:
        raise UsageError(str(exc)) from None
    if args.source == "people" or args.source.startswith("people:"):
        frames, total, truth_boxes = _people_frames(args.source, args.people, args.frames)
        boxes = truth_boxes if boxes is None else boxes
    else:
        if boxes is None:
            raise UsageError(f"{args.source}: give the people's first-frame boxes with --init-file BOXES.txt "
                             "(one x,y,w,h line per person) or --init X,Y,W,H (repeatable)")
        try:
            source = open_source(args.source, n_frames=args.frames)
        except (SourceError, ValueError) as exc:
            raise UsageError(str(exc)) from None
        frames, total = iter(source), (None if source.live else len(source))
    cfg = method_config(args.filter, n_parts=args.parts, **({"n_particles": args.particles} if args.particles else {}))
    body = body_model(args.parts)
    out = open(args.out, "w", newline="") if args.out else sys.stdout
    try:
        writer = csv.writer(out)
        writer.writerow(["frame", "target", "part", "x", "y"])
        tracker = None
        for k, frame in enumerate(tqdm(frames, total=total, unit="frame", disable=args.no_progress, file=sys.stderr)):
            if args.frames is not None and k >= args.frames:
                break
            ev = HistogramEvidence(frame.image, cfg.histogram)
            if tracker is None:
                h, w = frame.image.shape[:2]
                init = MultiInit.from_boxes(boxes, body, (w, h))
                tracker = make_filter(cfg, init, ev, args.seed)
            state = tracker.step(frame.time, ev)
            for t, parts in enumerate(state.parts):
                for name, (x, y) in zip(body.names, parts):
                    writer.writerow([frame.index, t, name, f"{x:.2f}", f"{y:.2f}"])
    except (InitError, SourceError) as exc:
        raise UsageError(str(exc)) from None
    finally:
        if args.out:
            out.close()
    if tracker is None:
        raise UsageError(f"{args.source}: no frames")
    return 0
