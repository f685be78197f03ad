"""The benchmark's plots (matplotlib, Agg): OTB-style precision and success plots over a set of
sequences, one curve per tracker, and a sequence's centre error over time.

The set's curve of a tracker is the mean of its per-sequence curves (each sequence weighing the
same, as OTB averages them), so the AUC in its legend is the mean of the per-sequence AUCs.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from common.evaluation.benchmark import PRECISION_THRESHOLDS, SUCCESS_THRESHOLDS


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_curves(curves: dict[str, list[np.ndarray]], kind: str, path: Path, title: str) -> None:
    """``kind`` "precision" (curves over :data:`PRECISION_THRESHOLDS`, legend: precision@20 px and
    AUC) or "success" (over :data:`SUCCESS_THRESHOLDS`, legend: AUC); ``curves`` maps a tracker to
    its per-sequence curves, averaged here. A tracker keeps its colour (its place in ``curves``), the
    legend is in order of AUC."""
    plt = _pyplot()
    x = PRECISION_THRESHOLDS if kind == "precision" else SUCCESS_THRESHOLDS
    means = {name: (f"C{i}", np.nanmean(np.stack(c), axis=0)) for i, (name, c) in enumerate(curves.items())}
    fig, ax = plt.subplots(figsize=(6.5, 5))
    for name, (colour, m) in sorted(means.items(), key=lambda kv: -float(np.nanmean(kv[1][1]))):
        if kind == "precision":
            label = f"{name} [{m[list(x).index(20)]:.3f} @20px, AUC {np.nanmean(m):.3f}]"
        else:
            label = f"{name} [AUC {np.nanmean(m):.3f}]"
        ax.plot(x, m, lw=2, color=colour, label=label)
    if kind == "precision":
        ax.set_xlabel("location error threshold (px)")
        ax.set_ylabel("precision")
        ax.axvline(20, color="k", lw=0.5, ls="--")
        ax.legend(loc="lower right")
    else:
        ax.set_xlabel("overlap (IoU) threshold")
        ax.set_ylabel("success rate")
        ax.legend(loc="lower left")
    ax.set_xlim(x[0], x[-1])
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_errors_over_time(errors: dict[str, np.ndarray], visible: np.ndarray, path: Path, title: str) -> None:
    """Centre error per frame, one line per tracker (coloured as in :func:`plot_curves`); the frames
    without a visible target shaded."""
    plt = _pyplot()
    hidden = ~np.asarray(visible, bool)
    frames = np.arange(len(hidden))
    fig, ax = plt.subplots(figsize=(11, 4))
    if hidden.any():
        ax.fill_between(frames, 0, 1, where=hidden, transform=ax.get_xaxis_transform(), color="0.85",
                        label="target not visible")
    for i, (name, e) in enumerate(errors.items()):
        ax.plot(frames, e, lw=1.2, color=f"C{i}", label=name)
    ax.axhline(20, color="k", lw=0.5, ls="--")
    ax.set_yscale("symlog", linthresh=10)
    ax.set_ylim(bottom=0)
    ax.set_xlabel("frame")
    ax.set_ylabel("centre error (px)")
    ax.legend(loc="upper left")
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
