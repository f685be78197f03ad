"""Reproduce Bhaskar and Mihaylova (2011)'s comparisons on the synthetic people scene.

Main comparison (paper Table 1, Figs. 5-6): on scene seeds 0..N-1 (``--first-seed`` S: S..S+N-1) with ``--people`` walkers, the
proposed EPMCMC + ELPDA, the EPMCMC + PDA baseline and the JPDA particle filter run side by side on
the same frames; reported per method: combined RMSE (mean over targets and seeds, pixels, all parts
of the body model), time per frame, identities kept at the end of the run, MOTA / IDF1 / identity
switches (motmetrics) and OSPA of the torso centres; and ``elpda_beats_pda``, the fraction of seeds
where EPMCMC + ELPDA's combined RMSE is lower than EPMCMC + PDA's. With ``--runs K`` every scene is
tracked K times with independent filter seeds (the paper's Monte Carlo cycles; section 4.1 uses
100) and a method's RMSE on a scene is the mean over its runs; ``elpda_beats_pda`` compares those
means, ``elpda_beats_pda_runs`` the single runs (run r of ELPDA against run r of PDA), and a
scene's identities count as kept when every run kept them (``identities_kept_runs``: the share of
single runs that did). ``elpda_vs_pda`` classifies the seeds by the paired difference ELPDA - PDA over
the runs and its 95 % Student-t interval (:func:`~common.multitarget.metrics.paired_difference`): the
shares of seeds where ELPDA is lower, higher, or undecided within the Monte Carlo noise (every seed
is undecided with one run); ``per_seed`` has each seed's difference, half-width and verdict.

Sweeps (paper Figs. 7-9) for EPMCMC + ELPDA and EPMCMC + PDA on ``--sweep-seeds`` seeds: combined
RMSE against the number of targets (1-5), the number of parts (1, 2, 6, 10) and the gate size.

``--init boxes`` starts every filter from the people's boxes alone (a standing body in each), as
``polartrack run`` and ``track`` do, instead of the first frame's part positions.

Writes a table (rich), PNGs and ``eval-multi.json`` under ``--out-dir``.
"""

from __future__ import annotations

import argparse
import json
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

HELP = "multi-target articulated tracking on the synthetic people scene: EPMCMC+ELPDA vs baselines"

SWEEP_METHODS = ("epmcmc-elpda", "epmcmc-pda")
SWEEPS = {"targets": [1, 2, 3, 4, 5], "parts": [1, 2, 6, 10], "gate": [5.0, 10.0, 15.0, 20.0, 25.0]}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seeds", type=int, default=10, help="how many scene seeds the main comparison runs (default 10)")
    p.add_argument("--first-seed", type=int, default=0,
                   help="the main comparison's first scene seed (default 0: seeds 0..N-1; the defaults were tuned on "
                   "seeds 100-119)")
    p.add_argument("--people", type=int, default=3, help="people in the main comparison's scenes, 1-5 (default 3)")
    p.add_argument("--frames", type=int, default=80, help="frames per scene (default 80)")
    p.add_argument("--particles", type=int, help="particles per target (default: the config's 500, the paper's)")
    p.add_argument("--parts", type=int, default=10, choices=[1, 2, 6, 10], help="body-model parts (default 10)")
    p.add_argument("--gate", type=float, default=15.0, help="validation gate size, px (default 15, the paper's)")
    p.add_argument("--level", default="structure", choices=["structure", "part"],
                   help="association unit of every method (GateConfig.level): the whole pictorial structure, "
                   "located by its torso (default; the paper's section 3.2), or every part on its own")
    p.add_argument("--sweeps", default="targets,parts,gate", metavar="S[,S...]",
                   help="which sweeps to run: targets, parts, gate (comma separated; 'none' for none)")
    p.add_argument("--sweep-seeds", type=int, default=3, help="scene seeds per sweep point (default 3)")
    p.add_argument("--runs", type=int, default=3,
                   help="Monte Carlo runs (independent filter seeds) per scene seed of the main comparison; "
                   "a method's RMSE on a scene is the mean over them (default 3: one run's RMSE spreads "
                   "between filter seeds about as much as the methods differ, so a single run's winner "
                   "is largely chance)")
    p.add_argument("--init", default="truth", choices=["truth", "boxes"],
                   help="how every filter starts: from the first frame's part positions (default; the paper starts "
                   "from a pictorial-structure detector), or from the people's boxes only, as `polartrack run` does")
    p.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1), help="processes")
    p.add_argument("--out-dir", default="recordings/eval-multi", help="where to write the PNGs and JSON")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def _configs(methods, particles: int | None, parts: int, gate: float, level: str = "structure") -> dict:
    from common.multitarget import method_config
    from common.multitarget.config import GateConfig

    upd = {"n_parts": parts, "gate": GateConfig(gate_size=gate, level=level)}
    if particles is not None:
        upd["n_particles"] = particles
    return {m: method_config(m, **upd) for m in methods}


