"""A stretch of a UAV123/OTB sequence as a sequence of its own: frames START..END-1 (from 0) linked,
not copied, under OUT/img, and their ground-truth lines, so that ``polartrack benchmark`` starts
from the ground truth's box on frame START (a diagnostic for docs/real-footage.md, stop 38: a
target whose first box is larger than the template's footprint).

    uv run python tools/clip_sequence.py ../shared/data/uav123-car16 440 665 /tmp/big/uav123-car16-from440
    uv run polartrack benchmark /tmp/big/uav123-car16-from440 --seeds 10 --jobs 2 --peers
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sequence", type=Path)
    ap.add_argument("start", type=int)
    ap.add_argument("end", type=int)
    ap.add_argument("out", type=Path)
    a = ap.parse_args(argv)
    images = sorted((a.sequence / "img").iterdir())
    truth = (a.sequence / "groundtruth_rect.txt").read_text().strip().splitlines()
    if len(truth) != len(images) or not 0 <= a.start < a.end <= len(images):
        ap.error(f"{a.sequence}: {len(images)} frames, {len(truth)} boxes; START and END must lie within them")
    (a.out / "img").mkdir(parents=True, exist_ok=True)
    for path in images[a.start:a.end]:
        link = a.out / "img" / path.name
        if not link.exists():
            os.symlink(path.resolve(), link)
    (a.out / "groundtruth_rect.txt").write_text("\n".join(truth[a.start:a.end]) + "\n")
    print(f"{a.out}: frames {a.start}-{a.end - 1}, first box {truth[a.start]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
