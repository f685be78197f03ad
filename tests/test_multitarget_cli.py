"""eval-multi and track-multi on small inputs; bad box files give clear errors."""

import json

import cv2
import numpy as np
import pytest

from services.cli import main
from common.scene.people import PeopleScene, PeopleSceneConfig


def test_eval_multi_json_has_the_three_methods(tmp_path, capsys):
    rc = main(["eval-multi", "--json", "--seeds", "1", "--people", "2", "--frames", "12", "--particles", "30",
               "--sweeps", "none", "--workers", "1", "--out-dir", str(tmp_path)])
    assert rc == 0
    report = json.loads(capsys.readouterr().out)
    for m in ("epmcmc-elpda", "epmcmc-pda", "jpda-pf"):
        assert report["methods"][m]["rmse"] > 0 and report["methods"][m]["ms_per_frame"] > 0
    (seed,) = report["per_seed"]  # one seed: the shares are that seed's comparisons
    assert report["elpda_beats_pda"] == float(seed["epmcmc-elpda"]["rmse"] < seed["epmcmc-pda"]["rmse"])
    assert report["init"] == "truth"
    assert (tmp_path / "eval-multi.json").exists() and (tmp_path / "error_per_frame.png").exists()


def test_eval_multi_monte_carlo_runs(tmp_path, capsys):
    rc = main(["eval-multi", "--json", "--seeds", "1", "--people", "2", "--frames", "10", "--particles", "20",
               "--parts", "1", "--runs", "2", "--init", "boxes", "--first-seed", "3", "--sweeps", "none", "--workers", "1",
               "--out-dir", str(tmp_path)])
    assert rc == 0
    report = json.loads(capsys.readouterr().out)
    assert report["runs"] == 2
    assert report["level"] == "structure" and report["init"] == "boxes"
    assert report["first_seed"] == 3 and [r["seed"] for r in report["per_seed"]] == [3]
    paired = report["per_seed"][0]["elpda_minus_pda"]
    e, p = (report["per_seed"][0][m]["rmse_runs"] for m in ("epmcmc-elpda", "epmcmc-pda"))
    assert report["elpda_beats_pda_runs"] == pytest.approx(np.mean([a < b for a, b in zip(e, p)]), abs=1e-3)
    assert paired["difference"] == pytest.approx(np.mean(np.subtract(e, p)), abs=2e-3)
    assert report["elpda_vs_pda"] == {v: float(paired["verdict"] == v) for v in ("lower", "higher", "undecided")}
    for m in ("epmcmc-elpda", "epmcmc-pda", "jpda-pf"):
        seed0 = report["per_seed"][0][m]
        assert len(seed0["rmse_runs"]) == 2 and seed0["rmse"] == pytest.approx(np.mean(seed0["rmse_runs"]), abs=2e-3)
        assert report["methods"][m]["identities_kept_runs"] == pytest.approx(np.mean(seed0["identities_kept_runs"]), abs=1e-3)
    assert main(["eval-multi", "--runs", "0", "--out-dir", str(tmp_path)]) == 2
    assert "--runs" in capsys.readouterr().err
    assert main(["eval-multi", "--first-seed", "-1", "--out-dir", str(tmp_path)]) == 2
    assert "--first-seed" in capsys.readouterr().err


@pytest.fixture
def frames_folder(tmp_path):
    scene = PeopleScene(PeopleSceneConfig(n_people=2, n_frames=10), seed=3)
    folder = tmp_path / "clip"
    folder.mkdir()
    for i in range(6):
        cv2.imwrite(str(folder / f"{i:04d}.png"), cv2.cvtColor(scene.frame(i).image, cv2.COLOR_RGB2BGR))
    boxes = tmp_path / "boxes.txt"
    boxes.write_text("# x,y,w,h\n" + "\n".join(",".join(f"{v:.1f}" for v in b) for b in scene.frame(0).truth.boxes))
    return folder, boxes


def test_track_multi_on_a_folder_writes_every_part(frames_folder, tmp_path):
    folder, boxes = frames_folder
    out = tmp_path / "t.csv"
    rc = main(["track-multi", str(folder), "--init-file", str(boxes), "--parts", "6", "--particles", "20",
               "--out", str(out), "--no-progress"])
    assert rc == 0
    rows = out.read_text().splitlines()
    assert rows[0] == "frame,target,part,x,y"
    assert len(rows) == 1 + 6 * 2 * 6


@pytest.mark.parametrize("content, message", [
    ("10,20,30\n", "expected four numbers"),
    ("", "no boxes"),
    ("370,100,40,120\n", "not inside the 384x288 frame"),
    ("10,10,-5,50\n", "must be positive"),
])
def test_bad_box_files_are_explained(frames_folder, tmp_path, capsys, content, message):
    folder, _ = frames_folder
    bad = tmp_path / "bad.txt"
    bad.write_text(content)
    assert main(["track-multi", str(folder), "--init-file", str(bad), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert message in err and "track-multi: error" in err


def test_missing_boxes_are_explained(frames_folder, capsys):
    folder, _ = frames_folder
    assert main(["track-multi", str(folder), "--no-progress"]) == 2
    assert "--init-file" in capsys.readouterr().err
    assert main(["track-multi", str(folder), "--init-file", str(folder / "nope.txt"), "--no-progress"]) == 2
    assert "no such file" in capsys.readouterr().err


def test_eval_multi_part_level_association(tmp_path, capsys, monkeypatch):
    from services.commands import eval_multi

    seen = []
    real = eval_multi._configs
    monkeypatch.setattr(eval_multi, "_configs", lambda *a: seen.append(real(*a)) or seen[-1])
    rc = main(["eval-multi", "--json", "--seeds", "1", "--people", "2", "--frames", "10", "--particles", "20",
               "--parts", "2", "--level", "part", "--sweeps", "none", "--workers", "1", "--out-dir", str(tmp_path)])
    assert rc == 0 and json.loads(capsys.readouterr().out)["level"] == "part"
    assert seen and all(c.gate.level == "part" for c in seen[0].values())  # every method, the same measurement model


def test_eval_multi_table_names_the_seeds_and_the_start(capsys, monkeypatch):
    from services.commands.eval_multi import _print_table

    monkeypatch.setenv("COLUMNS", "200")
    row = {"rmse": 4.0, "rmse_std": 0.1, "ms_per_frame": 10.0, "identities_kept": 1.0, "mota": 1.0, "idf1": 1.0,
           "id_switches": 0, "ospa": 1.0}
    _print_table({"epmcmc-elpda": row}, 0.5, 20, {}, [], 3, 0.4, "boxes", 20)
    out = capsys.readouterr().out
    assert "seeds 20-39 x 3 run(s)" in out and "started from boxes only" in out
    _print_table({"epmcmc-elpda": row}, 0.5, 10, {}, [], 1, None)
    assert "seeds 0-9 x 1 run(s), started from first-frame parts" in capsys.readouterr().out