def _job(job: tuple) -> dict:
    from common.multitarget.experiment import evaluate_scene
    from common.scene.people import PeopleSceneConfig

    kind, value, seed, people, frames, particles, parts, gate, level, methods, runs, init = job
    res = evaluate_scene(PeopleSceneConfig(n_people=people, n_frames=frames), seed,
                         _configs(methods, particles, parts, gate, level), runs=runs, init=init)
    res["kind"], res["value"] = kind, value
    return res


def _summary(results: list[dict], methods) -> dict:
    out = {}
    for m in methods:
        rows = [r["methods"][m] for r in results]
        out[m] = {
            "rmse": round(float(np.mean([r["rmse"] for r in rows])), 3),
            "rmse_std": round(float(np.std([r["rmse"] for r in rows])), 3),
            "rmse_per_target": np.mean([r["rmse_per_target"] for r in rows], axis=0).round(3).tolist(),
            "ms_per_frame": round(float(np.mean([r["ms_per_frame"] for r in rows])), 2),
            "identities_kept": round(float(np.mean([r["identities_kept"] for r in rows])), 3),
            "identities_kept_runs": round(float(np.mean([k for r in rows for k in r["identities_kept_runs"]])), 3),
            "mota": round(float(np.mean([r["mota"] for r in rows])), 4),
            "idf1": round(float(np.mean([r["idf1"] for r in rows])), 4),
            "id_switches": int(sum(r["id_switches"] for r in rows)),
            "ospa": round(float(np.mean([r["ospa"] for r in rows])), 3),
        }
    return out


