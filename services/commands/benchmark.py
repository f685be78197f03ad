"""Benchmark the tracker on many UAV123 / OTB sequence folders, optionally beside OpenCV's peers.

Each SEQ_DIR is a folder ``img/*.jpg`` + ``groundtruth_rect.txt`` (see ../shared/data/README.md;
UAV123's 1-based boxes and NaN rows are handled as by ``polartrack track``). PolarTrack runs
in-process exactly as ``track`` and ``eval`` run it, from the first ground-truth box with the
source's profile (``--set`` overrides); its box per frame is the axis-aligned box around its
oriented box. ``--peers`` adds OpenCV's CSRT, KCF and NanoTrack v2 from the same first box (rounded
to whole pixels, as OpenCV takes it), run by tools/opencv_baselines.py in an isolated environment
with opencv-contrib-python-headless (``uv run --isolated``: the product does not depend on it nor
on NanoTrack's ONNX files). One scorer (common/evaluation/benchmark.py) scores every tracker's boxes: over the
frames where the target is visible (NaN ground truth left out, as OTB and UAV123 do),
precision20, auc50 (precision over 0-50 px), success_auc (OTB: fraction of frames with IoU above
0, 0.05, ..., 1.0, averaged; 20/21 at best), mean_err (px), frames_lost (frames whose box does
not overlap the target, IoU = 0) and fps (frames over the time in the tracker's start and steps,
reading the images not included); the mean weighs every sequence the same. A peer's
``failures`` counts the frames where OpenCV reported failure (it keeps its last box there). Writes under --out
precision.png and success.png (one curve per tracker, AUC in the legend), errors-SEQ.png per
sequence (centre error per frame), frames-SEQ.csv per sequence (every run's box, centre error and
IoU on every frame: one run per tracker, PolarTrack's one per seed) and benchmark.json (what
--json prints). A PolarTrack run that raises does not stop the benchmark: its later frames are
scored as misses, the error is listed under its sequence (``errors``, the traceback in
error-SEQ-seedN.txt) and said in one line on stderr, and the command exits 1. ``--jobs N`` makes N of
PolarTrack's runs (sequences x seeds) at once, each in a spawned worker process that opens its
sequence again: every run is a function of its sequence, settings and seed alone, so the boxes and
figures are those of one run at a time (tested); only the timings (fps, the re-acquisition's ms per
searched frame), measured while N run, are not.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from services.commands.common_args import positive_int, seed_int

HELP = "benchmark on UAV123/OTB sequence folders (precision, success AUC, fps; --peers: CSRT, KCF, NanoTrack)"
REPO = Path(__file__).resolve().parents[2]
PEERS_TOOL = REPO / "tools" / "opencv_baselines.py"
PEERS = ("csrt", "kcf", "nanotrack")
NANOTRACK_FILES = ("nanotrack_backbone_sim.onnx", "nanotrack_head_sim.onnx")


def peer_env() -> list[str]:
    """``uv run`` options of the peers' isolated environment: opencv-contrib at the very version of
    the product's OpenCV (from uv.lock), so that the peers' figures are reproducible. Unpinned,
    a new release moved NanoTrack on uav123-car16 from 0.902 (OpenCV 5.0.0) to 0.128 (5.1.0)."""
    from importlib.metadata import version

    return ["--isolated", "--no-project", "--with", f"opencv-contrib-python-headless=={version('opencv-python-headless')}",
            "--with", "numpy"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("sequences", nargs="+", metavar="SEQ_DIR", help="UAV123/OTB folders: img/*.jpg + groundtruth_rect.txt")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--out", metavar="DIR", default="recordings/benchmark",
                   help="where to write the plots, the per-frame CSVs and benchmark.json (default recordings/benchmark)")
    p.add_argument("--peers", action="store_true", help="also OpenCV's CSRT, KCF and NanoTrack v2 (isolated environment)")
    p.add_argument("--nanotrack-dir", metavar="DIR", default="../shared/models/nanotrack-v2",
                   help="NanoTrack v2's ONNX files for --peers (default ../shared/models/nanotrack-v2)")
    p.add_argument("--frames", type=positive_int, metavar="N", help="only the first N frames of each sequence")
    p.add_argument("--filter", default="rbpf", choices=["rbpf", "sir", "ml"], help="PolarTrack's filter")
    p.add_argument("--particles", type=positive_int, metavar="N", help="number of particles (rbpf, sir)")
    p.add_argument("--seed", type=seed_int, default=0, help="seed of the filter's random generator")
    p.add_argument("--seeds", type=positive_int, default=1, metavar="N",
                   help="run PolarTrack with N seeds (--seed, --seed + 1, ...) and report each sequence's "
                        "mean over them, with every seed's figures under 'seeds' (the plots: the first seed)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", dest="overrides",
                   help="override a tracker setting by its dotted name (repeatable), as on track and eval")
    p.add_argument("--jobs", type=positive_int, default=1, metavar="N",
                   help="PolarTrack's runs (sequences x seeds) N at a time, each in its own process: the same "
                        "boxes and figures as one at a time, but fps measured while N run (use 1 to time it)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars on stderr")


def open_sequences(args) -> list:
    """Every SEQ_DIR opened and checked before anything runs: (source, first box, settings)."""
    from services.commands.errors import UsageError
    from services.commands.common_args import settings_for
    from common.sources import SourceError, open_source

    out = []
    for spec in args.sequences:
        if not Path(spec).is_dir():
            raise UsageError(f"{spec}: not a folder (SEQ_DIR is a sequence folder: img/*.jpg + groundtruth_rect.txt)")
        try:
            source = open_source(spec, n_frames=args.frames)
        except SourceError as exc:
            raise UsageError(str(exc)) from None
        if not source.has_truth:
            raise UsageError(f"{spec}: not a sequence: no groundtruth_rect.txt (one x,y,w,h line per frame)")
        first = source.truth[0]
        if first is None:
            raise UsageError(f"{spec}: the first frame has no ground-truth box (NaN); the trackers start from it")
        out.append((spec, source, tuple(float(v) for v in first), settings_for(args, source, args.filter)))
    return out


def peer_command(args) -> list[str]:
    """The ``uv run --isolated ...`` prefix of the peers' tool, after checking what it needs."""
    from services.commands.errors import UsageError

    missing = [str(Path(args.nanotrack_dir) / f) for f in NANOTRACK_FILES if not (Path(args.nanotrack_dir) / f).is_file()]
    if missing:
        raise UsageError(f"--peers: NanoTrack model file {missing[0]} not found (--nanotrack-dir DIR must hold "
                         f"{' and '.join(NANOTRACK_FILES)})")
    uv = shutil.which("uv")
    if uv is None:
        raise UsageError("--peers: needs uv on PATH (it runs the OpenCV peers in an isolated environment)")
    if not PEERS_TOOL.is_file():
        raise UsageError(f"--peers: {PEERS_TOOL} not found (run from a checkout of the repository)")
    return [uv, "run", *peer_env(), "python", str(PEERS_TOOL)]


