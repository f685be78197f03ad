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

import pytest

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


def test_the_turned_sequences_box_the_same_pixels(tmp_path):
    """``tools/stress_sequences.py --kinds turn90,turn180,mirror``: each derived frame's box covers
    the pixels the original box did, turned (within JPEG's loss; a box one pixel off does not)."""
    import cv2
    import numpy as np

    sys.path.insert(0, str(ROOT / "tools"))
    try:
        import stress_sequences
    finally:
        sys.path.remove(str(ROOT / "tools"))
    seq = tmp_path / "seq"
    (seq / "img").mkdir(parents=True)
    rng = np.random.default_rng(0)
    frames = []
    for i in range(2):  # JPEG, as UAV123's folders (the tool reads those); compared as read back
        im = cv2.resize(rng.uniform(0, 255, (12, 20, 3)).astype(np.uint8), (160, 96), interpolation=cv2.INTER_CUBIC)
        path = seq / "img" / f"{i + 1:06d}.jpg"
        cv2.imwrite(str(path), im, [cv2.IMWRITE_JPEG_QUALITY, 100])
        frames.append(cv2.imread(str(path)))
    (seq / "groundtruth_rect.txt").write_text("31,17,24,13\n90,40,30,20\n")
    assert stress_sequences.main([str(seq), "--out", str(tmp_path / "out"), "--kinds", "turn90,turn180,mirror"]) == 0
    turns = {"turn90": lambda a: cv2.rotate(a, cv2.ROTATE_90_CLOCKWISE),
             "turn180": lambda a: cv2.rotate(a, cv2.ROTATE_180), "mirror": lambda a: cv2.flip(a, 1)}
    boxes = [(31, 17, 24, 13), (90, 40, 30, 20)]
    for kind, turn in turns.items():
        out = tmp_path / "out" / f"seq-{kind}"
        rows = [[float(v) for v in line.split(",")] for line in (out / "groundtruth_rect.txt").read_text().split()]
        for i, ((x, y, w, h), row) in enumerate(zip(boxes, rows)):
            im = cv2.imread(str(out / "img" / f"{i + 1:06d}.jpg")).astype(float)
            want = turn(frames[i][y:y + h, x:x + w]).astype(float)
            bx, by, bw, bh = (int(round(v)) for v in row)
            assert (bh, bw) == want.shape[:2]
            err = {(dx, dy): np.abs(im[by + dy:by + dy + bh, bx + dx:bx + dx + bw] - want).mean()
                   for dx in (-1, 0, 1) for dy in (-1, 0, 1)}
            assert err[(0, 0)] < 6 and min(v for k, v in err.items() if k != (0, 0)) > 2 * err[(0, 0)], (kind, i, err)


def _benchmark(tmp_path, name, sequences):
    """A ``polartrack benchmark --json`` result holding ``sequences`` {name: (success, {seed: p20})}."""
    seqs = [{"sequence": seq, "trackers": {"polartrack": {
        "precision20": sum(p.values()) / len(p), "success_auc": success,
        "seeds": [{"seed": s, "precision20": v} for s, v in p.items()]}}} for seq, (success, p) in sequences.items()]
    path = tmp_path / name
    path.write_text(json.dumps({"sequences": seqs}))
    return str(path)


