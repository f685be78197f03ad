"""kernel_mode_index computed in place equals the (candidates, n, 2) expression it replaced."""

import numpy as np

from common.tracking.state import kernel_mode_index


def _reference_density(xy: np.ndarray, w: np.ndarray, cand: np.ndarray, h2: float) -> np.ndarray:
    diff = xy[cand, None, :] - xy[None, :, :]
    return np.exp(-np.sum(diff * diff, axis=2) / (2.0 * h2)) @ w


def _bandwidth(xy: np.ndarray, w: np.ndarray) -> float:
    d = xy - w @ xy
    return float(w @ np.sum(d * d, axis=1)) / 2.0 * (1.0 / float(np.sum(w * w))) ** (-1.0 / 3.0)


def test_same_mode_as_the_reference_expression():
    rng = np.random.default_rng(11)
    for _ in range(200):
        n = int(rng.integers(2, 700))
        xy = rng.normal(0.0, rng.uniform(0.01, 80.0), (n, 2)) + rng.normal(0, 500, 2)
        w = rng.random(n) ** 3
        w /= w.sum()
        cand = np.arange(n)
        want = int(np.argmax(_reference_density(xy, w, cand, _bandwidth(xy, w))))
        assert kernel_mode_index(xy, w) == want


def test_candidates_limited_to_the_heaviest():
    rng = np.random.default_rng(12)
    xy = rng.normal(0.0, 10.0, (300, 2))
    w = rng.random(300)
    w /= w.sum()
    cand = np.argsort(-w, kind="stable")[:50]
    want = int(cand[np.argmax(_reference_density(xy, w, cand, _bandwidth(xy, w)))])
    assert kernel_mode_index(xy, w, max_points=50) == want
