"""CPU per frame of the target's own size measurement (common/single_target/target_flow.py).

Times ``measure_scale_change`` on two consecutive frames of a sequence for targets of several
lengths (a box at the frame's centre), one OpenCV thread, against the stabiliser's own
frame-to-frame estimate on the same frames (the reference measured in the same run).

    uv run python tools/flow_cost.py ../shared/data/uav123-car16
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common.single_target.stabilise import CameraMotionEstimator  # noqa: E402
from common.single_target.target_flow import TargetFlowConfig, measure_scale_change  # noqa: E402
from common.sources import open_source  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("sequence")
    p.add_argument("--repeat", type=int, default=50)
    a = p.parse_args(argv)
    cv2.setNumThreads(1)
    frames = [f.image for _, f in zip(range(2), open_source(a.sequence))]
    h, w = frames[0].shape[:2]

    def per_call(fn) -> float:
        t = time.perf_counter()
        for _ in range(a.repeat):
            fn()
        return 1e3 * (time.perf_counter() - t) / a.repeat

    est = CameraMotionEstimator()

    def stabilise():
        est.start(frames[0])
        est.update(frames[1], (w / 2, h / 2), 100.0)

    ref = per_call(stabilise)
    print(f"{a.sequence}: {w}x{h}; the stabiliser's frame-to-frame estimate {ref:.2f} ms")
    cfg = TargetFlowConfig()
    for length in (22, 60, 128, 300, 600):
        box = (w / 2, h / 2, length, 0.7 * length, 0.0)
        ms = per_call(lambda: measure_scale_change(cfg, frames[0], frames[1], box))
        m = measure_scale_change(cfg, frames[0], frames[1], box)
        print(f"  target {length:4d} px long: {ms:5.2f} ms ({ms / ref:.2f} of the stabiliser's), "
              f"{'no measurement' if m is None else f'{m.points} points'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
