"""Zenoh's shared-memory segment files in /dev/shm, and removing the orphaned ones.

zenoh 1.10 creates a file per segment (``/dev/shm/<id>.zenoh``) and holds a shared advisory lock
(flock) on it in every process that uses it; it never removes them when a process exits (killed
or not), only at the start of the next process with shared memory, which removes the files
nobody holds a lock on. The launcher does the same after a run, once its services and router
have exited, so that a run leaves no segment behind, even with a service killed.
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

SHM_DIR = Path("/dev/shm")


def segment_files() -> set[str]:
    """Names of the Zenoh segment files present now."""
    try:
        return {p.name for p in SHM_DIR.glob("*.zenoh")}
    except OSError:
        return set()


def segments_mapped_by(pids) -> set[str]:
    """Names of the segment files that processes ``pids`` have mapped now (from /proc/PID/maps):
    the segments of one run, told apart from those of other runs on the same machine."""
    names: set[str] = set()
    for pid in pids:
        try:
            maps = Path(f"/proc/{int(pid)}/maps").read_text()
        except OSError:
            continue
        for line in maps.splitlines():
            fields = line.split(maxsplit=5)  # address perms offset dev inode [path]
            path = fields[5] if len(fields) == 6 else ""
            if path.startswith(str(SHM_DIR) + "/") and path.endswith(".zenoh"):
                names.add(Path(path).name)
    return names


def _orphaned(path: Path, remove: bool) -> bool:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # no process holds it
    except OSError:
        return False
    else:
        if remove:
            try:
                path.unlink()  # while holding the lock: no process takes it meanwhile
            except OSError:
                return False
        return True
    finally:
        os.close(fd)


def orphaned_segments() -> set[str]:
    """Segment files no live process holds (what a killed or exited process left behind)."""
    return {name for name in segment_files() if _orphaned(SHM_DIR / name, remove=False)}


def remove_orphaned_segments() -> list[str]:
    """Remove the segment files no live process holds, as Zenoh does at start-up; their names."""
    return sorted(name for name in segment_files() if _orphaned(SHM_DIR / name, remove=True))
