"""One OpenCV thread per service process by default.

The five services share the machine's cores; OpenCV starts a thread per core in every process,
and on a 2-core machine shared by five services that only adds switching. OpenCV's results here
do not depend on its thread count (see common/single_target/stabilise.py). BLAS is on one thread in every
process already (common/__init__.py: its results do depend on the count).
"""

from __future__ import annotations


def limit_threads(n: int) -> None:
    """OpenCV on ``n`` threads in this process (0: leave its default, a thread per core)."""
    if n <= 0:
        return
    import cv2

    cv2.setNumThreads(n)
