"""OpenCV's CSRT, KCF and NanoTrack v2 on a UAV123-format sequence: per-frame boxes and frame rates.

CSRT, KCF and NanoTrack (``cv2.TrackerNano``) live in opencv-contrib, which the project does not
depend on (it uses opencv-python-headless), so run this in a throw-away environment:

    uv run --isolated --no-project --with opencv-contrib-python-headless==VERSION --with numpy \\
        python tools/opencv_baselines.py /work/shared/data/uavdt-S1001

with VERSION the product's own OpenCV (opencv-python-headless in uv.lock), as the benchmark pins it.

``polartrack benchmark --peers`` runs it so and scores the boxes with the same scorer as
PolarTrack's (``common/evaluation/benchmark.py``); this script does not score. Every tracker starts from
``--init X,Y,W,H`` (0-based pixels; default: the first ground-truth box, whose UAV123 boxes count
from 1 and are shifted by one pixel, as ``common.sources.FolderSource`` does), rounded to whole
pixels as OpenCV's trackers take it. A tracker that reports failure on a frame keeps its last box
(so every frame has a box) and the frame is counted in ``failures``. ``fps`` is frames over the time
spent in ``init`` and ``update`` (reading the images not included), OpenCV on one thread.
NanoTrack needs its two ONNX files (``--nanotrack-dir``). Prints one JSON object:
``{"source", "frames", "opencv", "trackers": {"csrt": {"boxes": [[x, y, w, h], ...], "fps",
"failures", "init_box"}, "kcf": ..., "nanotrack": ...}}``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import cv2

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff")
NAMES = {"CSRT": "csrt", "KCF": "kcf", "NANO": "nanotrack"}
"""Tracker (as ``--trackers`` names it) -> key in the output."""
NANOTRACK_FILES = {"backbone": "nanotrack_backbone_sim.onnx", "neckhead": "nanotrack_head_sim.onnx"}


def first_truth_box(folder: Path, one_based: bool) -> tuple[float, float, float, float]:
    line = next((ln for ln in (folder / "groundtruth_rect.txt").read_text().splitlines() if ln.strip()), "")
    vals = [float(p) for p in line.replace("\t", ",").replace(" ", ",").split(",") if p]
    if len(vals) != 4 or any(math.isnan(v) for v in vals):
        raise SystemExit(f"{folder}: no ground-truth box in the first frame; give --init X,Y,W,H")
    shift = 1.0 if one_based else 0.0
    return (vals[0] - shift, vals[1] - shift, vals[2], vals[3])


def make_tracker(name: str, nanotrack_dir: Path):
    if name == "NANO":
        params = cv2.TrackerNano_Params()
        for attr, file in NANOTRACK_FILES.items():
            path = nanotrack_dir / file
            if not path.is_file():
                raise SystemExit(f"NanoTrack model file {path} not found (--nanotrack-dir)")
            setattr(params, attr, str(path))
        return cv2.TrackerNano_create(params)
    for factory in (getattr(cv2, f"Tracker{name}_create", None),
                    getattr(getattr(cv2, "legacy", None), f"Tracker{name}_create", None)):
        if factory is not None:
            return factory()
    raise SystemExit(f"cv2 has no {name} tracker: install opencv-contrib-python(-headless)")


def run(name: str, frames: list[Path], init: tuple[float, float, float, float], nanotrack_dir: Path,
        progress=None) -> dict:
    tracker = make_tracker(name, nanotrack_dir)
    start = tuple(int(round(v)) for v in init)
    boxes, failures, elapsed = [], 0, 0.0
    last = [float(v) for v in start]
    for i, f in enumerate(frames):
        img = cv2.imread(str(f), cv2.IMREAD_COLOR)
        if img is None:
            raise SystemExit(f"{f}: cannot read the image")
        t0 = time.perf_counter()
        if i == 0:
            tracker.init(img, start)
            box = last
        else:
            ok, b = tracker.update(img)
            if ok:
                box = [float(v) for v in b]
            else:
                box, failures = last, failures + 1
        elapsed += time.perf_counter() - t0
        last = box
        boxes.append([round(v, 3) for v in box])
        if progress is not None:
            progress(1)
    return {"boxes": boxes, "fps": round(len(frames) / elapsed, 1) if elapsed > 0 else None,
            "failures": failures, "init_box": list(start)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("folder", type=Path, help="UAV123-format folder: img/*.jpg and groundtruth_rect.txt")
    p.add_argument("--trackers", default="CSRT,KCF,NANO", help="comma separated (default CSRT,KCF,NANO)")
    p.add_argument("--init", metavar="X,Y,W,H", help="the first box, 0-based pixels (default: the ground truth's)")
    p.add_argument("--frames", type=int, metavar="N", help="only the first N frames")
    p.add_argument("--nanotrack-dir", type=Path, default=Path("../shared/models/nanotrack-v2"),
                   help="folder of NanoTrack v2's ONNX files (default ../shared/models/nanotrack-v2)")
    p.add_argument("--one-based", choices=["auto", "yes", "no"], default="auto",
                   help="whether the ground-truth boxes count from 1 (auto: folders named uav123*)")
    p.add_argument("--progress", action="store_true",
                   help="write 'progress N' lines on stderr (N frames done, all trackers together)")
    args = p.parse_args(argv)
    folder = args.folder
    img_dir = folder / "img" if (folder / "img").is_dir() else folder
    frames = sorted(q for q in img_dir.iterdir() if q.suffix.lower() in IMAGE_SUFFIXES)
    if args.frames is not None:
        frames = frames[:max(0, args.frames)]
    if not frames:
        raise SystemExit(f"{folder}: no images")
    if args.init:
        init = tuple(float(v) for v in args.init.split(","))
        if len(init) != 4:
            raise SystemExit(f"--init {args.init}: expected X,Y,W,H")
    else:
        one = folder.name.startswith("uav123") if args.one_based == "auto" else args.one_based == "yes"
        init = first_truth_box(folder, one)
    names = [t.strip().upper() for t in args.trackers.split(",") if t.strip()]
    unknown = [n for n in names if n not in NAMES]
    if unknown:
        raise SystemExit(f"--trackers: unknown {unknown}; choose from {', '.join(NAMES)}")
    cv2.setNumThreads(1)  # a fixed thread count: reproducible and comparable timings
    done = 0

    def progress(n: int) -> None:
        nonlocal done
        done += n
        if done % 10 == 0 or done == len(frames) * len(names):
            print(f"progress {done}", file=sys.stderr, flush=True)

    out = {"source": str(folder), "frames": len(frames), "opencv": cv2.__version__, "trackers": {}}
    for name in names:
        out["trackers"][NAMES[name]] = run(name, frames, init, args.nanotrack_dir,
                                           progress if args.progress else None)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
