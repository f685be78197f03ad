"""Does the camera's zoom at the target predict the target's change of size?

A diagnostic for docs/real-footage.md. Between searches the scale state is predicted by the
stabiliser's frame-to-frame map: its zoom (sqrt det of the Jacobian) at the target's ground point
(:meth:`common.single_target.scale.ScaleTracker.predict`). That is the target's own zoom only while
the target stays on that ground point. This runs the stabiliser (``--model``, the real profile's
homography by default) with the ground-truth box's centre as the excluded target, and prints per
window of ``--window`` frames the product of the zooms at the true centre against the truth's size
change (sqrt of the box area ratio), then the RMS over windows of log(zoom) - log(truth) with the
zoom, without it (no prediction) and with half of it.

    uv run python tools/zoom_probe.py ../shared/data/uav123-car16
    uv run python tools/zoom_probe.py ../shared/data/uav123-car16 --model similarity
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common.single_target.stabilise import CameraMotionEstimator, StabiliserConfig  # noqa: E402
from common.sources import open_source  # noqa: E402
from common.tracking.camera import homography_jacobian  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("sequence")
    p.add_argument("--window", type=int, default=30, help="frames per window")
    p.add_argument("--model", choices=["homography", "affine", "similarity"], default="homography",
                   help="the stabiliser's frame-to-frame model")
    p.add_argument("--exclusion-lengths", type=float, default=StabiliserConfig().exclusion_lengths,
                   help="radius of the featureless disc about the target, in target lengths")
    a = p.parse_args(argv)
    src = open_source(a.sequence)
    truth = getattr(src, "truth", None)
    if not truth or truth[0] is None:
        print(f"zoom_probe: {a.sequence} has no ground truth (groundtruth_rect.txt)", file=sys.stderr)
        return 2
    gt = np.array([t if t is not None else (np.nan,) * 4 for t in truth], float)
    est = CameraMotionEstimator(StabiliserConfig(model=a.model))
    zoom, size = [], []
    for i, frame in enumerate(src):
        if i == 0:
            est.start(frame.image)
            continue
        prev = gt[i - 1]
        centre = np.array([prev[0] + prev[2] / 2, prev[1] + prev[3] / 2])
        est.update(frame.image, centre, a.exclusion_lengths * max(prev[2], prev[3]))
        j = homography_jacobian(est.last.interframe, centre)
        zoom.append(0.5 * math.log(abs(float(np.linalg.det(j)))))
        size.append(0.5 * math.log(gt[i, 2] * gt[i, 3] / (prev[2] * prev[3])))
    zoom, size = np.array(zoom), np.array(size)
    ok = np.isfinite(zoom) & np.isfinite(size)
    zoom, size = np.where(ok, zoom, 0.0), np.where(ok, size, 0.0)
    print(f"{a.sequence}: {len(zoom)} frame pairs, {a.model}")
    rows = []
    for s in range(0, len(zoom), a.window):
        z, t = zoom[s:s + a.window].sum(), size[s:s + a.window].sum()
        print(f"  frames {s + 1:4d}-{min(s + a.window, len(zoom)):4d}: camera zoom at the target "
              f"{math.exp(z):6.2f}  target {math.exp(t):6.2f}")
        if s + a.window <= len(zoom):
            rows.append((z, t))
    w = np.array(rows)
    if len(w):
        rms = lambda d: float(np.sqrt(np.mean(d ** 2)))  # noqa: E731
        print(f"  RMS log error per window: with the zoom {rms(w[:, 0] - w[:, 1]):.3f}, "
              f"without {rms(w[:, 1]):.3f}, half of it {rms(0.5 * w[:, 0] - w[:, 1]):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
