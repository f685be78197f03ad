"""Replay a recording: republish it on the bus, or re-run the tracker and check the estimates.

Without flags the recorded messages are published again on a loopback bus (``--speed X``
times real time, or ``--max``), the endpoint printed first; ``--topics`` picks topics,
``--start``/``--end`` a window (seconds from the first message), ``--loop`` repeats it. ``--retrack`` re-runs the tracker against the recorded frames
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
    p.add_argument("--topics", nargs="+", metavar="TOPIC", help="republish only these topics (e.g. frame/image "
                   "track/estimate; `polartrack info FILE.mcap` lists them)")
    p.add_argument("--start", type=float, default=0.0, metavar="S",
                   help="republish from S seconds after the recording's first message")
    p.add_argument("--end", type=float, metavar="S", help="republish up to S seconds after the first message")
    p.add_argument("--loop", type=int, nargs="?", const=0, default=1, metavar="N",
                   help="republish N times (--loop alone: until interrupted)")
    p.add_argument("--rerun", nargs="+", metavar="MODE", help="send the recording to Rerun instead of the bus: "
                   "spawn, connect [URL], serve [PORT] (until interrupted), save PATH.rrd (as on run)")
    p.add_argument("--stream", default="replay", help="bus namespace for republishing")
    p.add_argument("--listen", action="append", help="Zenoh endpoint to listen on (republish)")
    p.add_argument("--connect", action="append", help="Zenoh endpoint to connect to (republish)")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def run(args: argparse.Namespace) -> int:
    from services.commands.errors import UsageError
    from common.record.reader import RecordingError
    from common.record.retrack import offline_retrack

    if args.speed is not None and args.speed <= 0:
        raise UsageError("--speed must be positive")
    if args.start < 0 or (args.end is not None and args.end <= args.start):
        raise UsageError(f"--start {args.start:g} and --end {args.end:g}: need 0 <= start < end"
                         if args.end is not None else f"--start {args.start:g}: must be at least 0")
    if args.loop < 0:
        raise UsageError("--loop N: N must be at least 1 (or --loop alone: until interrupted)")
    if (args.retrack or args.offline) and (args.topics or args.start or args.end is not None or args.loop != 1):
        raise UsageError("--topics, --start, --end and --loop apply to republishing, not to --retrack or --offline")
    if args.rerun:
        if args.retrack or args.offline or args.topics or args.start or args.end is not None or args.loop != 1:
            raise UsageError("--rerun sends the whole recording to Rerun: without --retrack, --offline, "
                             "--topics, --start, --end or --loop")
        return _to_rerun(args)
    try:
        if args.offline:
            out = {"mode": "offline", **offline_retrack(args.mcap)}
        elif args.retrack:
            from services.replay import retrack

            out = {"mode": "retrack", **retrack(args.mcap)}
        else:
            from services.bus import BusConfig
            from services.replay import republish

            import sys

            from services.launcher import free_ports

            listen = args.listen if args.listen is not None else ([] if args.connect else
                                                                   [f"tcp/127.0.0.1:{free_ports(1)[0]}"])
            bus = BusConfig(stream=args.stream, listen=listen, connect=args.connect or [])

            def ready() -> None:
                where = ", ".join([f"listening on {e}" for e in listen] + [f"connected to {e}" for e in args.connect or []])
                print(f"replaying {args.mcap} on polartrack/{args.stream}/** ({where}); subscribers: "
                      f"--connect {listen[0] if listen else (args.connect or [''])[0]} --stream {args.stream}",
                      file=sys.stderr if args.json else sys.stdout, flush=True)

            out = {"mode": "republish", **republish(args.mcap, bus, None if args.max else args.speed,
                                                    topics=args.topics, start_s=args.start, end_s=args.end,
                                                    loops=args.loop, on_ready=ready)}
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
        passes = f" in {out['passes']} passes" if out.get("passes", 1) > 1 else ""
        print(f"republished {out['messages']} messages on {out['topics']} topics{passes}")
        if out.get("topics_not_found"):
            print("no message on: " + ", ".join(out["topics_not_found"]))
    if not args.json and out.get("malformed"):
        print("malformed messages skipped: " + ", ".join(f"{k} {v}" for k, v in sorted(out["malformed"].items())))
    return 0 if out.get("identical", True) else 1


def _to_rerun(args: argparse.Namespace) -> int:
    """``replay FILE --rerun MODE``: the recording converted as ``view`` does and streamed live."""
    import tempfile
    import time
    from pathlib import Path

    from services.commands.errors import UsageError
    from services.commands.run import rerun_options
    from common.record.rerun import mcap_to_rrd

    live = rerun_options(args.rerun)
    with tempfile.TemporaryDirectory(prefix="polartrack-replay-") as tmp:
        rrd = live.get("out") or str(Path(tmp) / "replay.rrd")
        if "rerun_serve_port" in live:
            print(f"serving {args.mcap} to Rerun viewers: rerun --connect "
                  f"rerun+http://127.0.0.1:{live['rerun_serve_port']}/proxy (Ctrl-C to stop)", flush=True)
        def serve_until_interrupted() -> None:
            try:
                while True:
                    time.sleep(1.0)
            except KeyboardInterrupt:
                pass

        try:
            out = mcap_to_rrd(args.mcap, rrd, spawn=bool(live.get("spawn")), connect=live.get("rerun_connect"),
                              serve_port=live.get("rerun_serve_port"),
                              before_close=serve_until_interrupted if "rerun_serve_port" in live else None)
        except (ValueError, OSError) as exc:
            raise UsageError(str(exc).splitlines()[0][:300]) from None
    if args.json:
        print(json.dumps({"mode": "rerun", **{k: v for k, v in out.items() if k != "rrd"},
                          **({"rrd": live["out"]} if "out" in live else {})}))
    else:
        print(f"sent {out['messages']} messages ({out['images']} frame images) to Rerun"
              + (f"; saved {live['out']}" if "out" in live else ""))
    return 0
