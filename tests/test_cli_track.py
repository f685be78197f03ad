"""polartrack track / eval end to end on a short synthetic scene, and bad input."""

import csv
import json

import numpy as np
import pytest

from services.cli import main
from common.sources import open_source


@pytest.fixture(scope="module")
def short_track(tmp_path_factory):
    out = tmp_path_factory.mktemp("track") / "run.csv"
    assert main(["track", "synthetic:2", "--frames", "40", "--out", str(out), "--no-progress"]) == 0
    with open(out) as fh:
        rows = list(csv.DictReader(fh))
    return rows


def test_track_csv_and_accuracy(short_track):
    rows = short_track
    assert list(rows[0].keys()) == ["frame", "x", "y", "theta_deg", "p_visible", "w", "h", "box_x", "box_y"]
    assert [int(r["frame"]) for r in rows] == list(range(40))
    src = open_source("synthetic:2", n_frames=40)
    errs = [np.hypot(float(r["x"]) - src.true_centre(i)[0], float(r["y"]) - src.true_centre(i)[1])
            for i, r in enumerate(rows)]
    assert max(errs) < 5.0
    assert all(float(r["p_visible"]) > 0.9 for r in rows)
    # theta follows the car's rotation relative to the first frame
    t0 = src.frame(0).truth.angle_deg
    true_rel = (src.frame(39).truth.angle_deg - t0 + 180) % 360 - 180
    assert abs((float(rows[39]["theta_deg"]) - true_rel + 180) % 360 - 180) < 6.0


def test_track_csv_boxes_against_truth(short_track):
    """The oriented box (x, y, w, h, theta_deg) turned into its axis-aligned envelope overlaps the
    synthetic car's true axis-aligned body box; a box of the wrong size is the negative control."""
    from common.tracking.state import oriented_to_axis_aligned

    src = open_source("synthetic:2", n_frames=40)

    def iou(a, b):
        ix = max(0.0, min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0]))
        iy = max(0.0, min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1]))
        inter = ix * iy
        return inter / (a[2] * a[3] + b[2] * b[3] - inter)

    ious, wrong = [], []
    for i, r in enumerate(rows := short_track):
        x, y, w, h, th = (float(r[k]) for k in ("x", "y", "w", "h", "theta_deg"))
        truth = src.frame(i).truth.box
        ious.append(iou(oriented_to_axis_aligned(x, y, w, h, th), truth))
        wrong.append(iou(oriented_to_axis_aligned(x, y, 2.5 * w, 2.5 * h, th), truth))
    assert float(rows[0]["w"]) == pytest.approx(src.frame(0).truth.box[2], abs=1e-3)
    assert np.median(ious) > 0.6
    assert np.median(wrong) < 0.3


def test_track_is_deterministic(short_track, tmp_path):
    out = tmp_path / "again.csv"
    assert main(["track", "synthetic:2", "--frames", "40", "--out", str(out), "--no-progress"]) == 0
    with open(out) as fh:
        assert list(csv.DictReader(fh)) == short_track


def test_eval_json(tmp_path, capsys):
    assert main(["eval", "synthetic:2", "--frames", "30", "--filter", "rbpf,ml", "--json", "--no-progress",
                 "--out-dir", str(tmp_path)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out["filters"]) == {"rbpf", "ml"}
    assert out["precision20"] == out["filters"]["rbpf"]["precision20"] == 1.0
    assert 0.8 < out["auc50"] <= 1.0 and out["mean_err"] < 3.0 and out["fps"] > 0
    assert (tmp_path / "errors.png").exists()
    # the table says the same figures
    assert main(["eval", "synthetic:2", "--frames", "30", "--filter", "rbpf,ml", "--no-progress",
                 "--out-dir", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    rows = {line.split("│")[1].strip(): line for line in text.splitlines() if line.count("│") > 4}
    assert f"{out['filters']['ml']['precision20']:.3f}" in rows["ml"] and f"{out['mean_err']:.2f}" in rows["rbpf"]


@pytest.mark.parametrize("argv, message", [
    (["track", "synthetic:1", "--frames", "3", "--init", "5000,10,40,20"], "outside the 1280x720 frame"),
    (["track", "synthetic:1", "--frames", "3", "--init", "600,300,-4,20"], "must be positive"),
    (["track", "nowhere/at/all.mp4"], "no such file or folder"),
    (["eval", "synthetic:1", "--filter", "rbpf,kalman"], "unknown filter"),
])
def test_bad_input_is_a_clear_error(capsys, argv, message):
    assert main(argv + ["--no-progress"]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_unreadable_video_and_mismatched_folder(tmp_path, capsys):
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(b"garbage" * 50)
    assert main(["track", str(bad), "--init", "1,1,5,5", "--no-progress"]) == 2
    assert "not a readable video" in capsys.readouterr().err
    d = tmp_path / "seq"
    (d / "img").mkdir(parents=True)
    import cv2

    cv2.imwrite(str(d / "img" / "000001.jpg"), np.zeros((200, 200, 3), np.uint8))
    (d / "groundtruth_rect.txt").write_text("1,1,5,5\n2,2,5,5\n")
    assert main(["eval", str(d), "--no-progress"]) == 2
    assert "2 boxes but img/ has 1 frames" in capsys.readouterr().err
    # a black first frame: nothing to build the template from, one line (not a traceback, nor an
    # all-zero template tracked on)
    cv2.imwrite(str(d / "img" / "000001.png"), np.zeros((200, 200, 3), np.uint8))
    (d / "img" / "000001.jpg").unlink()
    (d / "groundtruth_rect.txt").write_text("90,90,20,20\n")
    assert main(["track", str(d), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "template region is flat" in err and "start from a frame where the target is visible" in err
    assert err.count("\n") == 1
    (d / "img" / "000001.png").unlink()
    noise = np.random.default_rng(0).integers(0, 256, (200, 200, 3), dtype=np.uint8)
    cv2.imwrite(str(d / "img" / "000001.jpg"), noise)
    (d / "groundtruth_rect.txt").write_text("90,90,20,20\n90,90,20,20\n")
    # a frame of another size: one line naming it, not the optical flow's traceback
    cv2.imwrite(str(d / "img" / "000002.jpg"), np.zeros((160, 240, 3), np.uint8))
    assert main(["track", str(d), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "000002.jpg: 240x160 pixels, the folder's other frames 200x200" in err and err.count("\n") == 1
