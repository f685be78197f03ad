"""Where does the first frame's template match on later frames of a real sequence?

A diagnostic for docs/real-footage.md: for each requested frame of a UAV123/OTB sequence, the
template built on frame 0 at the first ground-truth box is scored (all 48 angles) at the target's
true scale on a 1-px grid around the ground-truth centre, and over the whole frame. It prints the
best score within 2.5 px of the truth against the best score elsewhere, so one can tell whether a
failure is the matcher's (the background outscores the target) or the filter's.

    uv run python tools/match_probe.py ../shared/data/uav123-truck4 --frames 5,8,20,40 --factor 1
    uv run python tools/match_probe.py ../shared/data/uav123-car16 --frames 150,300,550 --whole-frame

``--factor`` fixes the resampling factor (default: the tracker's, the target kept at its
canonical size); the local grid is ``--radius`` px either way.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common.detector.client import LocalDetector  # noqa: E402
from common.detector.resample import quantise_factor  # noqa: E402
from common.single_target.scale import first_box_factor  # noqa: E402
from common.settings import ScaleSettings  # noqa: E402
from common.sources import open_source  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("sequence")
    p.add_argument("--frames", required=True, help="comma-separated frame indices (from 0)")
    p.add_argument("--factor", type=float, default=None, help="resampling factor (default: the tracker's)")
    p.add_argument("--radius", type=int, default=16, help="local grid half-width, pixels")
    p.add_argument("--whole-frame", action="store_true", help="also the best background score over the frame")
    a = p.parse_args(argv)
    frames = sorted(int(v) for v in a.frames.split(","))
    src = open_source(a.sequence)
    truth = [t for t in src.truth]
    wanted = {}
    for f in src:
        if f.index == 0 or f.index in frames:
            wanted[f.index] = f
        if f.index >= frames[-1]:
            break
    b = truth[0]
    length0 = max(b[2], b[3])
    cfg = ScaleSettings()
    u = first_box_factor(tuple(b), cfg)
    det = LocalDetector()
    k0 = a.factor if a.factor is not None else quantise_factor(u, cfg.steps_per_octave)
    det.build_template(wanted[0], (b[0] + b[2] / 2, b[1] + b[3] / 2), tuple(b), k0)
    w, h = wanted[0].size
    for i in frames:
        g = truth[i]
        if g is None:
            print(f"frame {i}: no ground truth")
            continue
        cx, cy = g[0] + g[2] / 2, g[1] + g[3] / 2
        s = max(g[2], g[3]) / length0
        k = a.factor if a.factor is not None else quantise_factor(max(u / s, cfg.min_factor), cfg.steps_per_octave)
        off = np.arange(-a.radius, a.radius + 1, 1.0)
        gx, gy = np.meshgrid(cx + off, cy + off)
        xy = np.stack([gx.ravel(), gy.ravel()], axis=1)
        sc, ok = det.scale_grid(wanted[i], k, xy)
        best = np.where(ok, sc.max(axis=1), -np.inf)
        d = np.hypot(xy[:, 0] - cx, xy[:, 1] - cy)
        j = int(np.argmax(np.where(d > 6, best, -np.inf)))
        line = (f"frame {i} ({g[2]:.0f}x{g[3]:.0f} px, k={k:.3f}): near truth {best[d <= 2.5].max():.3f}, "
                f"elsewhere within {a.radius} px {best[j]:.3f} at ({xy[j, 0] - cx:+.0f}, {xy[j, 1] - cy:+.0f})")
        if a.whole_frame:
            step = 0.3 * max(g[2], g[3])
            gx, gy = np.meshgrid(np.arange(0, w, step), np.arange(0, h, step))
            xy = np.stack([gx.ravel(), gy.ravel()], axis=1)
            sc, ok = det.scale_grid(wanted[i], k, xy)
            far = ok & (np.hypot(xy[:, 0] - cx, xy[:, 1] - cy) > max(g[2], g[3]))
            m = sc.max(axis=1)[far]
            line += f"; background over the frame: max {m.max():.3f}, 99th percentile {np.quantile(m, 0.99):.3f}"
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
