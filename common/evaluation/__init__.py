"""Scoring a run against ground truth: centre errors, precision, AUC, occlusion recovery."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from common.await_info import AwaitInfo

THRESHOLDS = np.arange(0, 51)
"""Centre-error thresholds (px) of the precision curve whose mean is ``auc50``."""


@dataclass
class RunScore:
    precision20: float
    """Fraction of frames with the target visible where the centre error is at most 20 px."""
    auc50: float
    """Mean of that precision over thresholds 0, 1, ..., 50 px."""
    mean_err: float
    """Mean centre error (px) over frames with the target visible."""
    frames: int
    visible_frames: int

    def as_dict(self) -> dict:
        return {"precision20": round(self.precision20, 4), "auc50": round(self.auc50, 4),
                "mean_err": round(self.mean_err, 3), "frames": self.frames, "visible_frames": self.visible_frames}


def centre_errors(estimates: np.ndarray, truths: np.ndarray) -> np.ndarray:
    """Euclidean distance per frame between (N, 2) estimates and truths; NaN where no truth."""
    return np.hypot(estimates[:, 0] - truths[:, 0], estimates[:, 1] - truths[:, 1])


def precision_curve(errors: np.ndarray, thresholds: np.ndarray = THRESHOLDS) -> np.ndarray:
    """Fraction of ``errors`` (px, one per scored frame; NaN or inf: a miss) at most each threshold."""
    e = np.asarray(errors, float)
    e = np.where(np.isfinite(e), e, np.inf)
    return np.array([(e <= t).mean() for t in thresholds])


def score_run(errors: np.ndarray, visible: np.ndarray) -> RunScore:
    """Precision and AUC over the frames where the target is ``visible`` (bool per frame)."""
    e = np.asarray(errors, float)[np.asarray(visible, bool)]
    if e.size == 0:
        return RunScore(float("nan"), float("nan"), float("nan"), len(errors), 0)
    e = np.where(np.isfinite(e), e, np.inf)
    prec = precision_curve(e)
    return RunScore(float((e <= 20).mean()), float(prec.mean()), float(np.mean(e[np.isfinite(e)])) if np.isfinite(e).any()
                    else float("inf"), len(errors), int(e.size))


def reemergence_frame(visible_fraction: np.ndarray, occlusion: tuple[int, int], min_visible: float = 0.5) -> int | None:
    """First frame at or after the end of a full occlusion ``(start, end)`` (end exclusive) where
    at least ``min_visible`` of the target shows again."""
    vf = np.asarray(visible_fraction, float)
    for i in range(occlusion[1], len(vf)):
        if vf[i] >= min_visible:
            return i
    return None


def recovered(errors: np.ndarray, start: int | None, within: int = 10, below: float = 10.0, hold: int = 10) -> bool:
    """True if the error is back under ``below`` px within ``within`` frames of ``start`` and then
    stays under it for ``hold`` frames (so a track that merely sweeps past the target does not
    count)."""
    if start is None:
        return False
    e = np.asarray(errors, float)
    for f in range(start, min(start + within + 1, len(e))):
        if e[f] < below:
            seg = e[f:f + hold]
            return bool(len(seg) == min(hold, len(e) - f) and np.all(seg < below))
    return False


class _LiveScores:
    """A live run's error per frame, from its frames' truths and its estimates as they arrive, in
    either order (:class:`common.await_info.AwaitInfo`: an estimate waits for its frame's info, or a
    later frame's; a frame whose info never comes is not scored). ``errors``: frame index -> error,
    NaN where nothing could be scored. The estimates come in frame order (one tracker's stream), so a
    frame's estimate, once scored, lets go of every earlier frame's truth still kept (a frame the
    tracker skipped): a live camera's run keeps no truths it will not read."""

    def __init__(self):
        self.errors: dict[int, float] = {}
        self._truths: dict[int, object] = {}
        self._waiting: AwaitInfo[tuple[int, object]] = AwaitInfo()

    def _truth(self, index: int, truth) -> None:
        self._truths[int(index)] = truth
        self.frame(index)

    def frame(self, index: int) -> None:
        """Frame ``index``'s info has come (with or without a truth)."""
        for w in self._waiting.info(int(index)):
            self._score(*w)

    def _estimate(self, index: int, estimate) -> None:
        self.errors.setdefault(int(index), float("nan"))
        for w in self._waiting.hold(int(index), (int(index), estimate)):
            self._score(*w)

    def _score(self, index: int, estimate) -> None:
        t = self._truths.pop(index, None)
        for k in [k for k in self._truths if k < index]:
            del self._truths[k]
        if t is not None:
            self.errors[index] = self._error(t, estimate)

    def _error(self, truth, estimate) -> float:
        raise NotImplementedError


class LiveErrors(_LiveScores):
    """A single-target run's centre error per frame (px), NaN where the target was hidden or the
    frame has no truth (see :class:`_LiveScores` for the order)."""

    def truth(self, index: int, cx: float, cy: float, visible: bool) -> None:
        """Frame ``index``'s true centre (pixels) and whether the target is visible on it."""
        self._truth(index, (float(cx), float(cy), bool(visible)))

    def estimate(self, index: int, x: float, y: float) -> None:
        """Frame ``index``'s estimated centre (pixels)."""
        self._estimate(index, (float(x), float(y)))

    def _error(self, truth, estimate) -> float:
        cx, cy, visible = truth
        if not (visible and math.isfinite(cx) and math.isfinite(cy)):
            return float("nan")
        return float(math.hypot(estimate[0] - cx, estimate[1] - cy))


class LiveMultiErrors(_LiveScores):
    """A multi-target run's error per frame: the mean distance (px) between each estimated part
    centre and the true one, targets in the scene's person order; NaN where the frame has no truth
    or the estimate's targets are not the truth's people (see :class:`_LiveScores` for the order)."""

    def truth(self, index: int, parts: np.ndarray) -> None:
        """Frame ``index``'s true part centres, (people, parts, 2)."""
        self._truth(index, np.asarray(parts, float))

    def estimate(self, index: int, positions: np.ndarray) -> None:
        """Frame ``index``'s estimated part centres, (targets, parts, 2)."""
        self._estimate(index, np.asarray(positions, float))

    def _error(self, truth, estimate) -> float:
        if truth.shape != estimate.shape:
            return float("nan")
        return float(np.mean(np.linalg.norm(estimate - truth, axis=-1)))
