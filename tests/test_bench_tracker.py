"""bench --tracker: the real-footage profile in-process, re-acquisition on beside off, on the exit sequence."""

import json

from services.cli import main


def test_bench_tracker_reports_the_search_beside_a_run_without_it(capsys):
    assert main(["bench", "--tracker", "exit:0", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    on, off = out["reacquisition_on"], out["reacquisition_off"]
    assert out["frames"] == 112 and out["size"] == [1280, 720]
    # the car is out of the frame for 1.5 s and back on the left: searched while lost, one restart
    assert on["searching_frames"] > 10 and on["reacquisition"]["restarts"] == 1
    assert on["reacquisition"]["searched_frames"] == on["searching_frames"]
    assert on["reacquisition"]["ms_per_searched_frame"] > 0
    # negative control: without re-acquisition nothing is searched
    assert off["searching_frames"] == 0 and "reacquisition" not in off
    assert out["fps_ratio_on_off"] == round(on["fps"] / off["fps"], 3)
    assert out["source_fps"] == 10.0 and out["real_time_factor"] == round(on["fps"] / 10.0, 2)


def test_exit_source_at_another_frame_rate_has_the_same_events_in_seconds():
    """``exit:SEED:FPS``: three times the frames at 30 fps, the car out for the same 1.5 s; a bad FPS
    or an extra field is a one-line error saying the form."""
    import pytest

    from common.sources import SourceError, open_source

    a, b = open_source("exit:0"), open_source("exit:0:30")
    assert (a.fps, b.fps) == (10.0, 30.0)
    assert b.gap_frames / b.fps == a.gap_frames / a.fps == 1.5
    assert abs(b.exit_frame / b.fps - a.exit_frame / a.fps) <= 1.0 / a.fps
    assert abs(len(b) - 3 * len(a)) <= 3
    for bad in ("exit:0:0", "exit:0:fast", "exit:0:30:1", "zoom:0:30"):
        with pytest.raises(SourceError, match="use "):
            open_source(bad)


def test_bench_tracker_bad_source_is_one_line(capsys):
    assert main(["bench", "--tracker", "nowhere/at/all.mp4"]) == 2
    err = capsys.readouterr().err
    assert "no such file or folder" in err and len(err.strip().splitlines()) == 1
