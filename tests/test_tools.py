"""The diagnostic scripts in ``tools/`` still start against the library as it is now.

They are not part of the product and no other test runs them, so a renamed library function
breaks them silently (``tools/match_probe.py`` imported a scale helper that had been renamed, and
was found broken only when a later probe needed it). Each is run with ``--help`` in one child
process: it must import, parse its arguments and print its usage, exiting 0."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TOOLS = sorted(p.name for p in (ROOT / "tools").glob("*.py"))

_CHILD = r"""
import contextlib, io, json, runpy, sys
out = {}
for name in sys.argv[1:]:
    sys.argv = [name, "--help"]
    buf = io.StringIO()
    try:
        with contextlib.redirect_stdout(buf):
            runpy.run_path("tools/" + name, run_name="__main__")
        code = "returned without exiting"
    except SystemExit as e:
        code = e.code
    except BaseException as e:  # an import error, a renamed function: what this test is for
        code = f"{type(e).__name__}: {e}"
    out[name] = [code, buf.getvalue()[:200]]
print(json.dumps(out))
"""


def test_every_tool_starts_and_prints_its_usage():
    assert len(TOOLS) >= 10  # the glob found the folder
    proc = subprocess.run([sys.executable, "-c", _CHILD, *TOOLS], cwd=ROOT, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    broken = {name: code for name, (code, text) in result.items() if code not in (0, None) or "usage:" not in text}
    assert broken == {}
