"""Convert a run's MCAP recording to a Rerun recording (.rrd) and optionally open the viewer.

Reads every message the recorder wrote (frames, frame infos with ground truth, estimates,
particle clouds, multi-target estimates with their skeletons, template, run config) and logs it on the ``frame`` and ``capture_time``
timelines: the frame with the particles (coloured by weight), the MAP estimate, its track and the
truth overlaid; the ground plane; and time series of the posterior visibility, centre error,
orientation, speed and N_eff. Prints the path of the .rrd written. A recording cut short (a
recorder killed mid-run) is converted up to where it ends.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

HELP = "convert a run's MCAP recording to a Rerun .rrd (and open the viewer)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("mcap", metavar="FILE.mcap", help="recording written by the recorder service")
    p.add_argument("--out", metavar="FILE.rrd", help="Rerun recording to write (default: FILE.rrd beside the input)")
    p.add_argument("--spawn", action="store_true", help="open the Rerun viewer on the result (needs a display)")


def run(args: argparse.Namespace) -> int:
    from services.commands.errors import UsageError
    from common.record.rerun import MCAP_MAGIC, display_available, mcap_to_rrd, open_viewer

    src = Path(args.mcap)
    if not src.exists():
        raise UsageError(f"{src}: no such file")
    if not src.is_file():
        raise UsageError(f"{src}: not a file")
    out = Path(args.out) if args.out else src.with_suffix(".rrd")
    if out.suffix != ".rrd":
        raise UsageError(f"--out {out}: must be a .rrd file name")
    if out.resolve() == src.resolve():
        raise UsageError(f"--out {out}: would overwrite the input")
    try:
        with open(src, "rb") as fh:
            magic = fh.read(len(MCAP_MAGIC))
    except OSError as exc:
        raise UsageError(f"{src}: {exc.strerror or exc}") from None
    if magic != MCAP_MAGIC:
        raise UsageError(f"{src}: not an MCAP file")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        with open(out, "ab"):
            pass
    except OSError as exc:
        raise UsageError(f"--out {out}: cannot write ({exc.strerror or exc})") from None
    try:
        stats = mcap_to_rrd(src, out)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    except (OSError, RuntimeError) as exc:  # rerun reports a file it cannot create as RuntimeError
        raise UsageError(f"--out {out}: cannot write ({exc})") from None
    summary = (f"{stats['images']} frames, {stats['estimates']} estimates, {stats['clouds']} particle clouds"
               + (f", {stats['multi_estimates']} multi-target estimates" if stats.get("multi_estimates") else "")
               + (f", {stats['malformed']} malformed messages skipped" if stats["malformed"] else "")
               + (" (recording ended mid-record: converted up to there)" if stats["truncated"] else ""))
    print(summary, file=sys.stderr)
    print(out)
    if args.spawn:
        if not display_available() or not open_viewer(out):
            print(f"no display available: open it elsewhere with `rerun {out}`", file=sys.stderr)
    return 0
