"""What a recording holds: time span, messages per topic with their rates and schemas, chunk
compression and sizes, and the run's source, first box, seed and settings (``ros2 bag info``'s
habits). Reads the MCAP summary only; a file cut short (no summary) is read up to the cut."""

from __future__ import annotations

import argparse
import json

HELP = "summarise a recording (topics, counts, rates, schemas, compression, run metadata)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", metavar="FILE.mcap", help="a recording (recordings/*.mcap)")
    p.add_argument("--json", action="store_true", help="print one JSON object (with every metadata key)")


def run(args: argparse.Namespace) -> int:
    from common.record.info import InfoError, format_info, recording_info
    from services.commands.errors import UsageError

    try:
        info = recording_info(args.file)
    except InfoError as exc:
        raise UsageError(str(exc)) from None
    print(json.dumps(info.as_dict(), indent=1) if args.json else format_info(info))
    return 0
