"""Is the target the frame's strongest mover, and would the re-acquisition's mover test accept it?

A diagnostic for docs/real-footage.md: the sequence is tracked with the real-footage profile (for
the stabiliser's homographies), and on every ``--every``-th frame from ``--start`` a second
moving-target cue scores the whole frame's boxes at the target's true scale
(:meth:`common.single_target.motion_cue.MotionCue.movers`, as the re-acquisition does). It prints
whether the strongest box lies on the ground-truth target (within half its length), the runner-up
away from it, and the expected false alarms n P of the re-acquisition's peaks-over-threshold test
(:func:`common.single_target.reacquire.expected_false_alarms`): the test passes below
``false_alarms_per_s`` times the frame interval (0.005 at 10 fps).

    uv run python tools/mover_probe.py ../shared/data/uav123-car16 --start 120 --every 30
    uv run python tools/mover_probe.py ../shared/data/uavdt-S1001 --start 25 --every 25
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common.settings import profile_for  # noqa: E402
from common.single_target.motion_cue import MotionCue  # noqa: E402
from common.single_target.reacquire import background_boxes, expected_false_alarms  # noqa: E402
from common.single_target.runner import Tracker  # noqa: E402
from common.sources import open_source  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("sequence")
    p.add_argument("--start", type=int, default=0, help="first frame probed (from 0)")
    p.add_argument("--every", type=int, default=30, help="probe every this many frames")
    a = p.parse_args(argv)
    src = open_source(a.sequence)
    truth = getattr(src, "truth", None)
    if truth is None:
        print(f"{a.sequence}: no ground truth (a UAV123/OTB folder with groundtruth_rect.txt)", file=sys.stderr)
        return 2
    settings = profile_for(src)
    first = np.asarray(truth[0], float)
    tracker = probe = None
    counts = {"frames": 0, "strongest_is_target": 0, "passed_on_target": 0, "passed_elsewhere": 0}
    for frame in src:
        if tracker is None:
            tracker = Tracker.start(frame, tuple(first), settings)
            probe = MotionCue(settings.motion_cue, (first[2], first[3]))
        tracker.step(frame)
        probe.push(frame.time, frame.image, tracker.stabiliser.homography)
        box = np.asarray(truth[frame.index], float)
        if frame.index < a.start or (frame.index - a.start) % a.every or not np.all(np.isfinite(box)):
            continue
        length = float(max(box[2:]))
        xy, z = probe.movers(length / max(first[2:]))
        if len(z) == 0:
            continue
        top = int(np.argmax(z))
        # the tracker's rule (without its guard against a blob merged with the frame: these boxes are
        # the target's own size, not a sweep's small one)
        blob = probe.blob_box(tuple(xy[top])) if settings.reacquisition.mover_tail_without_blob else None
        far = background_boxes(xy, top, length, blob, (box[2] / 2, box[3] / 2))  # the runner-up's boxes
        false_alarms = expected_false_alarms(xy, z, top, length, len(z), settings.reacquisition.mover_tail_quantile,
                                             blob, (box[2] / 2, box[3] / 2))
        centre = box[:2] + box[2:] / 2
        on_target = bool(np.hypot(*(xy[top] - centre)) < 0.5 * length)
        passed = false_alarms <= settings.reacquisition.false_alarms_per_s / src.fps
        counts["frames"] += 1
        counts["strongest_is_target"] += on_target
        counts["passed_on_target"] += passed and on_target
        counts["passed_elsewhere"] += passed and not on_target
        near = np.hypot(*(xy - centre).T) < 0.5 * length
        own = (f"its z {np.max(z[near]):.1f}, rank {int(np.sum(z > np.max(z[near]))) + 1}" if near.any()
               else "no box on it")
        print(f"frame {frame.index}: target {length:.0f} px ({own}), strongest z {z[top]:.1f} "
              f"{'on the target' if on_target else 'elsewhere'}, runner-up {np.max(np.where(far, z, -np.inf)):.1f}, "
              f"n P {false_alarms:.2g} ({'passes' if passed else 'fails'})")
    print(" ".join(f"{k}={v}" for k, v in counts.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
