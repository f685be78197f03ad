"""The benchmark scorer: one set of rules for every tracker's boxes (PolarTrack's and the peers').

Boxes are axis-aligned ``(x, y, w, h)`` in pixels (top-left corner and size, 0-based), one row per
frame; a NaN row in the ground truth is a frame where the target is not visible, a NaN row in a
tracker's boxes a frame where it gave no box. Following OTB and UAV123, frames without a visible
target are left out of every score. Over the remaining ("visible") frames:

- centre error: distance between the box centres (px); no box is a miss at any threshold;
- ``precision20``: fraction of frames with a centre error of at most 20 px; ``auc50``: the mean of
  that precision over the thresholds 0, 1, ..., 50 px (:data:`common.evaluation.THRESHOLDS`), as
  ``polartrack eval`` scores;
- ``success_auc``: the success curve's AUC, OTB's convention: the fraction of frames whose IoU is
  above each of the 21 thresholds 0, 0.05, ..., 1.0, averaged (IoU > 1 never holds, so a perfect
  tracker scores 20/21 = 0.952);
- ``frames_lost``: frames whose box does not overlap the target at all (IoU = 0, no box included),
  the failure criterion of VOT: unlike a centre-error cut it scales with the target's size.

Every frame's boxes and scores are written by :func:`write_per_frame` (one CSV per sequence).
Numpy and the standard csv module; the plots are in :mod:`common.evaluation.plots`.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from common.evaluation import THRESHOLDS as PRECISION_THRESHOLDS
from common.evaluation import precision_curve, score_run

SUCCESS_THRESHOLDS = np.linspace(0.0, 1.0, 21)
"""IoU thresholds of the success curve (OTB: 0:0.05:1)."""

SCORE_KEYS = ("precision20", "auc50", "success_auc", "mean_err", "frames_lost", "fps")
"""The per-sequence figures a benchmark reports, in table order (``fps`` set by the caller)."""


def as_boxes(boxes) -> np.ndarray:
    """``boxes`` as an (N, 4) float array; ``None`` rows become NaN rows."""
    rows = [(np.nan,) * 4 if b is None else tuple(float(v) for v in b) for b in boxes]
    return np.asarray(rows, float).reshape(-1, 4)


def box_centres(boxes: np.ndarray) -> np.ndarray:
    """(N, 2) centres of (N, 4) ``(x, y, w, h)`` boxes."""
    b = np.asarray(boxes, float)
    return np.stack([b[:, 0] + b[:, 2] / 2.0, b[:, 1] + b[:, 3] / 2.0], axis=1)


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Intersection over union of axis-aligned ``(x, y, w, h)`` boxes, row by row ((N, 4) each);
    NaN where either row is NaN, 0 for boxes that only touch or have no area."""
    a, b = np.asarray(a, float).reshape(-1, 4), np.asarray(b, float).reshape(-1, 4)
    iw = np.minimum(a[:, 0] + a[:, 2], b[:, 0] + b[:, 2]) - np.maximum(a[:, 0], b[:, 0])
    ih = np.minimum(a[:, 1] + a[:, 3], b[:, 1] + b[:, 3]) - np.maximum(a[:, 1], b[:, 1])
    inter = np.clip(iw, 0.0, None) * np.clip(ih, 0.0, None)
    union = a[:, 2] * a[:, 3] + b[:, 2] * b[:, 3] - inter
    with np.errstate(invalid="ignore", divide="ignore"):
        iou = np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0)
    return np.where(np.isnan(inter) | np.isnan(union), np.nan, iou)


def success_curve(ious: np.ndarray, thresholds: np.ndarray = SUCCESS_THRESHOLDS) -> np.ndarray:
    """Fraction of ``ious`` (one per scored frame; NaN: no box, a miss) above each threshold."""
    o = np.nan_to_num(np.asarray(ious, float), nan=0.0)
    return np.array([(o > t).mean() for t in thresholds])


@dataclass
class SequenceScore:
    """One tracker on one sequence (see the module docstring for the definitions)."""

    precision20: float
    auc50: float
    success_auc: float
    mean_err: float
    """Mean centre error (px) over the visible frames where the tracker gave a box."""
    frames_lost: int
    frames: int
    visible_frames: int
    errors: np.ndarray = field(repr=False)
    """(frames,) centre error per frame, NaN where the target is not visible (or there is no box)."""
    ious: np.ndarray = field(repr=False)
    """(frames,) IoU per frame, NaN where the target is not visible."""
    precision: np.ndarray = field(repr=False)
    """The precision curve over :data:`PRECISION_THRESHOLDS`."""
    success: np.ndarray = field(repr=False)
    """The success curve over :data:`SUCCESS_THRESHOLDS`."""

    def as_dict(self) -> dict:
        return {"precision20": round(self.precision20, 4), "auc50": round(self.auc50, 4),
                "success_auc": round(self.success_auc, 4), "mean_err": round(self.mean_err, 3),
                "frames_lost": self.frames_lost, "frames": self.frames, "visible_frames": self.visible_frames}


