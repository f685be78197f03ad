"""kernel_mode_index (compiled kernel density) picks the mode of the NumPy expression it replaced."""

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


def test_compiled_density_equals_the_numpy_sum():
    """Both loops (all points, symmetric; given candidates) against the matrix expression, with
    a far point whose kernel underflows to exactly zero (the skipped terms)."""
    from common.tracking.kernel_density import kernel_density

    rng = np.random.default_rng(13)
    xy = np.vstack([rng.normal(0.0, 3.0, (120, 2)), [[1e4, -1e4]]])
    w = rng.random(121)
    w /= w.sum()
    h2 = 2.5
    cand = np.array([120, 3, 0, 77])
    want = _reference_density(xy, w, np.arange(121), h2)
    np.testing.assert_allclose(kernel_density(xy, w, h2), want, rtol=1e-12, atol=0)
    np.testing.assert_allclose(kernel_density(xy, w, h2, cand), want[cand], rtol=1e-12, atol=0)
    assert kernel_density(xy, w, h2)[120] == w[120]  # only its own kernel: the others underflow
