"""The polar match's scores on the ground about a real target, against the likelihood's background Beta.

On frames of a sequence, with the first frame's template matched at the scale of the ground-truth
box (the tracker's own factor for that size), scores every hypothesis on a grid of half target
lengths in the ring 1.5-6 lengths from the true centre, at all 48 angles, and prints their mean,
spread and quantiles, the Beta fitted to them by moments, the best angle's quantiles, and the
target's own score at its true centre. The likelihood's background is the synthetic fit
Beta(0.25, 8.08) (mean 0.03, 99th percentile 0.26; ``common/settings.py``).

    uv run python tools/background_scores.py ../shared/data/uavdt-S1001 0 50 150 250 300
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common.settings import profile_for  # noqa: E402
from common.single_target.runner import Tracker  # noqa: E402
from common.sources import open_source  # noqa: E402
from common.tracking.likelihood import beta_by_moments  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("sequence")
    p.add_argument("frames", type=int, nargs="*", default=[0])
    a = p.parse_args(argv)
    src = open_source(a.sequence)
    truth = [t for t in src.truth]
    if not truth or truth[0] is None:
        print(f"{a.sequence}: no ground truth for the first frame", file=sys.stderr)
        return 2
    x0, y0, w0, h0 = truth[0]
    tracker = None
    for i, frame in enumerate(src):
        if tracker is None:
            tracker = Tracker.start(frame, tuple(truth[0]), profile_for(src, seed=0))
        if i > max(a.frames):
            break
        if i not in a.frames or truth[i] is None:
            continue
        x, y, w, h = truth[i]
        centre, length = np.array([x + w / 2, y + h / 2]), max(w, h)
        k = tracker.scale.raw_factor(math.sqrt(w * h / (w0 * h0)))
        steps = np.arange(-6 * length, 6 * length + 1e-9, length / 2)
        ring = np.array([(dx, dy) for dy in steps for dx in steps if 1.5 * length <= math.hypot(dx, dy) <= 6 * length])
        scores, ok = tracker.detector.scale_grid(frame, k, centre + ring)
        z = np.clip(scores[ok].ravel(), 1e-5, 1 - 1e-5)
        best = scores[ok].max(axis=1)
        own, _ = tracker.detector.scale_grid(frame, k, centre[None])
        ba, bb = beta_by_moments(z)
        print(f"frame {i}: k {k:.3f}, {int(ok.sum())} points x 48 angles: mean {z.mean():.3f} sd {z.std():.3f} "
              f"q50/90/99 {np.quantile(z, 0.5):.3f}/{np.quantile(z, 0.9):.3f}/{np.quantile(z, 0.99):.3f} "
              f"Beta({ba:.2f}, {bb:.2f}); best angle q50/90 {np.quantile(best, 0.5):.3f}/{np.quantile(best, 0.9):.3f}; "
              f"target {own.max():.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
