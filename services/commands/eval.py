"""Track and score against the ground truth: precision20, auc50, mean error, frame rate.

Several filters (``--filter rbpf,sir,ml``) run side by side on the same frames, each with its
own template, frame cache and generator, exactly as ``polartrack track`` would run them alone.
Writes two PNGs: the centre error per frame of each filter (Pang Fig. 9) and the posterior
visibility (Pang Fig. 6c), with the frames where the target is hidden shaded.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from services.commands.common_args import add_tracking_arguments, open_checked, settings_for, truth_centre

HELP = "track and score against ground truth (precision, AUC, error plots)"
FILTERS = ("rbpf", "sir", "ml")


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_tracking_arguments(p, multi_filter=True)
    p.add_argument("--out-dir", metavar="DIR", help="where to write the PNGs (default recordings/eval-SOURCE)")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def evaluate(source, init, settings_by_name: dict, progress: bool = False) -> dict:
    """Run every filter in lockstep over ``source``; per-filter arrays and timings."""
    from tqdm import tqdm

    from common.single_target.runner import Tracker

    trackers: dict = {}
    est = {k: [] for k in settings_by_name}
    pvis = {k: [] for k in settings_by_name}
    elapsed = {k: 0.0 for k in settings_by_name}
    truth, visible, vfrac = [], [], []
    total = len(source) if not source.live else None
    for frame in tqdm(source, total=total, unit="frame", disable=not progress, file=sys.stderr, desc=source.name):
        for name, st in settings_by_name.items():
            t0 = time.perf_counter()
            if name not in trackers:
                trackers[name] = Tracker.start(frame, init, st)
            state = trackers[name].step(frame)
            elapsed[name] += time.perf_counter() - t0
            est[name].append(state.centre)  # the box's centre: the MAP's unless measured apart
            pvis[name].append(state.p_visible)
        truth.append(truth_centre(source, frame))
        t = frame.truth
        visible.append(t is not None and t.box is not None)
        vfrac.append(np.nan if t is None or t.visible_fraction is None else t.visible_fraction)
    return {"est": {k: np.asarray(v) for k, v in est.items()}, "p_visible": {k: np.asarray(v) for k, v in pvis.items()},
            "elapsed": elapsed, "truth": np.asarray(truth, float), "visible": np.asarray(visible),
            "visible_fraction": np.asarray(vfrac, float)}


def plot_errors(run: dict, errors: dict, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    hidden = ~run["visible"]
    fig, axes = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
    frames = np.arange(len(hidden))
    for ax in axes:
        ax.fill_between(frames, 0, 1, where=hidden, transform=ax.get_xaxis_transform(), color="0.85",
                        label="target hidden")
    for name, e in errors.items():
        axes[0].plot(frames, e, label=name)
    axes[0].set_ylabel("centre error (px)")
    axes[0].set_yscale("symlog", linthresh=10)
    axes[0].axhline(20, color="k", lw=0.5, ls="--")
    axes[0].legend(loc="upper left")
    axes[0].set_title(title)
    for name, p in run["p_visible"].items():
        axes[1].plot(frames, p, label=name)
    if np.isfinite(run["visible_fraction"]).any():
        axes[1].plot(frames, run["visible_fraction"], "k:", label="true visible fraction")
    axes[1].set_ylabel("p(V=1 | Z)")
    axes[1].set_xlabel("frame")
    axes[1].set_ylim(-0.05, 1.05)
    axes[1].legend(loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def run(args: argparse.Namespace) -> int:
    from services.commands.errors import UsageError
    from common.evaluation import centre_errors, score_run
    from common.single_target.runner import InitError
    from common.sources import SourceError

    names = [n.strip() for n in args.filter.split(",") if n.strip()]
    bad = [n for n in names if n not in FILTERS]
    if bad or not names:
        raise UsageError(f"--filter {args.filter}: unknown filter(s) {bad}; choose from {', '.join(FILTERS)}")
    source, init = open_checked(args)
    if not source.has_truth:
        raise UsageError(f"{args.source}: eval needs ground truth (a UAV123-format folder or synthetic[:SEED])")
    settings = {n: settings_for(args, source, n) for n in names}
    try:
        run_ = evaluate(source, init, settings, progress=not args.no_progress)
    except (InitError, SourceError) as exc:
        raise UsageError(str(exc)) from None
    out_dir = Path(args.out_dir) if args.out_dir else Path("recordings") / f"eval-{source.name}"
    out_dir.mkdir(parents=True, exist_ok=True)
    errors = {n: centre_errors(run_["est"][n], run_["truth"]) for n in names}
    results = {}
    for n in names:
        sc = score_run(errors[n], run_["visible"]).as_dict()
        sc["fps"] = round(len(run_["visible"]) / run_["elapsed"][n], 2)
        results[n] = sc
    plot = out_dir / "errors.png"
    plot_errors(run_, errors, plot, f"{source.name}: centre error and posterior visibility")
    summary = {"source": args.source, "frames": int(len(run_["visible"])), **results[names[0]],
               "filters": results, "plot": str(plot)}
    if args.json:
        print(json.dumps(summary))
    else:
        from services.commands.tables import print_table

        print_table(f"{source.name}: {summary['frames']} frames, plot {plot}",
                    ["filter", "precision20", "auc50", "mean_err", "fps"],
                    [[n, f"{r['precision20']:.3f}", f"{r['auc50']:.3f}", f"{r['mean_err']:.2f}", f"{r['fps']:.1f}"]
                     for n, r in results.items()])
    return 0
