"""Live Rerun from a run (`run --rerun spawn|connect URL|serve PORT|save PATH`): the viewer
service streams to a Rerun gRPC server as well as writing its .rrd. The server here is Rerun's
own, headless (`rerun --port P --save FILE`: it writes what it receives), on loopback; the
summary says how many frame images the .rrd kept; a bad mode is one line."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from services.cli import main
from services.commands.run import rerun_options
from services.launcher import free_ports

FRAMES = 8


def entities(rrd: Path) -> dict[str, int]:
    """Chunks per entity path of an .rrd, from `rerun rrd stats`."""
    out = subprocess.run([sys.executable, "-m", "rerun", "rrd", "stats", str(rrd)], capture_output=True, text=True,
                         timeout=120).stdout
    lines = out.split("Num chunks per entity", 1)[1].splitlines()[2:]  # after the title's underline
    block = lines[:lines.index("")] if "" in lines else lines
    return {line.rsplit(":", 1)[0].strip(): int(line.rsplit(":", 1)[1]) for line in block if ":" in line}


@contextlib.contextmanager
def rerun_server(live: Path):
    """Rerun's own headless gRPC server on a free loopback port, writing what it receives to
    ``live``; yields the URL to connect to, and stops it (what it received is then in the file)."""
    port = free_ports(1)[0]
    server = subprocess.Popen([sys.executable, "-m", "rerun", "--bind", "127.0.0.1", "--port", str(port),
                               "--save", str(live)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                              start_new_session=True)
    try:
        time.sleep(2.0)
        assert server.poll() is None
        yield f"rerun+http://127.0.0.1:{port}/proxy"
        time.sleep(1.0)
    finally:
        # `python -m rerun` runs the viewer binary as its child: stop the whole session's group, not
        # only the wrapper (the binary was left running, holding its port, after every run)
        try:
            os.killpg(server.pid, signal.SIGTERM)
        except ProcessLookupError:
            pass
        server.wait(30)


@pytest.mark.slow
def test_connect_streams_the_run_to_a_rerun_server_and_save_keeps_every_frame(tmp_path, capsys):
    live = tmp_path / "live.rrd"
    with rerun_server(live) as url:
        code = main(["run", "--source", "synthetic:3", "--frames", str(FRAMES), "--out-dir", str(tmp_path),
                     "--no-progress", "--rerun", "connect", url])
        out = capsys.readouterr().out
        assert code == 0, out
    got = entities(live)
    assert got.get("/camera/image", 0) >= 1 and got.get("/camera/estimate", 0) >= 1, got
    assert f"of {FRAMES} frame images kept" in out

    saved = tmp_path / "every.rrd"
    assert main(["run", "--source", "synthetic:3", "--frames", str(FRAMES), "--out-dir", str(tmp_path),
                 "--no-progress", "--rerun", "save", str(saved)]) == 0
    out = capsys.readouterr().out
    assert f"rerun:     {saved}" in out and f"{FRAMES} of {FRAMES} frame images kept\n" in out
    assert saved.exists()


@pytest.mark.parametrize("words, says", [(["connect", "http://x"], "a Rerun gRPC URL"), (["serve", "0"], "a port number"),
                                         (["save", "x.mcap"], "must end in .rrd"), (["fly"], "--rerun spawn |"),
                                         (["spawn", "a", "b"], "one argument at most")])
def test_bad_rerun_modes_are_one_line(words, says, capsys, tmp_path):
    assert main(["run", "--source", "synthetic:0", "--frames", "2", "--out-dir", str(tmp_path), "--rerun", *words]) == 2
    err = capsys.readouterr().err
    assert says in err and err.count("\n") == 1
    assert not list(tmp_path.iterdir())


def test_modes_map_to_the_viewer_settings():
    assert rerun_options(["spawn"]) == {"spawn": True}
    assert rerun_options(["connect"]) == {"rerun_connect": "rerun+http://127.0.0.1:9876/proxy"}
    assert rerun_options(["serve", "9000"]) == {"rerun_serve_port": 9000}
    assert rerun_options(["save", "a.rrd"]) == {"out": "a.rrd", "max_image_hz": 0.0}
    assert rerun_options(None) == {}


@pytest.mark.slow
def test_replay_streams_a_recording_to_a_rerun_server(tmp_path, capsys):
    rec_dir = tmp_path / "rec"
    assert main(["run", "--source", "synthetic:3", "--frames", "4", "--out-dir", str(rec_dir), "--no-progress",
                 "--no-viewer"]) == 0
    mcap = next(rec_dir.glob("*.mcap"))
    capsys.readouterr()
    live = tmp_path / "live.rrd"
    with rerun_server(live) as url:
        assert main(["replay", str(mcap), "--rerun", "connect", url]) == 0
        assert capsys.readouterr().out.startswith("sent ")
    got = entities(live)
    assert got.get("/camera/image", 0) >= 1 and got.get("/camera/estimate", 0) >= 1, got
    assert main(["replay", str(mcap), "--rerun", "connect", "--offline"]) == 2
    assert "--rerun sends the whole recording" in capsys.readouterr().err