def run_polartrack(source, init, settings, bar) -> tuple[np.ndarray, float, dict | None, dict | None]:
    """PolarTrack's axis-aligned box per frame (NaN rows where it has none), its seconds, its
    re-acquisition's statistics (None when off) and its failure (None, or the frame, the error's
    one line and its traceback): a run that raises is a failed run of its sequence and seed, its
    frames from there on without a box (scored as misses), not the end of the benchmark. A first box
    the tracker refuses and an unreadable frame stay the command's one-line usage errors."""
    import traceback

    from common.single_target.runner import InitError, Tracker
    from common.sources import SourceError

    tracker, boxes, elapsed, failure = None, [], 0.0, None
    for frame in source:
        box = None
        if failure is None:
            t0 = time.perf_counter()
            try:
                if tracker is None:
                    tracker = Tracker.start(frame, init, settings)
                box = tracker.step(frame).axis_aligned_box()
            except (InitError, SourceError):
                raise
            except Exception as exc:  # noqa: BLE001 - reported as this run's failure, below
                failure = {"frame": frame.index, "error": f"{type(exc).__name__}: {exc}".splitlines()[0][:300],
                           "traceback": traceback.format_exc()}
            elapsed += time.perf_counter() - t0
        boxes.append((np.nan,) * 4 if box is None else box)
        bar.update(1)
    stats = tracker.reacquirer.stats() if tracker is not None and tracker.reacquirer is not None else None
    return np.asarray(boxes, float), elapsed, stats, failure