def _figure(path: Path, size, xlabel: str, ylabel: str, title: str, draw) -> str:
    """One PNG: ``draw(ax)`` plots, then labels, legend, save."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=size)
    draw(ax)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return str(path)


def _plots(main: list[dict], sweeps: dict, out_dir: Path) -> list[str]:
    from common.multitarget import METHODS

    paths = []
    # Figs. 5-6: combined RMSE of target 1 and target 2 over the runs (the paper's Monte Carlo cycles)
    for t in range(min(2, len(main[0]["methods"]["epmcmc-elpda"]["rmse_per_target"]))):
        def draw(ax, t=t):
            for m in SWEEP_METHODS:
                ax.plot([r["seed"] for r in main], [r["methods"][m]["rmse_per_target"][t] for r in main], "o-", label=m)

        paths.append(_figure(out_dir / f"rmse_target{t + 1}.png", (7, 3.5), "scene seed (Monte Carlo run)",
                             "combined RMSE (px)", f"Combined RMSE of target {t + 1} (paper Fig. {5 + t})", draw))
    r0 = main[0]

    def draw_frames(ax):
        for c in r0["crossings"]:
            ax.axvline(c[2], color="0.8", lw=1)
        for m in METHODS:
            ax.plot(np.array(r0["methods"][m]["error_per_frame"]).mean(axis=1), label=m)

    paths.append(_figure(out_dir / "error_per_frame.png", (9, 3.8), "frame (grey: crossings)", "mean part error (px)",
                         f"Seed {r0['seed']}: error per frame, mean over targets and parts", draw_frames))
    titles = {"targets": ("number of targets", 7), "parts": ("number of parts", 8), "gate": ("gate size (px)", 9)}
    for kind, table in sweeps.items():
        def draw_sweep(ax, table=table):
            for m in SWEEP_METHODS:
                xs = sorted(table[m], key=float)
                ax.plot([float(x) for x in xs], [table[m][x] for x in xs], "o-", label=m)

        label, fig_no = titles[kind]
        paths.append(_figure(out_dir / f"sweep_{kind}.png", (6, 3.5), label, "combined RMSE (px)",
                             f"Combined RMSE vs {label} (paper Fig. {fig_no})", draw_sweep))
    return paths


def _print_table(summary: dict, wins: float, n: int, sweeps: dict, plots: list[str], runs: int = 1,
                 wins_runs: float | None = None, init: str = "truth", first_seed: int = 0,
                 vs: dict | None = None) -> None:
    from rich.console import Console
    from rich.table import Table

    con = Console()
    start = "first-frame parts" if init == "truth" else "boxes only"
    t = Table(title=f"Synthetic people scene, seeds {first_seed}-{first_seed + n - 1} x {runs} run(s), started "
              f"from {start} (combined RMSE in px, all parts)")
    for col in ("method", "RMSE", "± std", "ms/frame", "ids kept", "MOTA", "IDF1", "ID sw", "OSPA"):
        t.add_column(col, justify="right" if col != "method" else "left")
    for m, s in summary.items():
        t.add_row(m, f"{s['rmse']:.2f}", f"{s['rmse_std']:.2f}", f"{s['ms_per_frame']:.1f}", f"{s['identities_kept']:.0%}",
                  f"{s['mota']:.3f}", f"{s['idf1']:.3f}", str(s["id_switches"]), f"{s['ospa']:.2f}")
    con.print(t)
    con.print(f"EPMCMC+ELPDA beats EPMCMC+PDA on {wins:.0%} of the seeds" + ("" if runs == 1 else
              f" (mean over {runs} runs each; single runs: {wins_runs:.0%})"))
    if vs is not None and runs > 1:
        con.print(f"beyond the Monte Carlo noise (95 % interval of the paired difference over the runs): ELPDA lower on "
                  f"{vs['lower']:.0%} of the seeds, higher on {vs['higher']:.0%}, undecided on {vs['undecided']:.0%}")
    for kind, table in sweeps.items():
        st = Table(title=f"sweep: {kind}")
        st.add_column(kind)
        for m in SWEEP_METHODS:
            st.add_column(m, justify="right")
        for x in sorted(table[SWEEP_METHODS[0]], key=float):
            st.add_row(str(x), *(f"{table[m][x]:.2f}" for m in SWEEP_METHODS))
        con.print(st)
    con.print("plots: " + ", ".join(plots))


def run(args: argparse.Namespace) -> int:
    from services.commands.errors import UsageError
    from common.multitarget import METHODS
    from common.multitarget.metrics import paired_difference

    if args.seeds < 1 or args.workers < 1 or args.sweep_seeds < 1 or args.runs < 1:
        raise UsageError("--seeds, --sweep-seeds, --runs and --workers must be at least 1")
    if args.first_seed < 0:
        raise UsageError("--first-seed must be 0 or more")
    if not 1 <= args.people <= 5:
        raise UsageError("--people must be between 1 and 5")
    if args.frames < 10:
        raise UsageError("--frames must be at least 10")
    sweeps_wanted = [] if args.sweeps == "none" else [s.strip() for s in args.sweeps.split(",") if s.strip()]
    bad = [s for s in sweeps_wanted if s not in SWEEPS]
    if bad:
        raise UsageError(f"unknown sweep {', '.join(bad)}; choose from {', '.join(SWEEPS)} or none")
    out_dir = Path(args.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    base = (args.people, args.frames, args.particles, args.parts, args.gate)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    jobs = [("main", None, s, *base, args.level, tuple(METHODS), args.runs, args.init) for s in seeds]
    for kind in sweeps_wanted:
        for v in SWEEPS[kind]:
            people, frames, particles, parts, gate = base
            people = v if kind == "targets" else people
            parts = v if kind == "parts" else parts
            gate = v if kind == "gate" else gate
            jobs += [(kind, v, s, people, frames, particles, parts, gate, args.level, SWEEP_METHODS, 1, args.init)
                     for s in range(args.sweep_seeds)]
    if args.workers == 1:
        results = [_job(j) for j in jobs]
    else:
        with ProcessPoolExecutor(args.workers) as pool:
            results = list(pool.map(_job, jobs))
    main = [r for r in results if r["kind"] == "main"]
    summary = _summary(main, METHODS)
    wins = float(np.mean([r["methods"]["epmcmc-elpda"]["rmse"] < r["methods"]["epmcmc-pda"]["rmse"] for r in main]))
    wins_runs = float(np.mean([a < b for r in main for a, b in zip(r["methods"]["epmcmc-elpda"]["rmse_runs"],
                                                                   r["methods"]["epmcmc-pda"]["rmse_runs"])]))
    paired = [paired_difference(r["methods"]["epmcmc-elpda"]["rmse_runs"], r["methods"]["epmcmc-pda"]["rmse_runs"])
              for r in main]
    vs = {v: round(float(np.mean([p["verdict"] == v for p in paired])), 3) for v in ("lower", "higher", "undecided")}
    sweeps = {}
    for kind in sweeps_wanted:
        rows = [r for r in results if r["kind"] == kind]
        sweeps[kind] = {m: {str(v): round(float(np.mean([r["methods"][m]["rmse"] for r in rows if r["value"] == v])), 3)
                            for v in SWEEPS[kind]} for m in SWEEP_METHODS}
    plots = _plots(main, sweeps, out_dir)
    per_seed = [{"seed": r["seed"], "crossings": len(r["crossings"]),
                 **{m: {"rmse": round(v["rmse"], 3), "identities_kept": v["identities_kept"],
                        "id_switches": v["id_switches"], "rmse_runs": [round(x, 3) for x in v["rmse_runs"]],
                        "identities_kept_runs": v["identities_kept_runs"]}
                    for m, v in r["methods"].items()},
                 "elpda_minus_pda": {k: (round(x, 3) if isinstance(x, float) else x) for k, x in p.items()}}
                for r, p in zip(main, paired)]
    report = {
        "seeds": args.seeds, "first_seed": args.first_seed, "runs": args.runs, "people": args.people, "frames": args.frames, "parts": args.parts,
        "gate": args.gate, "level": args.level, "init": args.init, "methods": summary, "elpda_beats_pda": round(wins, 3),
        "elpda_beats_pda_runs": round(wins_runs, 3), "elpda_vs_pda": vs,
        "evidence_ms_per_frame": round(float(np.mean([r["evidence_ms_per_frame"] for r in main])), 2),
        "per_seed": per_seed, "sweeps": sweeps, "sweep_seeds": args.sweep_seeds, "plots": plots,
    }
    (out_dir / "eval-multi.json").write_text(json.dumps(report, indent=1))
    if args.json:
        print(json.dumps(report))
    else:
        _print_table(summary, wins, len(main), sweeps, plots, args.runs, wins_runs, args.init, args.first_seed, vs)
    return 0