def score_boxes(boxes, truth) -> SequenceScore:
    """Score a tracker's per-frame ``boxes`` against the ground-truth ``truth`` boxes (same length;
    rows ``(x, y, w, h)``, NaN or ``None`` rows as in the module docstring)."""
    pred, gt = as_boxes(boxes), as_boxes(truth)
    if len(pred) != len(gt):
        raise ValueError(f"{len(pred)} boxes for {len(gt)} ground-truth frames")
    visible = ~np.isnan(gt).any(axis=1)
    pc, gc = box_centres(pred), box_centres(gt)
    errors = np.hypot(pc[:, 0] - gc[:, 0], pc[:, 1] - gc[:, 1])
    ious = np.where(visible, np.nan_to_num(box_iou(pred, gt), nan=0.0), np.nan)
    run = score_run(errors, visible)
    if run.visible_frames == 0:
        empty = np.full(len(PRECISION_THRESHOLDS), np.nan), np.full(len(SUCCESS_THRESHOLDS), np.nan)
        return SequenceScore(np.nan, np.nan, np.nan, np.nan, 0, len(gt), 0, errors, ious, *empty)
    success = success_curve(ious[visible])
    return SequenceScore(run.precision20, run.auc50, float(success.mean()), run.mean_err,
                         int(np.sum(ious[visible] <= 0.0)), len(gt), run.visible_frames, errors, ious,
                         precision_curve(errors[visible]), success)


def mean_scores(rows: list[dict], keys=SCORE_KEYS) -> dict:
    """The mean over sequences of each figure in ``keys`` (per-sequence dicts such as
    :meth:`SequenceScore.as_dict` plus ``fps``), each sequence weighing the same; a figure a sequence
    does not have (None: a failed run's fps) is left out of its mean."""
    out = {}
    for k in keys:
        vals = [r[k] for r in rows if r.get(k) is not None]
        if vals:
            out[k] = round(float(np.mean(vals)), 4)
    out["sequences"] = len(rows)
    return out


SPREAD_KEYS = ("precision20", "auc50", "success_auc")
"""The figures whose spread over a tracker's seeds a benchmark reports (``KEY_se``)."""


def seed_standard_errors(per_seed: list[dict], keys=SPREAD_KEYS) -> dict:
    """``{KEY_se: s / sqrt(n)}`` over a sequence's ``n`` seeds, ``s`` their sample standard deviation
    (ddof 1): the standard error of the seeds' mean, how far another set of ``n`` seeds would move
    it (a particle filter's outcome on a real sequence can differ from seed to seed by most of its
    range). Empty with fewer than two seeds."""
    if len(per_seed) < 2:
        return {}
    out = {}
    for k in keys:
        vals = np.array([r[k] for r in per_seed if k in r], float)
        if len(vals) >= 2:
            out[f"{k}_se"] = round(float(np.std(vals, ddof=1) / np.sqrt(len(vals))), 4)
    return out


def mean_standard_errors(rows: list[dict], keys=SPREAD_KEYS) -> dict:
    """The standard error of :func:`mean_scores`' mean over sequences from each sequence's
    ``KEY_se`` (the sequences' seeds are drawn independently): sqrt(sum of se^2) / sequences. Only
    where every sequence has one."""
    out = {}
    for k in keys:
        ses = [r.get(f"{k}_se") for r in rows]
        if rows and all(se is not None for se in ses):
            out[f"{k}_se"] = round(float(np.sqrt(np.sum(np.square(ses))) / len(rows)), 4)
    return out


PER_FRAME_COLUMNS = ("frame", "tracker", "seed", "x", "y", "w", "h", "truth_x", "truth_y", "truth_w", "truth_h",
                     "centre_error", "iou")


def write_per_frame(path: str | Path, truth, runs) -> None:
    """One CSV of every frame's box and score for one sequence: a row per frame and run, columns
    :data:`PER_FRAME_COLUMNS`. ``runs`` is ``(tracker, seed or None, boxes, score)`` per run, ``score``
    the :class:`SequenceScore` of ``boxes`` against ``truth``; ``frame`` counts from 0 in the
    sequence's order, boxes are 0-based pixels as scored, and an empty cell is a NaN: a frame
    without a visible target has empty truth, ``centre_error`` and ``iou`` (it is not scored), a
    scored frame without a box an empty box and ``centre_error`` and an ``iou`` of 0 (a miss)."""
    gt = as_boxes(truth)

    def cell(v) -> str:
        return "" if v is None or not np.isfinite(v) else repr(float(v))

    with open(path, "w", newline="") as f:
        out = csv.writer(f)
        out.writerow(PER_FRAME_COLUMNS)
        for name, seed, boxes, score in runs:
            pred = as_boxes(boxes)
            if len(pred) != len(gt):
                raise ValueError(f"{name}: {len(pred)} boxes for {len(gt)} ground-truth frames")
            for i in range(len(gt)):
                out.writerow([i, name, "" if seed is None else seed, *map(cell, pred[i]), *map(cell, gt[i]),
                              cell(score.errors[i]), cell(score.ious[i])])
