"""Scores of multi-target articulated tracks against ground truth.

* combined RMSE of a target (paper section 4): sqrt of the mean, over frames and parts, of the
  squared distance between estimated and true part centres, pixels.
* OSPA (Schuhmacher, Vo and Vo 2008) between the estimated and true target positions (torso
  centres) of a frame: (min over assignments (1/n) sum_i min(d_i, c)^p + c^p |n - m|)^(1/p), n >= m.
* MOTA, IDF1 and identity switches (CLEAR MOT; Ristani et al. 2016) with ``motmetrics`` (1.4.0 runs
  on NumPy 2 / pandas 3), matching torso centres within ``match_radius`` pixels.
* identities kept: at the end of the run every estimate is on its own person.
* paired difference of two methods on one scene over Monte Carlo runs, with a Student-t interval.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment


def combined_rmse(est: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(T,) combined RMSE of every target from (F, T, P, 2) estimates and truth."""
    d2 = np.sum((np.asarray(est) - np.asarray(truth)) ** 2, axis=-1)
    return np.sqrt(d2.mean(axis=(0, 2)))


def ospa(x: np.ndarray, y: np.ndarray, c: float = 50.0, p: float = 2.0) -> float:
    """OSPA distance between point sets x (n, 2) and y (m, 2), cut-off ``c`` px, order ``p``."""
    x, y = np.asarray(x, float).reshape(-1, 2), np.asarray(y, float).reshape(-1, 2)
    if len(x) > len(y):
        x, y = y, x
    n, m = len(x), len(y)
    if m == 0:
        return 0.0
    d = np.minimum(np.linalg.norm(x[:, None] - y[None], axis=-1), c) ** p
    r, k = linear_sum_assignment(d) if n else (np.array([], int), np.array([], int))
    return float(((d[r, k].sum() + c**p * (m - n)) / m) ** (1.0 / p))


def mot_metrics(est: np.ndarray, truth: np.ndarray, match_radius: float) -> dict:
    """MOTA, IDF1 and identity switches of (F, T, 2) estimated and true positions (same target order)."""
    import motmetrics as mm

    acc = mm.MOTAccumulator(auto_id=True)
    ids = list(range(truth.shape[1]))
    for e, t in zip(est, truth):
        d = np.linalg.norm(t[:, None] - e[None], axis=-1)
        acc.update(ids, ids, np.where(d <= match_radius, d, np.nan))
    s = mm.metrics.create().compute(acc, metrics=["mota", "idf1", "num_switches"], name="run")
    return {"mota": float(s["mota"].iloc[0]), "idf1": float(s["idf1"].iloc[0]), "id_switches": int(s["num_switches"].iloc[0])}


def identities_kept(est: np.ndarray, truth: np.ndarray, max_error: float, last: int = 10) -> np.ndarray:
    """(T,) bool: at the end of the run (the ``last`` frames, all after the crossings) each estimate
    (F, T, 2) is within ``max_error`` of its own person, and the optimal assignment of estimates to
    people on the final frame gives every estimate its own person -- or a person standing within
    ``max_error`` of its own: two people who end the run one behind the other (a few px apart) cannot
    be told apart by position, and estimates a px or two off their own would swap in the assignment."""
    own = np.linalg.norm(est[-last:] - truth[-last:], axis=-1)  # (last, T)
    ok = np.all(own <= max_error, axis=0)
    d = np.linalg.norm(est[-1][:, None] - truth[-1][None], axis=-1)
    r, c = linear_sum_assignment(d)
    got = c[np.argsort(r)]  # the person each estimate is assigned to
    apart = np.linalg.norm(truth[-1] - truth[-1][got], axis=-1)  # from its own person
    return ok & ((got == np.arange(len(d))) | (apart <= max_error))


def paired_difference(a_runs, b_runs, confidence: float = 0.95) -> dict:
    """Is method a's combined RMSE on one scene lower than method b's beyond the Monte Carlo noise?

    ``a_runs``, ``b_runs``: the scene's per-run RMSEs, run r of a paired with run r of b (the same
    filter seed). The mean difference d = mean(a - b) gets a Student-t confidence interval
    d +- t_{(1+confidence)/2, R-1} s / sqrt(R), s the runs' standard deviation of a - b. ``verdict``:
    ``lower`` (the interval lies below 0), ``higher`` (above 0) or ``undecided`` (it holds 0, or fewer
    than two runs). With a handful of runs a scene where the methods differ by less than their
    run-to-run spread is undecided, rather than a coin toss counted as a win or a loss."""
    from scipy.stats import t as student_t

    d = np.asarray(a_runs, float) - np.asarray(b_runs, float)
    if d.ndim != 1 or len(d) == 0:
        raise ValueError("need one RMSE per run for both methods, paired")
    mean = float(d.mean())
    if len(d) < 2:
        return {"difference": mean, "half_width": None, "verdict": "undecided"}
    half = float(student_t.ppf(0.5 * (1.0 + confidence), len(d) - 1) * d.std(ddof=1) / np.sqrt(len(d)))
    verdict = "lower" if mean + half < 0 else "higher" if mean - half > 0 else "undecided"
    return {"difference": mean, "half_width": half, "verdict": verdict}
