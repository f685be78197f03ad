"""polartrack benchmark: the shared scorer against hand-computed cases, the command end to end on a
tiny sequence folder written here, its bad-input errors, and (where an isolated OpenCV-contrib
environment can be made offline) the peers' subprocess."""

import json
import math
import shutil
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from common.evaluation.benchmark import (PER_FRAME_COLUMNS, SUCCESS_THRESHOLDS, box_iou, mean_scores,
                                         mean_standard_errors, score_boxes, seed_standard_errors,
                                         success_curve, write_per_frame)
from services.cli import main
from common.evaluation import precision_curve
from common.sources import SyntheticSource

from imagegen import DATA, REPO

MODELS = REPO.parent / "shared" / "models" / "nanotrack-v2"
NAN = (np.nan,) * 4


# ----- the scorer ---------------------------------------------------------------------------------

def test_iou_known_cases():
    a = np.array([[0, 0, 4, 4], [0, 0, 4, 4], [0, 0, 4, 4], [0, 0, 4, 4], [0, 0, 2, 2], [0, 0, 4, 4]], float)
    b = np.array([[2, 2, 4, 4],  # 2x2 overlap of two 4x4: 4 / (16 + 16 - 4) = 1/7
                  [0, 0, 4, 4],  # identical
                  [4, 0, 4, 4],  # touching edges only
                  [1, 0, 2, 4],  # inside: 8 / 16
                  [10, 10, 0, 0],  # no area, apart
                  NAN], float)
    iou = box_iou(a, b)
    assert iou[:5] == pytest.approx([1 / 7, 1.0, 0.0, 0.5, 0.0])
    assert np.isnan(iou[5])
    assert box_iou(b[:1], a[:1]) == pytest.approx(1 / 7)  # symmetric


def test_precision_curve_by_hand():
    e = np.array([0.0, 10.0, 20.0, 30.0, 60.0])
    curve = precision_curve(e)
    assert curve[20] == pytest.approx(3 / 5) and curve[9] == pytest.approx(1 / 5) and curve[50] == pytest.approx(4 / 5)
    # thresholds 0..50: 0 counts at all 51, 10 at 41, 20 at 31, 30 at 21, 60 at none
    assert curve.mean() == pytest.approx((51 + 41 + 31 + 21) / (5 * 51))
    assert precision_curve(np.array([np.nan, 0.0]))[0] == 0.5  # no estimate: a miss


def test_success_curve_and_auc_by_hand():
    assert len(SUCCESS_THRESHOLDS) == 21 and SUCCESS_THRESHOLDS[1] == pytest.approx(0.05)
    ious = np.array([1.0, 0.52, 1 / 7, 0.0])
    s = success_curve(ious)
    # IoU 1 is above 20 thresholds (not 1.0 itself), 0.52 above 11 (0..0.5), 1/7 above 3, 0 above none
    assert s.mean() == pytest.approx((20 + 11 + 3 + 0) / (4 * 21))
    assert s[0] == pytest.approx(3 / 4) and s[-1] == 0.0
    assert success_curve(np.array([np.nan]))[0] == 0.0  # no box: a miss


def test_per_frame_csv_by_hand(tmp_path):
    """Three frames: a box half off the truth (centre error 5 px, IoU 50/150), no box (a miss), no truth
    (not scored); with a second run written after the first."""
    truth = [(0, 0, 10, 10), (0, 0, 10, 10), None]
    a = [(5, 0, 10, 10), (np.nan,) * 4, (1, 1, 2, 2)]
    b = [(0, 0, 10, 10)] * 3
    path = tmp_path / "f.csv"
    write_per_frame(path, truth, [("mine", 3, a, score_boxes(a, truth)), ("peer", None, b, score_boxes(b, truth))])
    rows = read_per_frame(path)
    got = [(r["tracker"], r["seed"], r["frame"], r["x"], r["truth_w"], r["centre_error"], r["iou"]) for r in rows]
    assert got[:3] == [("mine", "3", "0", "5.0", "10.0", "5.0", repr(50 / 150)), ("mine", "3", "1", "", "10.0", "", "0.0"),
                       ("mine", "3", "2", "1.0", "", "", "")]
    assert got[3:] == [("peer", "", "0", "0.0", "10.0", "0.0", "1.0"), ("peer", "", "1", "0.0", "10.0", "0.0", "1.0"),
                       ("peer", "", "2", "0.0", "", "", "")]
    with pytest.raises(ValueError, match="2 boxes for 3"):
        write_per_frame(path, truth, [("short", None, a[:2], score_boxes(b, truth))])


