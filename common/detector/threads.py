"""Hypotheses scored in parallel: fixed chunks on a small thread pool.

Each hypothesis is sampled on its own (its P-matrix and norm depend on its position alone), and
the compiled sampler releases the GIL, so splitting a batch into chunks on threads gives the same
numbers, bit for bit, as one call, whatever the number of threads. ``POLARTRACK_DETECTOR_THREADS``
sets the threads (default 2, the cores of the machines this runs on; 1 disables the pool).
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Callable

MIN_CHUNK = 64
"""Hypotheses per chunk at least: below this the hand-off costs more than it saves."""

_pool: ThreadPoolExecutor | None = None
_pool_pid = 0
_pool_lock = threading.Lock()


def _get_pool(threads: int) -> ThreadPoolExecutor:
    """This process's pool: a child forked after the pool started (evaluation workers) has none of
    its threads, so it gets a new one rather than waiting forever on the parent's. Its size is
    the thread count at its first use (a later count changes the chunks, not the workers)."""
    global _pool, _pool_pid
    with _pool_lock:
        if _pool is None or _pool_pid != os.getpid():
            _pool = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="polartrack-sampler")
            _pool_pid = os.getpid()
        return _pool


def thread_count() -> int:
    raw = os.environ.get("POLARTRACK_DETECTOR_THREADS", "2")
    try:
        n = int(raw)
    except ValueError:
        raise ValueError(f"POLARTRACK_DETECTOR_THREADS must be a whole number of threads, got {raw!r}") from None
    if n < 1:
        raise ValueError(f"POLARTRACK_DETECTOR_THREADS must be at least 1, got {n}")
    return n


def chunks(n: int, threads: int) -> list[tuple[int, int]]:
    """[a, b) ranges splitting ``n`` items into at most ``threads`` chunks of ``MIN_CHUNK`` or more."""
    k = max(1, min(threads, n // MIN_CHUNK))
    edges = [round(i * n / k) for i in range(k + 1)]
    return [(edges[i], edges[i + 1]) for i in range(k) if edges[i + 1] > edges[i]]


def run_chunks(fn: Callable[[int, int], None], n: int) -> None:
    """``fn(a, b)`` over the chunks of ``range(n)``: this thread takes the first, the pool the rest,
    and it returns when all are done (a worker's exception is raised here)."""
    threads = thread_count()
    parts = chunks(n, threads)
    futures = [_get_pool(threads).submit(fn, a, b) for a, b in parts[1:]]
    for a, b in parts[:1]:
        fn(a, b)
    for f in futures:
        f.result()
