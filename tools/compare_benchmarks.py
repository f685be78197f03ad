"""Compare two ``polartrack benchmark --json`` results seed by seed: what a change did to each sequence.

The notes on real footage (docs/real-footage.md) report every change as before -> after per
sequence, with how many filter seeds went up and down: a particle filter's outcome on a sequence is
a coin flip per seed on some of them, so a change that only moves which seeds lose shows as seeds up
and down at the same mean. This prints, for each sequence in both results (the tracker's
``precision20`` / ``success_auc``): before, after, the seeds up, down and identical (precision20, to
1e-9), and the seeds that moved; then the mean over the sequences both hold.

    uv run python tools/compare_benchmarks.py before/benchmark.json after/benchmark.json
    uv run python tools/compare_benchmarks.py dev.json,car16.json after.json --tracker polartrack --json

Several results on one side, joined by commas, are read as one (a later file's sequence replaces an
earlier one's). Seeds are matched by their number; a seed run on one side only is not counted.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

SAME = 1e-9
"""Two precision20 figures closer than this are the same run's."""


class NotABenchmark(ValueError):
    """A file that is not a ``polartrack benchmark --json`` result."""


def load(paths: list[str], tracker: str) -> dict[str, dict]:
    """{sequence: the tracker's figures} from one or more benchmark results (later files win)."""
    out: dict[str, dict] = {}
    for p in paths:
        try:
            data = json.loads(Path(p).read_text())
            sequences = data["sequences"]
            for s in sequences:
                if tracker in s["trackers"]:
                    out[s["sequence"]] = s["trackers"][tracker]
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise NotABenchmark(f"{p}: not a `polartrack benchmark --json` result ({type(e).__name__}: {e})") from e
    return out


def _seeds(figures: dict) -> dict[int, float]:
    """{seed: precision20}; a single run without per-seed figures counts as seed 0."""
    seeds = figures.get("seeds")
    if not seeds:
        return {0: float(figures["precision20"])}
    return {int(s["seed"]): float(s["precision20"]) for s in seeds}


def compare(before: dict[str, dict], after: dict[str, dict]) -> dict:
    """Per sequence held by both, before and after (precision20, success AUC), the seeds up, down and
    identical and the seeds that moved ({seed: [before, after]}); the means over those sequences; and
    the sequences only one side holds."""
    rows = []
    for name in [n for n in before if n in after]:
        b, a = before[name], after[name]
        sb, sa = _seeds(b), _seeds(a)
        common = sorted(set(sb) & set(sa))
        moved = {s: [sb[s], sa[s]] for s in common if abs(sa[s] - sb[s]) > SAME}
        rows.append({
            "sequence": name,
            "before": [float(b["precision20"]), float(b["success_auc"])],
            "after": [float(a["precision20"]), float(a["success_auc"])],
            "up": sum(1 for s in moved if moved[s][1] > moved[s][0]),
            "down": sum(1 for s in moved if moved[s][1] < moved[s][0]),
            "same": len(common) - len(moved),
            "moved": moved,
        })
    n = len(rows)
    mean = {side: [sum(r[side][i] for r in rows) / n for i in (0, 1)] if n else None for side in ("before", "after")}
    return {"sequences": rows, "mean": mean,
            "only_before": sorted(set(before) - set(after)), "only_after": sorted(set(after) - set(before))}


def _print(result: dict) -> None:
    for r in result["sequences"]:
        (pb, sb), (pa, sa) = r["before"], r["after"]
        moved = ", ".join(f"{s}: {x:.3f} -> {y:.3f}" for s, (x, y) in sorted(r["moved"].items()))
        print(f"{r['sequence']:34s} {pb:.3f} / {sb:.3f} -> {pa:.3f} / {sa:.3f}   "
              f"up {r['up']}, down {r['down']}, same {r['same']}" + (f"   ({moved})" if moved else ""))
    m = result["mean"]
    if m["before"] is not None:
        print(f"{'mean over ' + str(len(result['sequences'])):34s} {m['before'][0]:.3f} / {m['before'][1]:.3f} -> "
              f"{m['after'][0]:.3f} / {m['after'][1]:.3f}")
    for side in ("only_before", "only_after"):
        if result[side]:
            print(f"{side.replace('_', ' ')} (not compared): {', '.join(result[side])}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before", help="benchmark JSON (several joined by commas)")
    ap.add_argument("after", help="benchmark JSON (several joined by commas)")
    ap.add_argument("--tracker", default="polartrack", help="whose figures to compare (default polartrack)")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    a = ap.parse_args(argv)
    try:
        result = compare(load(a.before.split(","), a.tracker), load(a.after.split(","), a.tracker))
    except NotABenchmark as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if a.json:
        print(json.dumps(result))
    else:
        _print(result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
