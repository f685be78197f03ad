"""PolarTrack's library (no bus code).

BLAS runs on one thread in every process that imports it. OpenBLAS's results depend on its
thread count (it takes another kernel path: scores, and so estimates, differ in the last bits),
and its default is a thread per core, so the same run would give other estimates on another
machine, or in a process set up otherwise. One thread everywhere keeps in-process, multi-process
and replayed runs bit-identical on any machine. It is faster here too: the matrices are small,
and idle OpenBLAS threads spin-wait, which more than doubled the detector service's CPU per frame
on a 2-core machine (bench --pipeline --pace consumer: 80 -> 30 ms).
"""

import numpy  # noqa: F401  (loads NumPy's OpenBLAS, so that the limit below applies to it)
from threadpoolctl import threadpool_limits

_BLAS_THREADS = threadpool_limits(1, user_api="blas")
