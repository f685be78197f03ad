"""Hypotheses sampled on several threads give the same P-matrices, bit for bit, as on one."""

import numpy as np
import pytest

from common.detector import PolarMatcher, Template, prepare_frame
from common.detector import threads
from services.commands.bench import _test_frame


def test_chunks_cover_every_hypothesis_once():
    for n in (0, 1, 63, 64, 127, 128, 500, 1001):
        for t in (1, 2, 3, 8):
            parts = threads.chunks(n, t)
            covered = [i for a, b in parts for i in range(a, b)]
            assert covered == list(range(n))
            assert len(parts) <= t
            assert all(b - a >= threads.MIN_CHUNK for a, b in parts) or len(parts) <= 1


def test_threads_give_identical_scores(monkeypatch):
    img = _test_frame(np.random.default_rng(5), 320, 256)
    matcher = PolarMatcher(Template.from_image(img, (160.0, 128.0)))
    prep = prepare_frame(img)
    rng = np.random.default_rng(6)
    hyps = np.c_[rng.uniform(40, 280, 700), rng.uniform(40, 216, 700), rng.uniform(-180, 180, 700)]
    results = {}
    for t in ("1", "2", "3"):
        monkeypatch.setenv("POLARTRACK_DETECTOR_THREADS", t)
        cols, norm2, valid = matcher.sample(prep, hyps[:, :2])
        scores, _ = matcher.score_at(prep, hyps)
        results[t] = (cols, norm2, scores)
    assert valid.sum() > 100 and (~valid).sum() > 10  # in and out of support
    for t in ("2", "3"):
        for a, b in zip(results["1"], results[t]):
            assert a.tobytes() == b.tobytes()


@pytest.mark.parametrize("raw", ["0", "two", "-1"])
def test_bad_thread_setting_is_explained(monkeypatch, raw):
    monkeypatch.setenv("POLARTRACK_DETECTOR_THREADS", raw)
    with pytest.raises(ValueError, match="POLARTRACK_DETECTOR_THREADS"):
        threads.thread_count()


def _score_in_child(queue):
    img = _test_frame(np.random.default_rng(5), 320, 256)
    matcher = PolarMatcher(Template.from_image(img, (160.0, 128.0)))
    rng = np.random.default_rng(6)
    hyps = np.c_[rng.uniform(80, 240, 300), rng.uniform(80, 176, 300), np.zeros(300)]
    scores, _ = matcher.score_at(prepare_frame(img), hyps)
    queue.put(scores.tobytes())


def test_forked_child_scores_with_its_own_threads(monkeypatch):
    """A process forked after the pool started (evaluation workers) has none of its threads: it
    must start its own instead of waiting forever, and score the same."""
    import multiprocessing

    monkeypatch.setenv("POLARTRACK_DETECTOR_THREADS", "2")
    ctx = multiprocessing.get_context("fork")
    parent = ctx.Queue()
    _score_in_child(parent)  # starts the pool in this process
    q = ctx.Queue()
    child = ctx.Process(target=_score_in_child, args=(q,))
    child.start()
    try:
        got = q.get(timeout=60)
    finally:
        child.join(timeout=10)
        if child.is_alive():
            child.kill()
    assert got == parent.get(timeout=5)