def test_score_boxes_excludes_frames_without_truth():
    truth = [(0, 0, 4, 4), (0, 0, 4, 4), None, (0, 0, 4, 4), (0, 0, 4, 4)]
    boxes = [(0, 0, 4, 4),      # IoU 1, error 0
             (2, 2, 4, 4),      # IoU 1/7, error sqrt(8)
             (500, 500, 4, 4),  # far off, but the target is not visible here: not scored
             (100, 100, 4, 4),  # IoU 0, error 141: lost
             NAN]               # no box: lost
    sc = score_boxes(boxes, truth)
    assert (sc.frames, sc.visible_frames) == (5, 4)
    assert sc.precision20 == pytest.approx(2 / 4)
    assert sc.auc50 == pytest.approx((51 + 48 + 0 + 0) / (4 * 51))  # sqrt(8) = 2.83 is within 3..50
    assert sc.success_auc == pytest.approx((20 + 3) / (4 * 21))
    assert sc.frames_lost == 2
    assert sc.mean_err == pytest.approx(np.mean([0, np.sqrt(8), np.hypot(100, 100)]))
    assert np.isnan(sc.ious[2]) and np.isnan(sc.errors[2])
    # negative control: the same far-off box on a frame with truth counts against the tracker
    sc2 = score_boxes(boxes, [(0, 0, 4, 4)] * 5)
    assert sc2.visible_frames == 5 and sc2.frames_lost == 3 and sc2.precision20 == pytest.approx(2 / 5)
    with pytest.raises(ValueError):
        score_boxes(boxes[:3], truth)


def test_mean_over_sequences():
    m = mean_scores([{"precision20": 1.0, "fps": 10.0, "frames_lost": 0}, {"precision20": 0.5, "fps": 30.0, "frames_lost": 3}])
    assert m == {"precision20": 0.75, "frames_lost": 1.5, "fps": 20.0, "sequences": 2}
    # a failed run has no fps: the mean is the others'
    m = mean_scores([{"precision20": 1.0, "fps": 10.0}, {"precision20": 0.5, "fps": None}])
    assert m == {"precision20": 0.75, "fps": 10.0, "sequences": 2}


def test_standard_errors_over_seeds_by_hand():
    """Three seeds at 0.5, 0.7, 0.9: sample standard deviation 0.2, standard error 0.2 / sqrt(3);
    one seed has no spread to report (negative control); the mean over two sequences with standard
    errors 0.03 and 0.04 has sqrt(0.03^2 + 0.04^2) / 2 = 0.025, and none when a sequence lacks one."""
    per_seed = [{"precision20": v, "auc50": 0.6, "success_auc": v / 2} for v in (0.5, 0.7, 0.9)]
    se = seed_standard_errors(per_seed)
    assert se == {"precision20_se": round(0.2 / math.sqrt(3), 4), "auc50_se": 0.0,
                  "success_auc_se": round(0.1 / math.sqrt(3), 4)}
    assert seed_standard_errors(per_seed[:1]) == {}
    assert mean_standard_errors([{"precision20_se": 0.03}, {"precision20_se": 0.04}]) == {"precision20_se": 0.025}
    assert mean_standard_errors([{"precision20_se": 0.03}, {"precision20": 0.9}]) == {}


# ----- the command --------------------------------------------------------------------------------

def write_sequence(folder: Path, n: int = 12, nan_rows: tuple[int, ...] = (), extra_lines: int = 0,
                   seed: int = 0) -> Path:
    """``n`` frames of the synthetic scene ``seed`` as JPEGs under ``folder/img`` and their truth
    boxes (0-based) as ``groundtruth_rect.txt``, NaN on ``nan_rows``."""
    src = SyntheticSource(seed=seed, n_frames=n)
    (folder / "img").mkdir(parents=True)
    lines = []
    for i in range(n):
        f = src.frame(i)
        cv2.imwrite(str(folder / "img" / f"{i + 1:04d}.jpg"), f.image[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 95])
        box = None if i in nan_rows else f.truth.box
        lines.append("NaN,NaN,NaN,NaN" if box is None else ",".join(f"{v:.2f}" for v in box))
    lines += ["1,1,5,5"] * extra_lines
    (folder / "groundtruth_rect.txt").write_text("\n".join(lines) + "\n")
    return folder


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    return write_sequence(tmp_path_factory.mktemp("bench") / "carseq", nan_rows=(6,))


