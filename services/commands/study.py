"""Reproduce the papers' claims on the synthetic scene over many seeds.

For each scene seed, on the same frames: the RBPF (Pang, 200 particles; and with the jump
component of ``common.settings.RECOVERY_PROPOSAL``), the SIR filter
(Nelson, 300 particles) and the windowed ML search at thresholds 0.5, 0.6 and 0.7. Reports, per
method, in how many seeds the track survives the full smoke occlusion (centre error back under
10 px within 10 frames of re-emergence, i.e. the first frame after the smoke with at least half
the car visible, and staying under 10 px for 10 frames), the mean precision20 and mean error,
and plots the median error per frame over seeds (Pang Fig. 9).
"""

from __future__ import annotations

import argparse
import json
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from services.commands.common_args import positive_int

HELP = "reproduce the papers' claims on the synthetic scene over many seeds"

METHODS = {  # name: (filter, profile_for keywords, updates of that filter's config)
    "rbpf": ("rbpf", {"particles": 200}, {}),
    "rbpf+jumps": ("rbpf", {"particles": 200}, "RECOVERY_PROPOSAL"),
    "sir": ("sir", {"particles": 300}, {}),
    "ml@0.5": ("ml", {}, {"threshold": 0.5}),
    "ml@0.6": ("ml", {}, {"threshold": 0.6}),
    "ml@0.7": ("ml", {}, {"threshold": 0.7}),
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seeds", type=int, default=20, help="scene seeds 0..N-1 (default 20)")
    p.add_argument("--frames", type=positive_int, help="frames per scene (default: the scene's length)")
    p.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1), help="processes")
    p.add_argument("--out-dir", default="recordings/study", help="where to write the PNG and JSON")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def run_seed(seed: int, frames: int | None) -> dict:
    from services.commands.eval import evaluate
    from common.evaluation import centre_errors, recovered, reemergence_frame, score_run
    from common.settings import RECOVERY_PROPOSAL, profile_for
    from common.sources import SyntheticSource

    source = SyntheticSource(seed=seed, n_frames=frames)
    init = source.frame(0).truth.box
    settings = {}
    for name, (filt, kw, upd) in METHODS.items():
        st = profile_for(source, filter=filt, seed=seed, **kw)
        upd = RECOVERY_PROPOSAL if upd == "RECOVERY_PROPOSAL" else upd
        if upd:
            st = st.model_copy(update={filt: getattr(st, filt).model_copy(update=upd)})
        settings[name] = st
    run = evaluate(source, init, settings)
    smoke = source.scene.events.get("smoke")
    re = reemergence_frame(run["visible_fraction"], smoke) if smoke else None
    out = {"seed": seed, "reemergence": re, "smoke": smoke, "methods": {}}
    for name in settings:
        e = centre_errors(run["est"][name], run["truth"])
        sc = score_run(e, run["visible"])
        out["methods"][name] = {"recovered": recovered(e, re), "precision20": sc.precision20,
                                "mean_err": sc.mean_err, "errors": e.tolist(),
                                "ms_per_frame": 1e3 * run["elapsed"][name] / len(e)}
    return out


def summarise(results: list[dict]) -> dict:
    table = {}
    for name in METHODS:
        rows = [r["methods"][name] for r in results]
        table[name] = {
            "recovered": int(sum(r["recovered"] for r in rows)),
            "seeds": len(rows),
            "precision20": round(float(np.mean([r["precision20"] for r in rows])), 4),
            "mean_err": round(float(np.median([r["mean_err"] for r in rows])), 3),
            "ms_per_frame": round(float(np.mean([r["ms_per_frame"] for r in rows])), 2),
        }
    return table


def plot(results: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(11, 4.5))
    smoke = results[0]["smoke"]
    if smoke:
        ax.axvspan(smoke[0], smoke[1], color="0.85", label="smoke (full occlusion, seed 0)")
    for name in METHODS:
        n = min(len(r["methods"][name]["errors"]) for r in results)
        e = np.array([r["methods"][name]["errors"][:n] for r in results])
        ax.plot(np.arange(n), np.median(e, axis=0), label=f"{name} (median of {len(results)} seeds)")
    ax.set_yscale("symlog", linthresh=10)
    ax.axhline(10, color="k", lw=0.5, ls="--")
    ax.set_xlabel("frame")
    ax.set_ylabel("centre error (px)")
    ax.set_title("Synthetic scene: RBPF vs SIR vs windowed ML (Pang Fig. 9)")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def run(args: argparse.Namespace) -> int:
    from services.commands.errors import UsageError

    if args.seeds < 1 or args.workers < 1:
        raise UsageError("--seeds and --workers must be at least 1")
    out_dir = Path(args.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    seeds = list(range(args.seeds))
    if args.workers == 1:
        results = [run_seed(s, args.frames) for s in seeds]
    else:
        with ProcessPoolExecutor(args.workers) as pool:
            results = list(pool.map(run_seed, seeds, [args.frames] * len(seeds)))
    table = summarise(results)
    png = out_dir / "errors.png"
    plot(results, png)
    per_seed = [{"seed": r["seed"], "reemergence": r["reemergence"],
                 **{n: {"recovered": m["recovered"], "precision20": round(m["precision20"], 4)}
                    for n, m in r["methods"].items()}} for r in results]
    summary = {"seeds": len(seeds), "methods": table, "per_seed": per_seed, "plot": str(png)}
    (out_dir / "study.json").write_text(json.dumps(summary, indent=1))
    if args.json:
        print(json.dumps(summary))
    else:
        from services.commands.tables import print_table

        print_table(f"{len(seeds)} seeds; plot {png}", ["method", "recovered", "precision20", "median err", "ms/frame"],
                    [[n, f"{r['recovered']}/{r['seeds']}", f"{r['precision20']:.3f}", f"{r['mean_err']:.2f}",
                      f"{r['ms_per_frame']:.1f}"] for n, r in table.items()])
    return 0
