"""The ``polartrack`` command line (the top layer, above the library in common/ and the service
shells): one sub-command per module in :mod:`services.commands`."""

from __future__ import annotations

import argparse
import re
import sys

from services.commands.errors import UsageError
from services.commands import bench, benchmark, calibrate, config, demo, eval as eval_cmd, eval_multi, graph, info, match, replay, run, study, track, track_multi, view

COMMANDS = {"demo": demo, "run": run, "replay": replay, "view": view, "track": track, "eval": eval_cmd, "calibrate": calibrate, "match": match, "bench": bench, "study": study,
            "eval-multi": eval_multi, "track-multi": track_multi, "benchmark": benchmark, "info": info,
            "config": config, "graph": graph}


class _Parser(argparse.ArgumentParser):
    """argparse, reading a value that starts with a minus and a digit as a value, not an option:
    ``--init -20,-20,15,12`` (a box partly left of the frame) or ``--set x=-1`` as ``-5``."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # argparse's own matcher takes only single numbers (-5, -.5); no option here starts with a digit
        self._negative_number_matcher = re.compile(r"^-\.?\d[\d.eE+\-,;]*$")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="polartrack",
        description="Track a known ground vehicle in aerial video (DTCWT polar matching).",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, module in COMMANDS.items():
        p = sub.add_parser(name, help=module.HELP, description=module.__doc__)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except UsageError as exc:
        print(f"polartrack {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # e.g. `polartrack graph | head`: the reader left, nothing is wrong
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == "__main__":
    sys.exit(main())
