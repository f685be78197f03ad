"""Derived real sequences for the failure modes the dev set lacks (a probe, not the product).

The project is judged on real sequences it does not have: night, small fast targets, a target out
of view and back. This writes, from a UAV123/OTB folder (``img/*.jpg`` + ``groundtruth_rect.txt``),
derived folders in the same layout that ``polartrack benchmark`` (and its peers) run as they are:

- ``night``: the frame darkened as a camera at night sees it (linear light times ``--night-gain``,
  back through the sRGB curve) plus sensor noise (``--night-noise`` grey levels, 1 sigma, seeded),
  re-encoded as JPEG;
- ``fast``: every ``--skip``-th frame (the target and the camera move that many times further
  between frames at the same frame rate);
- ``small``: the frames shrunk by ``--shrink`` (the target that many times smaller; the boxes
  scaled alike);
- ``turn90``, ``turn180``, ``mirror``: the frames turned a quarter turn clockwise (a portrait
  frame), a half turn, or flipped left to right, the boxes alike: the same footage, so a tracker
  that treated the image's axes alike would score the same on each up to the seeds' noise (the
  DTCWT's sampling grid and the JPEG re-encoding differ a little; docs/real-footage.md, stop 41);
- ``away``: a virtual camera (a crop of ``--crop`` of the frame, following the truth's centre with
  a lag) that turns away from the target for ``--away-s`` seconds mid-sequence and comes back at
  another offset: the target leaves the view and re-enters elsewhere (NaN ground truth while it is
  out, as UAV123 marks it).

    uv run python tools/stress_sequences.py ../shared/data/uavdt-S1001 --out /tmp/stress --kinds night,fast

Deterministic: the noise comes from ``numpy.random.default_rng(--seed)``.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common.sources import read_groundtruth  # noqa: E402


def _srgb_to_linear(x: np.ndarray) -> np.ndarray:
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def _linear_to_srgb(x: np.ndarray) -> np.ndarray:
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.maximum(x, 0), 1 / 2.4) - 0.055)


def night(image: np.ndarray, gain: float, noise: float, rng: np.random.Generator) -> np.ndarray:
    lin = _srgb_to_linear(image.astype(np.float64) / 255.0) * gain
    out = _linear_to_srgb(lin) * 255.0 + rng.normal(0.0, noise, image.shape)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def _write(out: Path, images: list[np.ndarray], boxes: list) -> None:
    (out / "img").mkdir(parents=True, exist_ok=True)
    for i, im in enumerate(images):
        cv2.imwrite(str(out / "img" / f"{i + 1:06d}.jpg"), im, [cv2.IMWRITE_JPEG_QUALITY, 90])
    lines = ["NaN,NaN,NaN,NaN" if b is None else ",".join(f"{v:.2f}" for v in b) for b in boxes]
    (out / "groundtruth_rect.txt").write_text("\n".join(lines) + "\n")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("seq", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--kinds", default="night,fast,small,away")
    ap.add_argument("--night-gain", type=float, default=0.08)
    ap.add_argument("--night-noise", type=float, default=4.0)
    ap.add_argument("--skip", type=int, default=3)
    ap.add_argument("--shrink", type=float, default=2.0)
    ap.add_argument("--crop", type=float, default=0.6, help="the virtual camera's view, a fraction of the frame")
    ap.add_argument("--away-s", type=float, default=1.5)
    ap.add_argument("--fps", type=float, default=30.0)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    paths = sorted((a.seq / "img").glob("*.jpg"))
    truth = read_groundtruth(a.seq / "groundtruth_rect.txt")
    if len(paths) != len(truth):
        print(f"error: {a.seq}: {len(paths)} images but {len(truth)} ground-truth rows", file=sys.stderr)
        return 2
    images = [cv2.imread(str(p)) for p in paths]
    name = a.seq.name
    rng = np.random.default_rng(a.seed)
    for kind in a.kinds.split(","):
        out = a.out / f"{name}-{kind}"
        if kind == "night":
            _write(out, [night(im, a.night_gain, a.night_noise, rng) for im in images], truth)
        elif kind == "fast":
            _write(out, images[::a.skip], truth[::a.skip])
        elif kind == "small":
            f = 1.0 / a.shrink
            ims = [cv2.resize(im, None, fx=f, fy=f, interpolation=cv2.INTER_AREA) for im in images]
            _write(out, ims, [None if b is None else tuple(v * f for v in b) for b in truth])
        elif kind == "away":
            _write(out, *_away(images, truth, a.crop, a.away_s, a.fps))
        elif kind in _TURNS:
            h, w = images[0].shape[:2]
            turn, box = _TURNS[kind]
            _write(out, [turn(im) for im in images], [None if b is None else box(b, w, h) for b in truth])
        else:
            print(f"error: unknown kind {kind!r}: use night, fast, small, away, {', '.join(_TURNS)}", file=sys.stderr)
            return 2
        print(out)
    return 0


_TURNS = {
    # kind: (the image turned; the box (x, y, w, h) of a w x h frame, covering [x, x + w) x [y, y + h), turned)
    "turn90": (lambda im: cv2.rotate(im, cv2.ROTATE_90_CLOCKWISE),
               lambda b, w, h: (h - (b[1] + b[3]), b[0], b[3], b[2])),
    "turn180": (lambda im: cv2.rotate(im, cv2.ROTATE_180),
                lambda b, w, h: (w - (b[0] + b[2]), h - (b[1] + b[3]), b[2], b[3])),
    "mirror": (lambda im: cv2.flip(im, 1), lambda b, w, h: (w - (b[0] + b[2]), b[1], b[2], b[3])),
}


def _away(images, truth, crop: float, away_s: float, fps: float):
    """A crop window following the truth's centre (clamped to the frame); from a third of the way
    in, for ``away_s`` seconds, it slides off by its own width towards the side of the frame with
    more room (the target leaves the view) and comes back centred a quarter window to the other
    side."""
    h, w = images[0].shape[:2]
    cw, ch = int(w * crop), int(h * crop)
    n = len(images)
    t0, t1 = n // 3, n // 3 + int(round(away_s * fps))
    centres, last = [], None
    for b in truth:
        if b is not None:
            last = (b[0] + b[2] / 2, b[1] + b[3] / 2)
        centres.append(last)
    # it turns towards the side of the frame with more room (else the frame's edge stops it)
    side = 1.0 if centres[t0] is None or centres[t0][0] < w / 2 else -1.0
    out_im, out_box = [], []
    for i, (im, b) in enumerate(zip(images, truth)):
        cx, cy = centres[i] if centres[i] is not None else (w / 2, h / 2)
        if t0 <= i < t1:  # turning away and back: a half sine of one window width
            cx += side * cw * math.sin(math.pi * (i - t0) / (t1 - t0))
        elif i >= t1:
            cx -= side * cw / 4
        x0 = int(np.clip(round(cx - cw / 2), 0, w - cw))
        y0 = int(np.clip(round(cy - ch / 2), 0, h - ch))
        out_im.append(im[y0:y0 + ch, x0:x0 + cw].copy())
        if b is None:
            out_box.append(None)
            continue
        bx, by = b[0] - x0, b[1] - y0
        # visible only while the whole box is in view (UAV123 marks partly out-of-view frames too,
        # but the scorer needs a box inside the view to score against)
        inside = bx >= 0 and by >= 0 and bx + b[2] <= cw and by + b[3] <= ch
        out_box.append((bx, by, b[2], b[3]) if inside else None)
    return out_im, out_box


if __name__ == "__main__":
    raise SystemExit(main())
