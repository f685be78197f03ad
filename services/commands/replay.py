"""Replay a recording: republish it on the bus, or re-run the tracker and check the estimates.

Without flags the recorded messages are published again on a loopback bus (``--speed X``
times real time, or ``--max``). ``--retrack`` re-runs the tracker against the recorded frames
with a live detector; ``--offline`` re-runs it from the recorded detector replies with no
detector at all. Both report whether every estimate equals the recorded one (same seed and
config give bit-identical estimates).

The file is streamed (the frame images one chunk at a time; the other topics, a few kB a frame,
are held for the comparison). A file cut short (recorder killed, disk full) is replayed up to the
cut with one warning line; chunks that fail their CRC, state more than 64 MiB decompressed or do
not decompress are skipped and counted; messages that do not decode are skipped and counted;
garbled run settings or init box end the replay with one line saying so (exit 2).
"""

from __future__ import annotations

import argparse
import json

HELP = "replay an MCAP recording (republish, --retrack or --offline with an identity check)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("mcap", metavar="FILE.mcap")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--speed", type=float, default=1.0, help="replay speed (x real time)")
    g.add_argument("--max", action="store_true", help="as fast as possible")
    m = p.add_mutually_exclusive_group()
    m.add_argument("--retrack", action="store_true", help="re-run the tracker with a live detector and compare")
    m.add_argument("--offline", action="store_true", help="re-run the tracker from the recorded replies")
    p.add_argument("--stream", default="replay", help="bus namespace for republishing")
    p.add_argument("--listen", action="append", help="Zenoh endpoint to listen on (republish)")
    p.add_argument("--connect", action="append", help="Zenoh endpoint to connect to (republish)")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def run(args: argparse.Namespace) -> int:
    from services.commands.errors import UsageError
    from common.recording import RecordingError, offline_retrack

    if args.speed is not None and args.speed <= 0:
        raise UsageError("--speed must be positive")
    try:
        if args.offline:
            out = {"mode": "offline", **offline_retrack(args.mcap)}
        elif args.retrack:
            from services.replay import retrack

            out = {"mode": "retrack", **retrack(args.mcap)}
        else:
            from services.bus import BusConfig
            from services.replay import republish

            bus = BusConfig(stream=args.stream, listen=args.listen or ["tcp/127.0.0.1:0"], connect=args.connect or [])
            out = {"mode": "republish", **republish(args.mcap, bus, None if args.max else args.speed)}
    except RecordingError as exc:
        raise UsageError(str(exc)) from None
    except KeyboardInterrupt:
        raise
    except Exception as exc:  # noqa: BLE001 - whatever a hostile file holds: one line, never a traceback
        first = (str(exc).splitlines() or [""])[0][:300]
        raise UsageError(f"{args.mcap}: replay failed ({type(exc).__name__}: {first})") from None
    if args.json:
        print(json.dumps(out))
    elif "identical" in out:
        verdict = "identical" if out["identical"] else "DIFFERENT"
        print(f"{out['mode']}: {out['compared']} estimates compared with {out['recorded']} recorded: {verdict}")
        if out.get("mismatched"):
            print(f"first mismatched frames: {out['mismatched']}")
    else:
        print(f"republished {out['messages']} messages on {out['topics']} topics")
    if not args.json and out.get("malformed"):
        print("malformed messages skipped: " + ", ".join(f"{k} {v}" for k, v in sorted(out["malformed"].items())))
    return 0 if out.get("identical", True) else 1
