"""Mapping in the Zenoh shared-memory segments at once (services/shm_populate.py)."""

import mmap
import os
import resource
import sys
import uuid
from pathlib import Path

import pytest

from services.shm_populate import SegmentPopulator

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux") or not Path("/dev/shm").is_dir(),
                                reason="Linux shared memory")

PAGES = 256


def _segment(name: str):
    path = Path("/dev/shm") / name
    fd = os.open(path, os.O_CREAT | os.O_RDWR, 0o600)
    os.ftruncate(fd, PAGES * 4096)
    m = mmap.mmap(fd, PAGES * 4096, mmap.MAP_SHARED)
    os.close(fd)
    return path, m


def _faults_reading(m) -> int:
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    total = sum(m[i * 4096] for i in range(PAGES))
    assert total == 0
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before


@pytest.mark.parametrize("write", [True, False])  # the publisher's, a subscriber's
def test_segments_are_mapped_in_once_and_other_files_left_alone(write):
    zpath, zm = _segment(f"{uuid.uuid4().int % 10**9}.zenoh")
    opath, om = _segment(f"polartrack-test-{uuid.uuid4().hex}")
    try:
        p = SegmentPopulator(write=write, calls=3)
        assert p.populate() >= PAGES  # this segment (and any other Zenoh segment mapped here)
        assert p.populate() == 0  # each mapping once
        # its pages are in: reading all 256 faults no more (ru_minflt counts the whole process, and
        # the interpreter itself can take a fault or two for a fresh heap page: seen once in a full run)
        assert _faults_reading(zm) <= 2
        assert _faults_reading(om) >= PAGES // 2  # negative control: a file that is not Zenoh's
        p.populate()
        assert p.calls_left == 0 and p.populate() == 0  # a bounded number of calls, then nothing
    finally:
        zm.close()
        om.close()
        zpath.unlink()
        opath.unlink()