def test_benchmark_end_to_end(sequence, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["benchmark", str(sequence), "--json", "--out", str(out), "--frames", "10", "--no-progress"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["trackers"] == ["polartrack"]
    (row,) = res["sequences"]
    assert (row["sequence"], row["frames"], row["visible_frames"]) == ("carseq", 10, 9)  # frame 6 has NaN truth
    pt = row["trackers"]["polartrack"]
    assert set(pt) >= {"precision20", "auc50", "success_auc", "mean_err", "frames_lost", "fps", "visible_frames"}
    assert pt["visible_frames"] == 9
    assert pt["precision20"] == 1.0 and pt["frames_lost"] == 0 and pt["fps"] > 0
    assert pt["mean_err"] < 5.0
    # the axis-aligned box overlaps the car's box; no IoU passes the last threshold, 1 (the AUC is rounded)
    assert 0.5 < pt["success_auc"] <= round(20 / 21, 4)
    assert res["mean"]["polartrack"]["precision20"] == pt["precision20"] and res["mean"]["polartrack"]["sequences"] == 1
    for path in (res["plots"]["precision"], res["plots"]["success"], res["plots"]["errors"]["carseq"]):
        assert Path(path).is_file() and Path(path).stat().st_size > 1000
    assert json.loads((out / "benchmark.json").read_text())["sequences"][0]["trackers"] == row["trackers"]
    # every frame's box and score: the CSV's own columns give its errors and IoUs, and they give the figures
    rows = read_per_frame(res["per_frame"]["carseq"])
    assert [r["frame"] for r in rows] == [str(i) for i in range(10)] and {r["tracker"] for r in rows} == {"polartrack"}
    assert [float(rows[0][k]) for k in ("truth_x", "truth_y", "truth_w", "truth_h")] == row["init_box"]
    assert rows[6]["truth_x"] == rows[6]["centre_error"] == rows[6]["iou"] == ""  # no truth: not scored
    scored = [r for r in rows if r["centre_error"] != ""]
    assert len(scored) == 9
    for r in scored:
        x, y, w, h, tx, ty, tw, th = (float(r[k]) for k in ("x", "y", "w", "h", "truth_x", "truth_y", "truth_w", "truth_h"))
        assert float(r["centre_error"]) == pytest.approx(math.hypot(x + w / 2 - tx - tw / 2, y + h / 2 - ty - th / 2), abs=1e-9)
        ix = max(0.0, min(x + w, tx + tw) - max(x, tx))
        iy = max(0.0, min(y + h, ty + th) - max(y, ty))
        assert float(r["iou"]) == pytest.approx(ix * iy / (w * h + tw * th - ix * iy), abs=1e-9)
    errors = np.array([float(r["centre_error"]) for r in scored])
    assert pt["mean_err"] == pytest.approx(errors.mean(), abs=1e-3)
    assert pt["precision20"] == pytest.approx(np.mean(errors <= 20), abs=1e-4)
    assert pt["frames_lost"] == sum(float(r["iou"]) <= 0 for r in scored)


def read_per_frame(path) -> list[dict]:
    import csv

    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    assert rows and list(rows[0]) == list(PER_FRAME_COLUMNS)
    return rows


def test_benchmark_over_seeds(sequence, tmp_path, capsys):
    """--seeds 3: PolarTrack's figures are the mean of its three seeds' (listed under 'seeds'), the
    first seed's run is the one --seed alone gives, and the seeds' runs differ (a real spread)."""
    base = ["benchmark", str(sequence), "--json", "--frames", "8", "--no-progress", "--set", "rbpf.n_particles=20"]
    assert main([*base, "--out", str(tmp_path / "a"), "--seed", "4", "--seeds", "3"]) == 0
    pt = json.loads(capsys.readouterr().out)["sequences"][0]["trackers"]["polartrack"]
    assert [r["seed"] for r in pt["seeds"]] == [4, 5, 6]
    for key in ("precision20", "auc50", "success_auc", "mean_err"):
        assert pt[key] == pytest.approx(np.mean([r[key] for r in pt["seeds"]]), abs=1e-4)
    assert len({r["mean_err"] for r in pt["seeds"]}) > 1
    for key in ("precision20", "auc50", "success_auc"):  # the seeds' spread: the standard error of their mean
        assert pt[f"{key}_se"] == pytest.approx(np.std([r[key] for r in pt["seeds"]], ddof=1) / math.sqrt(3), abs=1e-4)
    mean_row = json.loads((tmp_path / "a" / "benchmark.json").read_text())["mean"]["polartrack"]
    assert mean_row["auc50_se"] == pt["auc50_se"]  # one sequence: the mean's standard error is its own
    # the per-frame CSV has every seed's run, each giving that seed's figures
    res_a = json.loads((tmp_path / "a" / "benchmark.json").read_text())
    rows = read_per_frame(res_a["per_frame"]["carseq"])
    assert [(r["seed"], r["frame"]) for r in rows] == [(str(s), str(i)) for s in (4, 5, 6) for i in range(8)]
    for per in pt["seeds"]:
        errors = [float(r["centre_error"]) for r in rows if r["seed"] == str(per["seed"]) and r["centre_error"]]
        assert per["mean_err"] == pytest.approx(np.mean(errors), abs=1e-3)
    assert main([*base, "--out", str(tmp_path / "b"), "--seed", "4"]) == 0
    one = json.loads(capsys.readouterr().out)["sequences"][0]["trackers"]["polartrack"]
    assert "seeds" not in one and one["mean_err"] == pt["seeds"][0]["mean_err"] and "precision20_se" not in one
    with pytest.raises(SystemExit) as exc:
        main([*base, "--seeds", "0"])
    assert exc.value.code == 2 and "--seeds" in capsys.readouterr().err


def _without_fps(value):
    if isinstance(value, dict):
        return {k: _without_fps(v) for k, v in value.items() if k not in ("fps", "jobs", "plots", "per_frame", "ms_per_searched_frame")}
    if isinstance(value, list):
        return [_without_fps(v) for v in value]
    return value


def test_benchmark_jobs_give_the_figures_of_one_at_a_time(sequence, tmp_path, capsys):
    """--jobs 2: two sequences x two seeds run in two worker processes give exactly the figures (and
    per-seed figures, in seed order) of the runs made one at a time; only the timings and the jobs differ.
    The seeds' runs differ from each other, so a mixed-up order would show."""
    base = ["benchmark", str(sequence), str(sequence), "--json", "--frames", "8", "--no-progress",
            "--set", "rbpf.n_particles=20", "--seed", "4", "--seeds", "2"]
    assert main([*base, "--out", str(tmp_path / "a")]) == 0
    one = json.loads(capsys.readouterr().out)
    assert main([*base, "--out", str(tmp_path / "b"), "--jobs", "2"]) == 0
    two = json.loads(capsys.readouterr().out)
    assert (one["jobs"], two["jobs"]) == (1, 2)
    seeds = two["sequences"][0]["trackers"]["polartrack"]["seeds"]
    assert [r["seed"] for r in seeds] == [4, 5] and seeds[0]["mean_err"] != seeds[1]["mean_err"]
    assert _without_fps(two) == _without_fps(one)
    assert (tmp_path / "a" / "frames-carseq.csv").read_bytes() == (tmp_path / "b" / "frames-carseq.csv").read_bytes()
    with pytest.raises(SystemExit) as exc:
        main([*base, "--jobs", "0"])
    assert exc.value.code == 2 and "--jobs" in capsys.readouterr().err


def test_benchmark_table(sequence, tmp_path, capsys):
    """Two sequences (the same folder twice): a row per sequence and tracker, and the mean."""
    assert main(["benchmark", str(sequence), str(sequence), "--out", str(tmp_path), "--frames", "3", "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert text.count("carseq") == 2 and "mean" in text and "polartrack" in text and "success AUC" in text


def one_line_error(capsys, argv) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith("polartrack benchmark: error:")
    return err


def test_mismatched_groundtruth(tmp_path, capsys):
    bad = write_sequence(tmp_path / "bad", n=3, extra_lines=1)
    err = one_line_error(capsys, ["benchmark", str(bad), "--out", str(tmp_path / "o"), "--no-progress"])
    assert "4 boxes" in err and "3 frames" in err


def test_a_first_box_the_tracker_refuses_is_the_same_one_line_error_with_jobs(tmp_path, capsys):
    """A first box whose centre lies outside the frame: refused by the tracker when it starts, in
    this process (--jobs 1) or in a worker (--jobs 2), with the same one-line error."""
    folder = write_sequence(tmp_path / "edgeseq", n=4)
    lines = (folder / "groundtruth_rect.txt").read_text().splitlines()
    (folder / "groundtruth_rect.txt").write_text("\n".join(["-30,1,20,5", *lines[1:]]) + "\n")
    argv = ["benchmark", str(folder), "--json", "--no-progress", "--out", str(tmp_path / "out")]
    err = one_line_error(capsys, argv)
    assert "edgeseq" in err and "outside the" in err
    assert one_line_error(capsys, [*argv, "--jobs", "2", "--seeds", "2"]) == err


def test_a_run_that_raises_fails_its_sequence_not_the_benchmark(sequence, tmp_path, capsys, monkeypatch):
    """An exception inside the tracker on one sequence: the other sequence is scored as without it,
    the failed one up to the frame that raised (its later frames misses), the error is listed under
    it with its traceback file and said in one line on stderr, and the command exits 1."""
    from common.single_target.runner import Tracker

    other = write_sequence(tmp_path / "otherseq", n=10, seed=3)
    argv = ["benchmark", str(sequence), str(other), "--json", "--frames", "10", "--no-progress"]
    assert main([*argv, "--out", str(tmp_path / "ok")]) == 0
    clean = {r["sequence"]: r["trackers"]["polartrack"] for r in json.loads(capsys.readouterr().out)["sequences"]}
    x, y, w, h = (float(v) for v in (other / "groundtruth_rect.txt").read_text().splitlines()[0].split(","))
    step = Tracker.step

    def failing_step(self, frame):
        if frame.index == 4 and self.template.centre == (x + w / 2, y + h / 2):  # otherseq's tracker only
            raise RuntimeError("a fault for the test\nits second line")
        return step(self, frame)

    monkeypatch.setattr(Tracker, "step", failing_step)
    out = tmp_path / "failed"
    assert main([*argv, "--out", str(out)]) == 1
    captured = capsys.readouterr()
    res = {r["sequence"]: r["trackers"]["polartrack"] for r in json.loads(captured.out)["sequences"]}
    drop = {"fps", "reacquisition"}
    assert {k: v for k, v in res["carseq"].items() if k not in drop} == \
        {k: v for k, v in clean["carseq"].items() if k not in drop}
    bad = res["otherseq"]
    assert [(e["seed"], e["frame"], e["error"]) for e in bad["errors"]] == [(0, 4, "RuntimeError: a fault for the test")]
    assert "failing_step" in Path(bad["errors"][0]["traceback"]).read_text()
    # frames 0-3 as tracked without the fault, 4-9 without a box: misses
    rows = [line.split(",") for line in (out / "frames-otherseq.csv").read_text().splitlines()[1:]]
    ok_rows = [line.split(",") for line in (tmp_path / "ok" / "frames-otherseq.csv").read_text().splitlines()[1:]]
    assert rows[:4] == ok_rows[:4] and all(r[3] == "" for r in rows[4:]) and len(rows) == 10
    assert bad["precision20"] <= 0.4 < clean["otherseq"]["precision20"]
    assert bad["fps"] is None and res["carseq"]["fps"] > 0  # a failed run's time covers 4 frames: no rate
    err = captured.err.strip()
    assert err.count("\n") == 0 and "otherseq, seed 0: PolarTrack failed at frame 4: RuntimeError: a fault" in err


def test_not_a_sequence(tmp_path, capsys):
    (tmp_path / "frames").mkdir()
    cv2.imwrite(str(tmp_path / "frames" / "0001.jpg"), np.zeros((64, 64, 3), np.uint8))
    err = one_line_error(capsys, ["benchmark", str(tmp_path / "frames"), "--no-progress"])
    assert "groundtruth_rect.txt" in err
    err = one_line_error(capsys, ["benchmark", str(tmp_path / "nowhere"), "--no-progress"])
    assert "not a folder" in err


def test_peers_missing_model_checked_first(sequence, tmp_path, capsys):
    """The model files are checked before anything runs: no plots written."""
    models = tmp_path / "models"
    models.mkdir()
    (models / "nanotrack_backbone_sim.onnx").write_bytes(b"x")  # the head is missing
    out = tmp_path / "out"
    err = one_line_error(capsys, ["benchmark", str(sequence), "--peers", "--nanotrack-dir", str(models),
                                  "--out", str(out), "--no-progress"])
    assert "nanotrack_head_sim.onnx" in err and "not found" in err
    assert not out.exists()


def _peer_env_offline() -> bool:
    uv = shutil.which("uv")
    if uv is None:
        return False
    from services.commands.benchmark import peer_env

    probe = subprocess.run([uv, "run", "--offline", *peer_env(), "python", "-c", "import cv2; cv2.TrackerNano_create"],
                           capture_output=True, timeout=120)
    return probe.returncode == 0


def test_peers_run_the_products_opencv():
    """The peers' opencv-contrib is pinned to the product's OpenCV: an unpinned one follows every
    release, and a release moved NanoTrack on uav123-car16 from 0.902 to 0.128."""
    import cv2

    from services.commands.benchmark import peer_env

    env = peer_env()
    pin = env[env.index("--with") + 1]
    assert pin.startswith("opencv-contrib-python-headless==") and pin.split("==")[1].startswith(cv2.__version__)


@pytest.mark.skipif(not (MODELS / "nanotrack_head_sim.onnx").is_file(), reason="no NanoTrack models in ../shared/models")
def test_peers_subprocess(sequence, tmp_path, capsys, monkeypatch):
    if not _peer_env_offline():
        pytest.skip("no isolated opencv-contrib environment without the network (uv cache empty)")
    monkeypatch.setenv("UV_OFFLINE", "1")
    assert main(["benchmark", str(sequence), "--peers", "--nanotrack-dir", str(MODELS), "--json", "--frames", "5",
                 "--out", str(tmp_path), "--no-progress"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["trackers"] == ["polartrack", "csrt", "kcf", "nanotrack"] and res["opencv"]
    for name in ("csrt", "kcf", "nanotrack"):
        r = res["sequences"][0]["trackers"][name]
        assert r["visible_frames"] == 5 and r["fps"] > 0 and r["failures"] >= 0
        assert r["precision20"] == 1.0  # five frames of a car moving a few pixels: every peer holds it


@pytest.mark.skipif(not (DATA / "uav123-car16").is_dir(), reason="no ../shared/data/uav123-car16")
def test_uav123_boxes_count_from_one(tmp_path, capsys):
    """On a real UAV123 folder the trackers start from the first box shifted to 0-based pixels
    (the file says 556,253,22,16) and score against the shifted truth."""
    assert main(["benchmark", str(DATA / "uav123-car16"), "--json", "--frames", "4", "--out", str(tmp_path),
                 "--no-progress"]) == 0
    (row,) = json.loads(capsys.readouterr().out)["sequences"]
    assert row["init_box"] == [555.0, 252.0, 22.0, 16.0] and row["frames"] == 4
    assert row["trackers"]["polartrack"]["precision20"] == 1.0


def test_peers_failure_is_one_line(sequence, tmp_path, capsys, monkeypatch):
    """A peers' run that fails (here a stand-in script) ends the benchmark with its last stderr line."""
    import sys

    from services.commands import benchmark

    script = tmp_path / "fail.py"
    script.write_text("import sys\nprint('progress 3', file=sys.stderr)\nprint('Traceback ...', file=sys.stderr)\n"
                      "print('RuntimeError: no model', file=sys.stderr)\nsys.exit(1)\n")
    monkeypatch.setattr(benchmark, "peer_command", lambda args: [sys.executable, str(script)])
    err = one_line_error(capsys, ["benchmark", str(sequence), "--peers", "--frames", "2", "--out", str(tmp_path),
                                  "--no-progress"])
    assert err.endswith("--peers on " + str(sequence) + ": RuntimeError: no model")
