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

HELP = "track several articulated people (EPMCMC+ELPDA, EPMCMC+PDA or JPDA-PF), CSV out"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from services.commands.track import add_arguments as track_arguments

    track_arguments(p)
    p.set_defaults(filter="epmcmc-elpda")


def run(args: argparse.Namespace) -> int:
    """``track --filter ...`` with this command's argument names: one implementation of in-process
    multi-target tracking (:func:`services.commands.track.run_multi`)."""
    from services.commands.track import run_multi

    return run_multi(args)
