"""The pipeline's graph (common/msgs/topics.py): every key on the bus, its message, who
publishes it, who listens, whether it is recorded; as a Markdown table (the README's) or a
Mermaid flowchart (``--mermaid``)."""

from __future__ import annotations

import argparse

HELP = "print the pipeline's graph: keys, messages, publishers, subscribers, recorded"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mermaid", action="store_true", help="a Mermaid flowchart instead of the table")


def run(args: argparse.Namespace) -> int:
    from common.msgs.topics import mermaid, table

    print(mermaid() if args.mermaid else table())
    return 0
