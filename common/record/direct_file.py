"""An append-only file written around the page cache (``O_DIRECT``), for the recorder's raw video.

Writing 1280x720 RGB frames at 30 fps is 83 MB/s of new file data. Through the page cache every
4 KiB of it is a new cache page to allocate and fill: in ``bench --pipeline`` the kernel's copy
into the page cache (``copy_folio_from_iter_atomic``, seen with ``perf``) was three quarters of the
recorder's CPU, about 15 % of the whole machine, on these virtual machines, where fresh guest pages
are expensive. With ``O_DIRECT`` the disk reads the data straight from an aligned buffer here:
0.5 ms of kernel time per 2.7 MB frame against 3.1 ms through the cache (microbenchmark).

``O_DIRECT`` wants the buffer address, the length and the file offset aligned to the block size, and
MCAP records come in any length. So writes are collected in a page-aligned staging buffer; whole
blocks go to the file as soon as ``flush_bytes`` are staged (a raw frame at once, smaller chunks
a few at a time), the partial last block stays staged. ``flush()`` also writes that last block,
zero-padded, then cuts the file back to its exact length; the next write rewrites that block.
A process killed with SIGKILL therefore leaves everything written up to its last flush, plus the
whole blocks of later writes (the recorder flushes once a second; a reader stops at the cut).

Where the file system refuses ``O_DIRECT`` (tmpfs, some overlays) the file is an ordinary buffered
one, with the same interface.
"""

from __future__ import annotations

import errno
import mmap
import os

BLOCK = 4096
"""Alignment of buffer, length and offset (the largest logical block size in common use)."""


class DirectFile:
    """``write`` / ``tell`` / ``flush`` / ``close`` of a new file, through ``O_DIRECT`` where the
    file system allows it. ``direct`` says which way it is written."""

    def __init__(self, path: str, stage_bytes: int = 16 << 20, flush_bytes: int = 256 << 10):
        if stage_bytes % BLOCK or stage_bytes < 2 * BLOCK:
            raise ValueError(f"stage_bytes must be a multiple of {BLOCK} and at least {2 * BLOCK}")
        self.path = path
        self.flush_bytes = int(flush_bytes)
        self._stage = mmap.mmap(-1, stage_bytes)  # anonymous mappings are page-aligned
        self._view = memoryview(self._stage)
        self._fill = 0  # staged bytes
        self._base = 0  # file offset of the stage's first byte (a multiple of BLOCK)
        self.closed = False
        direct = getattr(os, "O_DIRECT", 0)  # not on macOS: a buffered file there
        self.direct = False
        if direct:
            try:
                self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | direct, 0o644)
                self.direct = True
            except OSError as exc:
                if exc.errno != errno.EINVAL:
                    raise
        if not self.direct:
            self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)

    def write(self, data) -> int:
        src = memoryview(data).cast("B")
        n = len(src)
        while len(src):
            room = len(self._stage) - self._fill
            k = min(room, len(src))
            self._view[self._fill:self._fill + k] = src[:k]
            self._fill += k
            src = src[k:]
            if self._fill == len(self._stage):
                self._write_blocks()
        if self._fill >= self.flush_bytes:
            self._write_blocks()
        return n

    def tell(self) -> int:
        return self._base + self._fill

    def _pwrite(self, length: int) -> None:
        """The stage's first ``length`` bytes (a multiple of BLOCK) at the stage's file offset."""
        done = 0
        while done < length:
            try:
                done += os.pwrite(self._fd, self._view[done:length], self._base + done)
            except OSError as exc:
                if exc.errno != errno.EINVAL or not self.direct:
                    raise
                self._reopen_buffered()  # the device wants a larger alignment: no O_DIRECT

    def _reopen_buffered(self) -> None:
        os.close(self._fd)
        self._fd = os.open(self.path, os.O_WRONLY)
        self.direct = False

    def _write_blocks(self) -> None:
        """Write the whole blocks staged; keep the partial last block at the stage's start."""
        full = self._fill // BLOCK * BLOCK
        if not full:
            return
        self._pwrite(full)
        tail = self._fill - full
        self._view[:tail] = self._view[full:self._fill]
        self._base += full
        self._fill = tail

    def flush(self) -> None:
        """Everything staged to the file: the last block zero-padded (rewritten by the next write),
        then the file cut back to its exact length, so that a reader of a killed writer's file
        finds no zeros after the last record."""
        self._write_blocks()
        if self._fill:
            self._view[self._fill:BLOCK] = bytes(BLOCK - self._fill)
            self._pwrite(BLOCK)
            os.ftruncate(self._fd, self._base + self._fill)

    def close(self) -> None:
        if self.closed:
            return
        try:
            self.flush()
            os.ftruncate(self._fd, self._base + self._fill)
        finally:
            os.close(self._fd)
            self._view.release()
            self._stage.close()
            self.closed = True

    def __enter__(self) -> "DirectFile":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
