"""The full multi-process pipeline on the built-in synthetic scene (``run --source synthetic``).

Writes an MCAP recording and a Rerun file under recordings/, prints where they are and how well
it tracked: mean error, frames lost (error over 20 px), frame rate.
"""

from __future__ import annotations

import argparse

from services.commands import run as run_cmd
from services.commands.common_args import seed_int

HELP = "run the pipeline on the synthetic scene (recording + Rerun file + tracking summary)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seed", type=seed_int, default=0, help="scene and filter seed")
    run_cmd.add_arguments(p, demo=True)


def run(args: argparse.Namespace) -> int:
    return run_cmd.execute(args, f"synthetic:{args.seed}", None, "rbpf", None, args.seed)
