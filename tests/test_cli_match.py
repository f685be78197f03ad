"""``polartrack match``: JSON output, the angle convention, and one-line errors with status 2."""

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from services.cli import main
from imagegen import blob_image


def _write(path: Path, img: np.ndarray) -> str:
    lo, hi = img.min(), img.max()
    u8 = ((img - lo) / (hi - lo) * 255).round().astype(np.uint8)
    cv2.imwrite(str(path), u8[:, :, ::-1])
    return str(path)


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    d = tmp_path_factory.mktemp("match")
    t = _write(d / "template.png", blob_image(0, channels=3, seed=3))
    r = _write(d / "rotated.png", blob_image(35, channels=3, seed=3))
    return t, r


def test_json_output(pair, capsys):
    t, r = pair
    assert main([ "match", r, "--template", t, "--template-at", "128,128", "--at", "128,128", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["angles_deg"][:3] == [0.0, 7.5, 15.0] and len(out["angles_deg"]) == 48
    assert len(out["scores"]) == 48
    assert abs(out["best_angle_deg"] - 35.0) < 2.0  # anticlockwise rotation of the target
    assert out["best_score"] > 0.85
    assert out["best_score"] >= max(out["scores"]) - 1e-6
    assert -180 < out["best_angle_deg"] <= 180


def test_clockwise_gives_negative_angle(tmp_path, capsys):
    t = _write(tmp_path / "t.png", blob_image(0, channels=3, seed=5))
    r = _write(tmp_path / "r.png", blob_image(-50, channels=3, seed=5))
    assert main(["match", r, "--template", t, "--template-at", "128,128", "--at", "128,128", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert abs(out["best_angle_deg"] + 50.0) < 2.0


@pytest.mark.parametrize("args, message", [
    (["missing.png", "--template", "{t}", "--template-at", "128,128", "--at", "128,128"], "no such file"),
    (["{notimage}", "--template", "{t}", "--template-at", "128,128", "--at", "128,128"], "not a readable image"),
    (["{r}", "--template", "{t}", "--template-at", "128,128", "--at", "900,10"], "outside the 256x256 image"),
    (["{r}", "--template", "{t}", "--template-at", "20,128", "--at", "128,128"], "within 64 px of the edge"),
])
def test_errors_are_one_line_with_status_2(pair, tmp_path, capsys, args, message):
    t, r = pair
    notimage = tmp_path / "notes.png"
    notimage.write_text("hello")
    argv = ["match"] + [a.format(t=t, r=r, notimage=notimage) for a in args]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err


def test_console_script_bad_point(pair):
    t, r = pair
    exe = Path(sys.executable).with_name("polartrack")
    proc = subprocess.run([str(exe), "match", r, "--template", t, "--template-at", "1,2,3", "--at", "128,128"],
                          capture_output=True, text=True)
    assert proc.returncode == 2
    assert "expected X,Y" in proc.stderr
