"""DirectFile: the bytes written are the file's, whichever way (O_DIRECT or buffered) it was written."""

import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from common.record.direct_file import BLOCK, DirectFile


def _chunks(rng, total):
    out = []
    while total > 0:
        n = int(min(total, rng.choice([1, 7, 4095, 4096, 4097, 100_000, 2_764_800])))
        out.append(rng.integers(0, 256, n, dtype=np.uint8).tobytes())
        total -= n
    return out


@pytest.mark.parametrize("stage", [2 * BLOCK, 1 << 20])
def test_file_holds_exactly_what_was_written(tmp_path, stage):
    rng = np.random.default_rng(1)
    parts = _chunks(rng, 9_000_000)
    path = str(tmp_path / "f.bin")
    with DirectFile(path, stage_bytes=stage, flush_bytes=BLOCK * 3) as f:
        for i, p in enumerate(parts):
            assert f.write(p) == len(p)
            if i % 5 == 0:
                f.flush()  # padded last block, rewritten by the next write
            assert f.tell() == sum(len(q) for q in parts[: i + 1])
    data = open(path, "rb").read()
    assert data == b"".join(parts)


def test_flushed_bytes_survive_sigkill(tmp_path):
    """A writer killed with SIGKILL after a flush leaves exactly its bytes."""
    path = tmp_path / "k.bin"
    code = (f"import os, signal; from common.record.direct_file import DirectFile\n"
            f"f = DirectFile({str(path)!r})\n"
            f"f.write(bytes(range(256)) * 1000 + b'end')\n"
            f"f.flush()\n"
            f"os.kill(os.getpid(), signal.SIGKILL)\n")
    proc = subprocess.run([sys.executable, "-c", code], cwd=os.path.dirname(os.path.dirname(__file__)))
    assert proc.returncode == -signal.SIGKILL
    want = bytes(range(256)) * 1000 + b"end"
    assert path.read_bytes() == want  # the flush cut the padding off: no zeros after the data


def test_file_system_without_o_direct_falls_back(tmp_path, monkeypatch):
    """open() refusing O_DIRECT (EINVAL): an ordinary file, same bytes."""
    import errno

    real_open = os.open

    def no_direct(path, flags, *a):
        if flags & os.O_DIRECT:
            raise OSError(errno.EINVAL, "Invalid argument")
        return real_open(path, flags, *a)

    monkeypatch.setattr(os, "open", no_direct)
    path = str(tmp_path / "b.bin")
    with DirectFile(path) as f:
        assert f.direct is False
        f.write(b"x" * 5000)
        f.flush()
        f.write(b"y")
    assert open(path, "rb").read() == b"x" * 5000 + b"y"


def test_device_refusing_the_alignment_falls_back(tmp_path, monkeypatch):
    """pwrite() refusing the 4 KiB alignment (EINVAL) on an O_DIRECT file: reopened buffered, nothing lost."""
    import errno

    real_pwrite = os.pwrite
    calls = []

    def picky(fd, data, offset):
        calls.append(offset)
        if len(calls) == 2:
            raise OSError(errno.EINVAL, "Invalid argument")
        return real_pwrite(fd, data, offset)

    path = str(tmp_path / "c.bin")
    probe = DirectFile(path)
    probe.close()
    if not probe.direct:
        pytest.skip("this file system has no O_DIRECT")
    monkeypatch.setattr(os, "pwrite", picky)
    want = bytes(range(256)) * 3000
    with DirectFile(path, flush_bytes=BLOCK) as f:
        for i in range(0, len(want), 10_000):
            f.write(want[i:i + 10_000])
        assert f.direct is False
    assert open(path, "rb").read() == want


def test_bad_stage_size_is_refused(tmp_path):
    with pytest.raises(ValueError, match="multiple of 4096"):
        DirectFile(str(tmp_path / "x"), stage_bytes=5000)
