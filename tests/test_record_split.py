"""Recordings split by size or duration (rosbag2's --max-bag-size / --max-bag-duration): each
part is a whole MCAP file with the run's metadata that reads, summarises and republishes alone;
splits fall before a frame image; the parts together hold every frame and estimate once."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from common.msgs.image_wire import decode_frame
from common.record.info import recording_info
from common.record.reader import read_recording
from common.record.writer import SplitSink

SOURCE = "synthetic:3"
FRAMES = 12


def test_split_sink_by_duration_before_frame_images(tmp_path):
    """Messages at 10 Hz for 3 s, a 1-second limit: parts of 10 frames each, every frame's image
    and info in one part, the run metadata in every part, each part's own counts."""
    path = str(tmp_path / "r.mcap")
    sink = SplitSink(path, "lz4", 1 << 16, max_duration_ns=10**9)
    sink.metadata("run", {"source": "x"})
    for i in range(30):
        ns = 10**9 + i * 10**8
        sink.write("frame/image", b"", ns, ns)
        sink.write("frame/info", b"", ns, ns)
    sink.close()
    assert sink.paths == [path] + [str(tmp_path / f"r.split{k}.mcap") for k in (1, 2)]
    for p in sink.paths:
        info = recording_info(p)
        assert info.complete and info.messages == 20 and info.metadata["run"] == {"source": "x"}
        assert info.metadata["recorder"]["count:frame/image"] == "10"
        assert info.duration_s == pytest.approx(0.9)


@pytest.mark.slow
def test_a_split_run_replays_part_by_part(tmp_path, capsys, synthetic_pipeline):
    from services.cli import main

    with synthetic_pipeline(SOURCE, FRAMES, seed=3, recorder_options={"max_size_mb": 8.0}) as pipe:
        result = pipe.run(progress=False, timeout=240)
    assert result.ok and result.estimates == FRAMES
    parts = result.recordings
    assert len(parts) >= 3 and parts[0] == result.mcap and all(".split" in Path(p).name for p in parts[1:])
    frames, estimates = [], []
    for p in parts:
        assert Path(p).stat().st_size < 8e6 + 4e6  # the limit plus a frame and its chunk
        rec = read_recording(p)  # no warning: a whole file
        assert json.loads(rec.run["init_box"]) == list(pipe.init_box)
        frames += [decode_frame(data)[0] for _, data in rec.messages["frame/image"]]
        estimates += [e.frame_index for e in rec.decoded("track/estimate")]
        assert main(["replay", p, "--max", "--json"]) == 0
        out = json.loads(capsys.readouterr().out)
        assert out["messages"] == sum(rec.counts.values())
    assert frames == list(range(FRAMES)) and sorted(estimates) == list(range(FRAMES))


@pytest.mark.parametrize("flag", ["--max-size", "--max-duration"])
def test_a_non_positive_split_is_one_line(flag, capsys, tmp_path):
    from services.cli import main

    assert main(["run", "--source", "synthetic:0", "--frames", "2", "--out-dir", str(tmp_path), flag, "0"]) == 2
    err = capsys.readouterr().err
    assert f"{flag} must be positive" in err and err.count("\n") == 1
    assert not list(tmp_path.iterdir())  # nothing started, nothing written
