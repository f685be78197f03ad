"""Bad flags end in one line saying what is wrong, never a traceback, and a failed run writes nothing."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from services.cli import main
from services.launcher import free_ports

REPO = Path(__file__).resolve().parents[1]


def usage_error(argv, capsys) -> str:
    """The stderr of a command that must fail with exit status 2 (argparse's or ours)."""
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse reports its errors by exiting
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return err.strip().splitlines()[-1]


@pytest.mark.parametrize("command", [["track", "synthetic:0"], ["eval", "synthetic:0"], ["run", "synthetic:0"],
                                     ["study"], ["benchmark", "."]])
@pytest.mark.parametrize("frames", ["0", "-3"])
def test_frames_below_one_is_a_usage_error(command, frames, capsys):
    line = usage_error([*command, "--frames", frames], capsys)
    assert f"argument --frames: must be at least 1, got {int(frames)}" in line


@pytest.mark.parametrize("argv", [["track", "synthetic:0", "--seed", "-1"], ["demo", "--seed", "-4"],
                                  ["track", "synthetic:0", "--frames", "2", "--set", "seed=-1"]])
def test_a_negative_seed_is_a_usage_error(argv, capsys):
    line = usage_error(argv, capsys)
    assert "seed" in line and ("at least 0" in line or "greater than or equal to 0" in line)


def test_a_box_starting_with_a_minus_is_read_as_a_box(capsys):
    # argparse took "-20,-20,15,12" for an option ("expected one argument"); it is a box left of the frame
    line = usage_error(["track", "synthetic:0", "--frames", "2", "--no-progress", "--init", "-20,-20,15,12"], capsys)
    assert "--init -20,-20,15,12: the box centre (-12.5, -14) is outside the 1280x720 frame" in line


def test_a_failed_track_writes_no_header_and_no_file(tmp_path, capsys):
    out = tmp_path / "track.csv"
    argv = ["track", "synthetic:0", "--frames", "2", "--no-progress", "--init", "-30,1,15,12"]
    assert main([*argv, "--out", str(out)]) == 2
    assert "is outside the 1280x720 frame" in capsys.readouterr().err
    assert not out.exists()
    assert main(argv) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and "is outside the 1280x720 frame" in captured.err
    # the control: a good box writes the header and one row per frame
    assert main(["track", "synthetic:0", "--frames", "2", "--no-progress", "--out", str(out)]) == 0
    lines = out.read_text().splitlines()
    assert lines[0].startswith("frame,x,y,") and len(lines) == 3


def test_a_service_with_no_router_says_so_in_one_line():
    port = free_ports(1)[0]  # nothing listens there
    proc = subprocess.run([sys.executable, "-m", "services.detector", "--mode", "client", "--connect",
                           f"tcp/127.0.0.1:{port}"], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1
    lines = proc.stderr.strip().splitlines()
    assert "Traceback" not in proc.stderr and len(lines) == 1
    assert lines[0].startswith(f"detector: error: cannot join the Zenoh bus at tcp/127.0.0.1:{port}")
    assert "is the router running?" in lines[0]