class _NoBar:
    """A progress bar that shows nothing (a worker's runs are counted by the parent's bar)."""

    def update(self, n: int) -> None:
        pass


def _run_in_worker(spec: str, n_frames: int | None, init, settings) -> tuple[np.ndarray, float, dict | None, dict | None]:
    """One PolarTrack run in a worker process of ``--jobs``: the sequence opened there again."""
    from common.sources import open_source

    return run_polartrack(open_source(spec, n_frames=n_frames), init, settings, _NoBar())


def run_all_polartrack(sequences, args, quiet: bool) -> list[list[tuple[np.ndarray, float, dict | None, dict | None]]]:
    """PolarTrack's runs, per sequence a list over the seeds: one at a time in this process
    (``--jobs 1``), or ``--jobs`` at a time in worker processes (spawned: nothing of this
    process's state is shared), collected in the same order."""
    from concurrent.futures import ProcessPoolExecutor
    import multiprocessing

    from tqdm import tqdm

    from common.single_target.runner import InitError
    from common.sources import SourceError
    from services.commands.errors import UsageError

    seeds = range(args.seed, args.seed + args.seeds)
    out: list[list] = []
    if args.jobs == 1:
        for spec, source, init, settings in tqdm(sequences, unit="seq", desc="benchmark", disable=quiet,
                                                 file=sys.stderr):
            with tqdm(total=len(source) * args.seeds, unit="frame", desc=f"{source.name} polartrack",
                      disable=quiet, file=sys.stderr, leave=False) as bar:
                try:
                    out.append([run_polartrack(source, init, settings.model_copy(update={"seed": seed}), bar)
                                for seed in seeds])
                except (InitError, SourceError) as exc:
                    raise UsageError(f"{spec}: {exc}") from None
        return out
    total = sum(len(source) for _, source, _, _ in sequences) * args.seeds
    with ProcessPoolExecutor(max_workers=args.jobs, mp_context=multiprocessing.get_context("spawn")) as pool, \
            tqdm(total=total, unit="frame", desc=f"benchmark polartrack, {args.jobs} jobs", disable=quiet,
                 file=sys.stderr) as bar:
        futures = [[pool.submit(_run_in_worker, spec, args.frames, init, settings.model_copy(update={"seed": seed}))
                    for seed in seeds] for spec, _, init, settings in sequences]
        try:
            for (spec, source, _, _), row in zip(sequences, futures):
                results = []
                for future in row:
                    try:
                        results.append(future.result())
                    except (InitError, SourceError) as exc:
                        raise UsageError(f"{spec}: {exc}") from None
                    bar.update(len(source))
                out.append(results)
        except BaseException:
            pool.shutdown(cancel_futures=True)  # the runs not started yet are not made
            raise
    return out


