"""OpenCV's CSRT and KCF trackers on a UAV123-format sequence, scored like ``polartrack eval``.

CSRT and KCF live in opencv-contrib, which the project does not depend on (it uses
opencv-python-headless), so run this in a throw-away environment:

    uv run --isolated --no-project --with opencv-contrib-python-headless --with numpy \\
        python tools/opencv_baselines.py /work/shared/data/uavdt-S1001

Both trackers start from the first ground-truth box. Boxes of folders named ``uav123*`` count
from 1 (MATLAB) and are shifted by one pixel, as ``common.sources.FolderSource`` does. Scores are
computed exactly as ``common/evaluation.py`` computes them: over the frames where the target is
visible, precision20 = fraction with centre error <= 20 px, auc50 = mean precision over the
thresholds 0, 1, ..., 50 px, mean_err = mean centre error (a tracker that reports failure keeps
its last box, so every frame has an estimate). Prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import cv2
import numpy as np

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff")
THRESHOLDS = np.arange(0, 51)


def read_boxes(path: Path) -> list[tuple[float, float, float, float] | None]:
    boxes = []
    for line in path.read_text().splitlines():
        line = line.strip()
        if not line:
            continue
        parts = [p for p in line.replace("\t", ",").replace(" ", ",").split(",") if p]
        vals = [float(p) for p in parts]
        boxes.append(None if any(math.isnan(v) for v in vals) else tuple(vals))
    return boxes


def score(errors: np.ndarray, visible: np.ndarray) -> dict:
    """As common.evaluation.score_run."""
    e = np.asarray(errors, float)[np.asarray(visible, bool)]
    if e.size == 0:
        return {"precision20": float("nan"), "auc50": float("nan"), "mean_err": float("nan")}
    e = np.where(np.isfinite(e), e, np.inf)
    prec = np.array([(e <= t).mean() for t in THRESHOLDS])
    mean = float(np.mean(e[np.isfinite(e)])) if np.isfinite(e).any() else float("inf")
    return {"precision20": round(float((e <= 20).mean()), 4), "auc50": round(float(prec.mean()), 4),
            "mean_err": round(mean, 3), "visible_frames": int(e.size)}


def make_tracker(name: str):
    for factory in (getattr(cv2, f"Tracker{name}_create", None),
                    getattr(getattr(cv2, "legacy", None), f"Tracker{name}_create", None)):
        if factory is not None:
            return factory()
    raise SystemExit(f"cv2 has no {name} tracker: install opencv-contrib-python(-headless)")


def run(folder: Path, name: str, frames: list[Path], truth: list) -> dict:
    first = truth[0]
    if first is None:
        raise SystemExit(f"{folder}: no ground truth in the first frame")
    tracker = make_tracker(name)
    est = []
    elapsed = 0.0
    last = first
    for i, f in enumerate(frames):
        img = cv2.imread(str(f), cv2.IMREAD_COLOR)
        t0 = time.perf_counter()
        if i == 0:
            tracker.init(img, tuple(int(round(v)) for v in first))
            box = first
        else:
            ok, b = tracker.update(img)
            box = tuple(float(v) for v in b) if ok else last
        elapsed += time.perf_counter() - t0
        last = box
        est.append((box[0] + box[2] / 2.0, box[1] + box[3] / 2.0))
    est = np.asarray(est)
    tc = np.array([(np.nan, np.nan) if b is None else (b[0] + b[2] / 2.0, b[1] + b[3] / 2.0) for b in truth])
    err = np.hypot(est[:, 0] - tc[:, 0], est[:, 1] - tc[:, 1])
    visible = np.array([b is not None for b in truth])
    return {**score(err, visible), "fps": round(len(frames) / elapsed, 1)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("folder", type=Path, help="UAV123-format folder: img/*.jpg and groundtruth_rect.txt")
    p.add_argument("--trackers", default="CSRT,KCF", help="comma separated (default CSRT,KCF)")
    p.add_argument("--one-based", choices=["auto", "yes", "no"], default="auto",
                   help="whether the boxes count from 1 (auto: folders named uav123*)")
    args = p.parse_args(argv)
    folder = args.folder
    img_dir = folder / "img" if (folder / "img").is_dir() else folder
    frames = sorted(q for q in img_dir.iterdir() if q.suffix.lower() in IMAGE_SUFFIXES)
    boxes = read_boxes(folder / "groundtruth_rect.txt")
    if len(boxes) != len(frames):
        raise SystemExit(f"{folder}: {len(boxes)} boxes but {len(frames)} frames")
    one = folder.name.startswith("uav123") if args.one_based == "auto" else args.one_based == "yes"
    shift = 1.0 if one else 0.0
    truth = [None if b is None else (b[0] - shift, b[1] - shift, b[2], b[3]) for b in boxes]
    cv2.setNumThreads(1)  # a fixed thread count: reproducible and comparable timings
    out = {"source": str(folder), "frames": len(frames), "opencv": cv2.__version__}
    for name in [t.strip().upper() for t in args.trackers.split(",") if t.strip()]:
        out[name.lower()] = run(folder, name, frames, truth)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
