"""Fingerprints of the estimates, to show that a change of structure changed no number.

    uv run python tools/estimate_hashes.py [--data ../shared/data] [--frames 60] [--json]

Runs, each from the first true box with the default settings of its source:
- ``track synthetic:3`` (in-process; the CSV), with each single-target filter (RBPF, SIR, ML),
- ``track`` on a real sequence with the real-footage profile (``uavdt-S0310``, when --data has it),
- ``track people:1`` with the multi-target filter (EPMCMC + ELPDA),
- ``run synthetic:3`` (the multi-process pipeline; the recorded estimates), then
  ``replay --offline`` and ``replay --retrack`` on its MCAP (each must report every estimate equal),
and prints a SHA-256 (first 16 hex digits) of each run's estimates: the CSV's bytes, or the
recorded estimates' fields that do not depend on timing. Run it before and after a change.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import json
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()[:16]


def _cli(argv: list[str]) -> tuple[int, str]:
    from services.cli import main

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        rc = main(argv)
    return rc, out.getvalue()


def _track(source: str, frames: int, tmp: Path, *extra: str) -> str:
    csv = tmp / f"{abs(hash(source))}.csv"
    rc, _ = _cli(["track", source, "--frames", str(frames), "--out", str(csv), "--no-progress", *extra])
    if rc != 0:
        raise SystemExit(f"track {source} failed ({rc})")
    return _digest(csv.read_bytes())


def _recorded(path: str) -> str:
    try:
        from common.record.reader import read_recording
    except ImportError:  # the layout before common/record/ (to fingerprint older commits)
        from common.recording import read_recording

    rec = read_recording(path, topics=["track/estimate"])
    rows = [(e.frame_index, e.time_s, e.observed, e.x, e.y, e.theta_deg, e.p_visible, e.world_x, e.world_y, e.vx, e.vy,
             e.mmse_x, e.mmse_y, e.n_eff, e.resampled, e.w, e.h, e.reacquired)
            for e in sorted(rec.decoded("track/estimate"), key=lambda e: e.frame_index)]
    return _digest(repr(rows).encode())


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    out: dict[str, str] = {}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        out["track synthetic:3"] = _track("synthetic:3", args.frames, tmp)
        for name in ("sir", "ml"):
            out[f"track synthetic:3 --filter {name}"] = _track("synthetic:3", args.frames, tmp, "--filter", name)
        real = Path(args.data) / "uavdt-S0310"
        if real.is_dir():
            out["track uavdt-S0310 (real-footage profile)"] = _track(str(real), args.frames, tmp)
        out["track people:1 --filter epmcmc-elpda"] = _track("people:1", min(args.frames, 30), tmp,
                                                             "--filter", "epmcmc-elpda", "--particles", "40")
        rc, text = _cli(["run", "--source", "synthetic:3", "--frames", str(args.frames), "--no-viewer",
                         "--out-dir", str(tmp / "run"), "--json", "--no-progress"])
        if rc != 0:
            raise SystemExit(f"run failed ({rc}): {text[-500:]}")
        mcap = json.loads(text)["mcap"]
        out["run synthetic:3"] = _recorded(mcap)
        for mode in ("--offline", "--retrack"):
            rc, text = _cli(["replay", mcap, mode, "--json"])
            report = json.loads(text)
            out[f"replay {mode}"] = (f"{'identical' if report['identical'] and rc == 0 else 'DIFFERENT'}: "
                                     f"{report['compared']} estimates compared")
    if args.json:
        print(json.dumps(out, indent=1))
    else:
        for k, v in out.items():
            print(f"{k:45s} {v}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
