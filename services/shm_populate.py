"""Map in every page of the Zenoh shared-memory segments a process uses, once, at the start.

A frame travels through a 96 MiB segment that each process maps lazily: the first time the
publisher writes a page, and the first time each subscriber reads one, costs a page fault, and on
these virtual machines a fault costs tens of microseconds. Until the pool had been used all
through, every frame cost the ingest ~700 faults (a 2.7 MB put took up to 35 ms instead of 1) and
the detector ~1000 (a 160 px region took 60 ms to prepare instead of 8), so the first second
of a live run fell behind and the tracker skipped frames. ``madvise(MADV_POPULATE_READ/WRITE)``
(Linux 5.14) maps a whole segment in one call instead. Elsewhere it does nothing.
"""

from __future__ import annotations

import ctypes
import logging
import sys

log = logging.getLogger("polartrack.shm")

MADV_POPULATE_READ = 22
MADV_POPULATE_WRITE = 23


def _mappings() -> list[tuple[int, int, str]]:
    """(start, end, path) of this process's mappings of Zenoh segment files."""
    out = []
    try:
        with open("/proc/self/maps") as fh:
            for line in fh:
                fields = line.split(maxsplit=5)
                if len(fields) == 6 and ".zenoh" in fields[5] and fields[5].startswith("/dev/shm/"):
                    a, b = (int(v, 16) for v in fields[0].split("-"))
                    out.append((a, b, fields[5].strip()))
    except OSError:
        pass
    return out


class SegmentPopulator:
    """``populate()`` maps in the segments this process has mapped since the last call (each once);
    ``write=True`` for the publisher, whose pages are then also allocated. Call it after the first
    few frames (a subscriber maps a segment when the first frame arrives through it)."""

    def __init__(self, write: bool = False, calls: int = 8):
        self.advice = MADV_POPULATE_WRITE if write else MADV_POPULATE_READ
        self.calls_left = calls if sys.platform.startswith("linux") else 0
        self.done: set[tuple[int, int]] = set()
        self.pages = 0
        self._madvise = None

    def populate(self) -> int:
        """Pages mapped in by this call (0 once ``calls`` calls have been made)."""
        if self.calls_left <= 0:
            return 0
        self.calls_left -= 1
        if self._madvise is None:
            libc = ctypes.CDLL(None, use_errno=True)
            self._madvise = libc.madvise
            self._madvise.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
        pages = 0
        for a, b, path in _mappings():
            if (a, b) in self.done:
                continue
            self.done.add((a, b))
            if self._madvise(a, b - a, self.advice) != 0:
                err = ctypes.get_errno()
                log.debug("madvise(%s) on %s: errno %d (an older kernel: pages fault in as used)",
                          self.advice, path, err)
                continue
            pages += (b - a) // 4096
        if pages:
            log.info("mapped in %d pages of shared memory", pages)
        self.pages += pages
        return pages