def run_peers(prefix: list[str], spec: str, init, args, n_frames: int, bar) -> dict:
    """The peers' output (tools/opencv_baselines.py's JSON) on one sequence, ``bar`` following its
    'progress N' lines."""
    from services.commands.errors import UsageError

    cmd = [*prefix, str(Path(spec).resolve()), "--init", ",".join(repr(float(v)) for v in init),
           "--frames", str(n_frames), "--nanotrack-dir", str(Path(args.nanotrack_dir).resolve()), "--progress"]
    env = {k: v for k, v in os.environ.items() if k != "VIRTUAL_ENV"}
    tail: list[str] = []
    with tempfile.TemporaryFile("w+") as stdout:
        proc = subprocess.Popen(cmd, stdout=stdout, stderr=subprocess.PIPE, text=True, env=env)
        done = 0
        for line in proc.stderr:
            if line.startswith("progress "):
                n = int(line.split()[1])
                bar.update(n - done)
                done = n
            elif line.strip():
                tail = (tail + [line.strip()])[-3:]
        proc.wait()
        stdout.seek(0)
        text = stdout.read()
    if proc.returncode != 0:
        raise UsageError(f"--peers on {spec}: {tail[-1] if tail else f'exit status {proc.returncode}'}")
    result = json.loads(text)
    if result["frames"] != n_frames:
        raise UsageError(f"--peers on {spec}: the peers saw {result['frames']} frames, PolarTrack {n_frames}")
    return result


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from common.evaluation.benchmark import (as_boxes, mean_scores, mean_standard_errors, score_boxes,
                                             seed_standard_errors, write_per_frame)
    from common.evaluation.plots import plot_curves, plot_errors_over_time

    sequences = open_sequences(args)
    prefix = peer_command(args) if args.peers else None
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    trackers = ["polartrack", *(PEERS if args.peers else ())]
    rows, curves, plots, frame_files, opencv = [], {"precision": {}, "success": {}}, {}, {}, None
    quiet = args.no_progress
    # per sequence, per seed: (boxes, elapsed, re-acquisition, failure)
    all_seeded = run_all_polartrack(sequences, args, quiet)
    failed = []  # (sequence, seed, frame, error, traceback file) of the runs that raised
    for (spec, source, init, settings), seeded in zip(sequences, all_seeded):
        truth = as_boxes(source.truth)
        errors = []
        for seed, (*_, failure) in zip(range(args.seed, args.seed + args.seeds), seeded):
            if failure is not None:
                trace = out_dir / f"error-{source.name}-seed{seed}.txt"
                trace.write_text(failure["traceback"])
                errors.append({"seed": seed, "frame": failure["frame"], "error": failure["error"],
                               "traceback": str(trace)})
                failed.append((source.name, seed, failure["frame"], failure["error"], trace))
        failed_seeds = {e["seed"] for e in errors}  # their time covers only the frames before: no rate
        boxes, elapsed, reacq, _ = seeded[0]
        runs = {"polartrack": (boxes, len(source) / elapsed if elapsed > 0 and args.seed not in failed_seeds else None)}
        failures = {}  # a peer's frames where OpenCV reported failure (it kept its last box there)
        if prefix is not None:
            with tqdm(total=len(source) * len(PEERS), unit="frame", desc=f"{source.name} peers", disable=quiet,
                      file=sys.stderr, leave=False) as bar:
                peers = run_peers(prefix, spec, init, args, len(source), bar)
            opencv = peers["opencv"]
            for name in PEERS:
                r = peers["trackers"][name]
                runs[name] = (np.asarray(r["boxes"], float), r["fps"])
                failures[name] = r["failures"]
        scores = {name: score_boxes(b, truth) for name, (b, _) in runs.items()}
        results = {}
        for name, sc in scores.items():
            fps = runs[name][1]
            results[name] = {**sc.as_dict(), "fps": None if fps is None else round(float(fps), 1)}
            if name in failures:
                results[name]["failures"] = failures[name]
            curves["precision"].setdefault(name, []).append(sc.precision)
            curves["success"].setdefault(name, []).append(sc.success)
        if reacq is not None:
            results["polartrack"]["reacquisition"] = reacq
        if errors:
            results["polartrack"]["errors"] = errors
        seed_scores = [(seed, b, el, scores["polartrack"] if seed == args.seed else score_boxes(b, truth))
                       for seed, (b, el, *_) in zip(range(args.seed, args.seed + args.seeds), seeded)]
        if args.seeds > 1:
            per_seed = [{"seed": seed, **sc.as_dict(),
                         "fps": round(len(source) / el, 1) if el > 0 and seed not in failed_seeds else None}
                        for seed, _, el, sc in seed_scores]
            means = {k: v for k, v in mean_scores(per_seed).items() if k != "sequences"}
            results["polartrack"] = {**results["polartrack"], **means, **seed_standard_errors(per_seed),
                                     "seeds": per_seed}
        per_frame = [("polartrack", seed, b, sc) for seed, b, _, sc in seed_scores]
        per_frame += [(name, None, b, scores[name]) for name, (b, _) in runs.items() if name != "polartrack"]
        frames_csv = out_dir / f"frames-{source.name}.csv"
        write_per_frame(frames_csv, truth, per_frame)
        frame_files[source.name] = str(frames_csv)
        plot = out_dir / f"errors-{source.name}.png"
        visible = ~np.isnan(truth).any(axis=1)
        plot_errors_over_time({n: sc.errors for n, sc in scores.items()}, visible, plot,
                              f"{source.name}: centre error per frame")
        plots[source.name] = str(plot)
        rows.append({"sequence": source.name, "path": spec, "frames": len(source),
                     "visible_frames": int(visible.sum()), "init_box": list(init), "trackers": results})
    mean = {name: {**mean_scores([r["trackers"][name] for r in rows]),
                   **mean_standard_errors([r["trackers"][name] for r in rows])} for name in trackers}
    title = f"{len(rows)} sequence{'s' if len(rows) != 1 else ''}"
    for kind in ("precision", "success"):
        plot_curves(curves[kind], kind, out_dir / f"{kind}.png", f"{kind} plot, {title}")
    summary = {"trackers": trackers, "jobs": args.jobs, "sequences": rows, "mean": mean,
               "plots": {"precision": str(out_dir / "precision.png"), "success": str(out_dir / "success.png"),
                         "errors": plots},
               "per_frame": frame_files,
               "definitions": {"scored_frames": "frames whose ground truth is a box (NaN rows left out)",
                               "errors": "PolarTrack's runs that raised (seed, frame, the error, its traceback "
                                         "file): that run's later frames have no box and are scored as misses; "
                                         "the command then exits 1",
                               "success_auc": "mean over IoU thresholds 0, 0.05, ..., 1 of the fraction of "
                                              "scored frames with IoU above the threshold (OTB)",
                               "frames_lost": "scored frames whose box does not overlap the truth (IoU = 0)",
                               "mean": "mean over sequences, each weighing the same",
                               "per_frame": "per sequence, a CSV of every run's box and score on every frame "
                                            "(frame from 0, 0-based pixels; polartrack one run per seed)",
                               "jobs": "PolarTrack's runs made at once (--jobs); its timings (fps, ms per "
                                       "searched frame) were measured while that many ran",
                               "seeds": "with --seeds N, PolarTrack's figures per sequence are the mean "
                                        "over its N seeds (each seed's under 'seeds'); the plots show the "
                                        "first seed",
                               "_se": "with --seeds N (N >= 2), the standard error of that mean over the "
                                      "seeds (sample standard deviation / sqrt(N)); in the mean over "
                                      "sequences, sqrt(sum of the sequences' se^2) / sequences; the "
                                      "table shows it after the figure (+-)"}}
    if opencv is not None:
        summary["opencv"] = opencv
    (out_dir / "benchmark.json").write_text(json.dumps(summary, indent=1))
    if args.json:
        print(json.dumps(summary))
    else:
        print_table(summary)
    for name, seed, frame, error, trace in failed:
        print(f"polartrack benchmark: {name}, seed {seed}: PolarTrack failed at frame {frame}: {error} "
              f"(its later frames scored as misses; traceback in {trace})", file=sys.stderr)
    return 1 if failed else 0


