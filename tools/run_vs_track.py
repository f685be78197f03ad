"""Compare a recording of ``polartrack run`` with ``polartrack track`` on the same frames.

Re-tracks the recorded source in-process (``common.single_target.runner.track_frames``, the code behind
``polartrack track``) with the recorded initial box and settings, over the frames the recording
has estimates for, and compares every estimate field by field, bit for bit
(``common.record.reader.compare_estimates``). Optionally also checks a ``polartrack track`` CSV
against the recorded estimates at the CSV's precision.

Multi-target recordings (``--filter epmcmc-elpda|epmcmc-pda|jpda-pf``) are re-tracked with
``common.multitarget.runner.track_frames`` (the code behind ``polartrack track`` with those filters)
on the recorded source (the scene's length from the recorded ``total_frames``) and compared
message by message; the CSV is then ``frame,target,part,x,y``.

Run: ``uv run python tools/run_vs_track.py RECORDING.mcap [--csv TRACK.csv]``.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys



def main(argv: list[str] | None = None) -> int:
    from common.msgs.convert import estimate_msg
    from common.record.retrack import compare_estimates
    from common.record.reader import read_recording
    from common.single_target.runner import track_frames
    from common.settings import TrackerSettings
    from common.sources import open_source

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("mcap")
    p.add_argument("--csv", help="a polartrack track CSV of the same source to check too")
    args = p.parse_args(argv)
    rec = read_recording(args.mcap)
    run = rec.run
    if run.get("multi_json"):
        return _multi(rec, args.csv)
    settings = TrackerSettings.model_validate_json(run["settings_json"])
    recorded = sorted(rec.decoded("track/estimate"), key=lambda e: e.frame_index)
    n = recorded[-1].frame_index + 1
    new = [estimate_msg(f.index, 0, s, settings.filter)
           for f, s in track_frames(open_source(run["source"], n_frames=n), tuple(json.loads(run["init_box"])), settings)
           if f.index <= recorded[-1].frame_index]
    out = compare_estimates(recorded, new)
    if args.csv:
        with open(args.csv) as fh:
            rows = {int(r["frame"]): r for r in csv.DictReader(fh)}
        diffs = [max(abs(float(rows[e.frame_index][k]) - v) for k, v in (("x", e.x), ("y", e.y),
                 ("theta_deg", e.theta_deg), ("p_visible", e.p_visible)))
                 for e in recorded if e.frame_index in rows]
        out["csv_rows_compared"] = len(diffs)
        out["csv_max_abs_diff"] = float(max(diffs)) if diffs else None
        out["csv_within_rounding"] = bool(diffs) and all(d <= 5e-4 + 1e-9 for d in diffs)
    print(json.dumps(out))
    return 0 if out["identical"] and out.get("csv_within_rounding", True) else 1


def _multi(rec, csv_path: str | None) -> int:
    from common.msgs.convert import msg_positions, multi_estimate_msg
    from common.multitarget.runner import MultiRun, track_frames
    from common.record.retrack import compare_multi
    from common.sources import open_source

    mr = MultiRun.from_json(rec.run["multi_json"])
    recorded = sorted(rec.decoded("track/multi_estimate"), key=lambda e: e.frame_index)
    total = next((int(i.total_frames) for i in rec.decoded("frame/info") if i.total_frames), None)
    last = recorded[-1].frame_index
    src = open_source(rec.run["source"], n_frames=total if total else last + 1)
    new = []
    for f, s in track_frames(src, mr):
        if f.index > last:
            break
        new.append(multi_estimate_msg(f.index, s, mr))
    out = compare_multi(recorded, new)
    if csv_path:
        with open(csv_path) as fh:
            rows = {(int(r["frame"]), int(r["target"]), r["part"]): r for r in csv.DictReader(fh)}
        diffs = []
        for e in recorded:
            pos = msg_positions(e)
            for t in range(e.targets):
                for p, name in enumerate(e.part_names):
                    r = rows.get((e.frame_index, t, name))
                    if r is not None:
                        diffs.append(max(abs(float(r["x"]) - pos[t, p, 0]), abs(float(r["y"]) - pos[t, p, 1])))
        out["csv_rows_compared"] = len(diffs)
        out["csv_max_abs_diff"] = float(max(diffs)) if diffs else None
        out["csv_within_rounding"] = bool(diffs) and all(d <= 5e-3 + 1e-9 for d in diffs)
    print(json.dumps(out))
    return 0 if out["identical"] and out.get("csv_within_rounding", True) else 1


if __name__ == "__main__":
    sys.exit(main())