def test_compare_benchmarks_counts_the_seeds_that_moved(tmp_path, capsys):
    """``tools/compare_benchmarks.py``: per sequence the seeds up, down and identical against hand-made
    results, the mean over the sequences both sides hold, several files on one side read as one, and
    a file that is not a benchmark result a one-line error (exit 2)."""
    sys.path.insert(0, str(ROOT / "tools"))
    try:
        import compare_benchmarks as cb
    finally:
        sys.path.remove(str(ROOT / "tools"))
    before = _benchmark(tmp_path, "before.json", {"a": (0.5, {0: 1.0, 1: 0.7, 2: 0.9}), "b": (0.4, {0: 0.6, 1: 0.6})})
    extra = _benchmark(tmp_path, "extra.json", {"c": (0.3, {0: 0.2})})
    after = _benchmark(tmp_path, "after.json", {"a": (0.6, {0: 1.0, 1: 0.8, 2: 0.5}), "b": (0.4, {0: 0.6, 1: 0.6}),
                                                "d": (0.1, {0: 0.1})})
    result = cb.compare(cb.load([before, extra], "polartrack"), cb.load([after], "polartrack"))
    rows = {r["sequence"]: r for r in result["sequences"]}
    assert set(rows) == {"a", "b"}
    assert (rows["a"]["up"], rows["a"]["down"], rows["a"]["same"]) == (1, 1, 1)
    assert rows["a"]["moved"] == {1: [0.7, 0.8], 2: [0.9, 0.5]}
    assert (rows["b"]["up"], rows["b"]["down"], rows["b"]["same"]) == (0, 0, 2)  # identical: nothing moved
    assert result["mean"]["before"] == pytest.approx([(2.6 / 3 + 0.6) / 2, 0.45])
    assert result["mean"]["after"] == pytest.approx([(2.3 / 3 + 0.6) / 2, 0.5])
    assert result["only_before"] == ["c"] and result["only_after"] == ["d"]
    bad = tmp_path / "bad.json"
    bad.write_text('{"trackers": {}}')
    assert cb.main([str(bad), after]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "bad.json" in err and "\n" not in err


def test_the_trace_follows_a_synthetic_scene_from_its_own_truth():
    """``tools/trace_track.py`` on a built-in scene (its truth comes with each frame, not in a list):
    the car that leaves and comes back (exit:0) is traced from its first box, each requested frame
    printed against its truth, out-of-view frames apart from the scored ones (96 of 112 frames have
    the car in view; the car is re-acquired within 6 frames of being whole again at frame 63).
    ``--restarts`` reports that one restart, and no other: on a mover, inside the truth's box, at
    the truth's scale, its score set beside the scores held before the car left."""
    import re

    proc = subprocess.run([sys.executable, "tools/trace_track.py", "exit:0", "--frames", "80:80", "--restarts"],
                          cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = proc.stdout
    # scored as the benchmark scores it, the reported box's centre (fitted to the car's segment,
    # ``segment.centre_box``, within a few px of the MAP here), the MAP's error beside it
    row = re.search(r"^f80 est .* err\s+([\d.]+)(?: \(MAP ([\d.]+)\))? ", out, re.M)
    assert row is not None and float(row.group(1)) < 10.0
    assert row.group(2) is None or float(row.group(2)) < 5.0
    assert re.search(r"^  out  f4\d-f61 ", out, re.M)  # the car out of the frame: not scored
    prec = re.search(r"precision20 ([\d.]+) over (\d+) frames with a truth", out)
    assert prec is not None and int(prec.group(2)) == 96 and 0.9 < float(prec.group(1)) < 1.0
    restarts = re.findall(r"^  restart f(\d+) on a (mover|tile)( in doubt)?: at .*?, (inside|off) the truth's box, "
                          r"(\d+) px from its centre; score ([\d.]+), held before ([\d.]+) median, ([\d.]+) 10th "
                          r"percentile \((\d+) frames\); scale ([\d.]+), the truth's ([\d.]+) \(x([\d.]+)\)$",
                          out, re.M)
    assert len(restarts) == 1 and len(re.findall(r"^  restart ", out, re.M)) == 1
    frame, kind, doubt, where, off, score, median, p10, n, s, truth_s, ratio = restarts[0]
    assert 63 <= int(frame) <= 69 and kind == "mover" and not doubt and where == "inside" and int(off) < 5
    assert int(n) == 30 and float(p10) <= float(median) and 0.5 < float(score) <= 1.0
    assert abs(float(s) / float(truth_s) - float(ratio)) < 0.01 and 0.8 < float(ratio) < 1.25


def test_the_variant_probe_scores_a_run_as_the_trace_and_the_benchmark_do():
    """``tools/variant_probe.py`` with no variant is the product's run, scored as ``polartrack
    benchmark`` scores it: the reported box's centre over the frames with a truth, each frame's own
    (a built-in scene's truth comes with its frames). On the exit scene its precision@20 and frame
    count are the trace's to the last digit (96 of 112 frames have the car in view). Until stop 62
    it scored the MAP over a folder's truth list and could not run on a built-in scene at all."""
    import re

    probe = subprocess.run([sys.executable, "tools/variant_probe.py", "exit:0", "--seeds", "0"],
                           cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert probe.returncode == 0, probe.stderr[-2000:]
    row = re.search(r"^exit:0 seed 0 p20 ([\d.]+) over (\d+) frames per 100 frames \[(.*)\]$", probe.stdout, re.M)
    assert row is not None, probe.stdout[-2000:]
    trace = subprocess.run([sys.executable, "tools/trace_track.py", "exit:0", "--seed", "0"],
                           cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert trace.returncode == 0, trace.stderr[-2000:]
    prec = re.search(r"precision20 ([\d.]+) over (\d+) frames with a truth", trace.stdout)
    assert prec is not None and int(row.group(2)) == int(prec.group(2)) == 96
    assert float(row.group(1)) == pytest.approx(float(prec.group(1)), abs=5e-4) and 0.9 < float(row.group(1)) < 1.0
    assert len(row.group(3).split(",")) == 2  # frames 0-99 and 100-111