def print_table(summary: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title="polartrack benchmark (scored: frames with a ground-truth box)")
    for col in ("sequence", "tracker", "scored/frames", "precision20", "auc50", "success AUC", "lost", "fps"):
        table.add_column(col, justify="left" if col in ("sequence", "tracker") else "right")

    def add(seq: str, frames: str, results: dict) -> None:
        for i, (name, r) in enumerate(results.items()):
            fps = "-" if r.get("fps") is None else f"{r['fps']:.1f}"
            lost = f"{r['frames_lost']:g}" if isinstance(r["frames_lost"], float) else str(r["frames_lost"])
            figs = [f"{r[k]:.3f}" + (f" ±{r[k + '_se']:.3f}" if f"{k}_se" in r else "")
                    for k in ("precision20", "auc50", "success_auc")]
            table.add_row(seq if i == 0 else "", name, frames if i == 0 else "", *figs, lost, fps,
                          end_section=i == len(results) - 1)

    for row in summary["sequences"]:
        add(row["sequence"], f"{row['visible_frames']}/{row['frames']}", row["trackers"])
    add("mean", f"{len(summary['sequences'])} seq", summary["mean"])
    console = Console()
    if not console.is_terminal:
        console = Console(width=max(console.width, 110))  # a pipe or a file: no truncated names
    console.print(table)
    plots = summary["plots"]
    print(f"plots: {plots['precision']}, {plots['success']}, {len(plots['errors'])} error plots")
