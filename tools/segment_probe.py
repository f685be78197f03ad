"""How often is GrabCut's segment of the target right, and does anything about it say so?

A diagnostic for docs/real-footage.md (stop 52). For every ``--every``-th frame of each UAV123/OTB
folder it segments the target (``common.single_target.segment.segment_target``, the registration's
settings) about ``--draws`` points drawn about the truth's centre (up to ``--max-offset`` target
lengths off, the length scaled by up to ``exp(+-max-log-scale)``), as a track held off the target's
centre at a wrong scale would. A segment is *good* when its centre is within 0.15 truth lengths of
the truth's, *bad* beyond 0.3. For three measures a registration could gate on it prints, per
sequence, how well each ranks the good segments above the bad ones (the area under the ROC curve,
0.5 for a coin) and the share of each that the registration's own test (rectangularity at least
``min_solidity``) lets through:

- ``rect``: the component's area over its minimum-area rectangle's (the registration's test);
- ``hull``: its area over its convex hull's (solidity as image-analysis packages define it);
- ``distinct``: one less the Bhattacharyya coefficient of the component's colours and the
  margin's (CIELAB, 8 bins a channel): how far the segment's colours stand out from what is
  around it.

    uv run python tools/segment_probe.py ../shared/data/uav123-car16 ../shared/data/uavdt-S1001

GrabCut's mask is read through a wrapper of ``cv2.grabCut`` and ``cv2.connectedComponentsWithStats``
for this process only; the library is not changed. Deterministic (``--seed``).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common.settings import SegmentRegistration  # noqa: E402
from common.single_target import segment as seg_mod  # noqa: E402
from common.sources import open_source  # noqa: E402

GOOD, BAD = 0.15, 0.3


class _Capture:
    """The last GrabCut call's image, rectangle and largest component (wrapping the cv2 functions
    the segment module calls)."""

    def __init__(self):
        self.img = self.rect = self.component = None
        self._gc, self._cc = cv2.grabCut, cv2.connectedComponentsWithStats

    def grab_cut(self, img, mask, rect, *args, **kwargs):
        self.img, self.rect, self.component = img.copy(), rect, None
        return self._gc(img, mask, rect, *args, **kwargs)

    def components(self, fg, connectivity=8):
        n, labels, stats, centres = self._cc(fg, connectivity=connectivity)
        if n > 1:
            self.component = labels == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        return n, labels, stats, centres


def _lab_histogram(pixels: np.ndarray) -> np.ndarray:
    lab = cv2.cvtColor(pixels.reshape(-1, 1, 3).astype(np.uint8), cv2.COLOR_RGB2LAB).reshape(-1, 3) // 32
    return np.bincount(lab[:, 0] * 64 + lab[:, 1] * 8 + lab[:, 2], minlength=512) / max(len(lab), 1)


def _measures(cap: _Capture) -> tuple[float, float]:
    """(hull solidity, colour distinctness) of the captured component."""
    comp = cap.component
    pts = np.argwhere(comp)[:, ::-1].astype(np.float32)
    hull = cv2.convexHull(pts)
    # the hull through the pixels' centres: half its perimeter added back, as the pixels have area
    solidity = float(comp.sum()) / max(cv2.contourArea(hull) + 0.5 * cv2.arcLength(hull, True) + 1.0, 1.0)
    rx, ry, rw, rh = cap.rect
    outside = np.ones(comp.shape, bool)
    outside[ry:ry + rh, rx:rx + rw] = False
    if not outside.any():
        return solidity, float("nan")
    bc = float(np.sum(np.sqrt(_lab_histogram(cap.img[comp]) * _lab_histogram(cap.img[outside]))))
    return solidity, 1.0 - bc


def _auc(pos: np.ndarray, neg: np.ndarray) -> float:
    if len(pos) == 0 or len(neg) == 0:
        return float("nan")
    return float(np.mean(pos[:, None] > neg[None, :]) + 0.5 * np.mean(pos[:, None] == neg[None, :]))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("sequences", nargs="+", help="UAV123/OTB folders (img/ + groundtruth_rect.txt)")
    p.add_argument("--every", type=int, default=6, help="every N-th frame (default 6)")
    p.add_argument("--draws", type=int, default=3, help="segmentations per frame (default 3)")
    p.add_argument("--max-offset", type=float, default=0.5, help="largest offset, truth lengths (default 0.5)")
    p.add_argument("--max-log-scale", type=float, default=0.5, help="largest |log| scale error (default 0.5)")
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args(argv)
    cfg = SegmentRegistration(enabled=True)
    cap = _Capture()
    seg_mod.cv2.grabCut, seg_mod.cv2.connectedComponentsWithStats = cap.grab_cut, cap.components
    rng = np.random.default_rng(a.seed)
    print(f"{'sequence':22s} {'segs':>5s} {'good':>5s} {'bad':>5s}  AUC rect / hull / distinct   "
          f"rect >= {cfg.min_solidity}: good, bad")
    for path in a.sequences:
        src = open_source(path)
        rows = []
        for i, frame in enumerate(src):
            box = src.truth[i] if i < len(src.truth) else None
            if i % a.every or box is None or not all(math.isfinite(v) for v in box):
                continue
            x, y, w, h = box
            cx, cy, length = x + w / 2, y + h / 2, max(w, h)
            for _ in range(a.draws):
                off, ang = rng.uniform(0, a.max_offset) * length, rng.uniform(0, 2 * math.pi)
                scale = math.exp(rng.uniform(-a.max_log_scale, a.max_log_scale))
                s = seg_mod.segment_target(np.asarray(frame.image), (cx + off * math.cos(ang), cy + off * math.sin(ang)),
                                           length * scale, cfg, seed=i)
                if s is None or cap.component is None:
                    continue
                rows.append((math.hypot(s.x - cx, s.y - cy) / length, s.solidity, *_measures(cap)))
        r = np.array(rows, float).reshape(-1, 4)
        good, bad = r[r[:, 0] < GOOD], r[r[:, 0] >= BAD]
        aucs = " / ".join(f"{_auc(good[:, j], bad[:, j]):.2f}" for j in (1, 2, 3))
        passed = (f"{np.mean(good[:, 1] >= cfg.min_solidity):.2f}, "
                  f"{np.mean(bad[:, 1] >= cfg.min_solidity) if len(bad) else float('nan'):.2f}")
        print(f"{Path(path).name:22s} {len(r):5d} {len(good):5d} {len(bad):5d}  {aucs:26s}   {passed}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
