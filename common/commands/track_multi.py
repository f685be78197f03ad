"""Track several people through a video, a folder of frames or the synthetic people scene (no scoring).

The targets are given as person boxes in the first frame (``--init-file``: one ``x,y,w,h`` line per
person, pixels, head top to feet; or ``--init X,Y,W,H`` repeated); each becomes a standing
pictorial structure of ``--parts`` parts whose colour histograms are taken from the first frame.
For ``people[:SEED]`` the boxes default to the scene's ground truth. Writes one CSV row per frame,
target and part: ``frame,target,part,x,y`` (part centre, pixels). The same as ``track SOURCE
--filter epmcmc-elpda|epmcmc-pda|jpda-pf``.
"""

from __future__ import annotations

import argparse

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
    p.add_argument("--people", type=int, metavar="K", help="people[:SEED] only: number of people, 1-5 (default 3)")
    p.add_argument("--seed", type=int, default=0, help="seed of the tracker's generators")
    p.add_argument("--frames", type=int, metavar="N", help="only the first N frames")
    p.add_argument("--out", metavar="FILE.csv", help="write the CSV here (default: stdout)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")


def run(args: argparse.Namespace) -> int:
    """``track --filter ...`` with this command's argument names: one implementation of in-process
    multi-target tracking (:func:`common.commands.track.run_multi`)."""
    from common.commands.track import run_multi

    return run_multi(args)
