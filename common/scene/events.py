"""Synthetic test sequences for the events real footage has and the aerial scene lacks.

Both are made from one rendered frame of the synthetic aerial scene (no smoke, no decoy; the parked
clutter cars stay), with exact ground truth, no homography (like real footage: the tracker must
stabilise and track the scale itself), and seeded sensor noise:

- :class:`ZoomSource` (``zoom[:SEED]``): the camera zooms in on the car by ``zoom`` (default 10x)
  over the run, geometrically (a constant rate of ``log(zoom) / duration`` per second), the car
  growing from about 17 px to about 170 px long, slightly off the image centre.
- :class:`ExitSource` (``exit[:SEED]``): the car drives out of the right edge of a static view,
  stays out of the frame for ``gap_s`` seconds and comes back in from the left edge on another
  row: where it re-enters no motion model predicts, so only a search of the frame can find it.
"""

from __future__ import annotations

import math
from typing import Iterator

import cv2
import numpy as np

from common.sources.base import Frame, GroundTruth, Source


def _canvas(seed: int, width: int, height: int) -> tuple[np.ndarray, tuple[float, float, float, float]]:
    """Frame 0 of the aerial scene without smoke or decoy, and the car's box in it."""
    from common.scene import SceneConfig, SyntheticScene

    cfg = SceneConfig(width=width, height=height, n_frames=20, smoke_duration_s=0.0, decoy=False)
    f = SyntheticScene(cfg, seed=seed).frame(0)
    return f.image, tuple(float(v) for v in f.truth.box)


def _noisy(image: np.ndarray, rng: np.random.Generator, sigma: float) -> np.ndarray:
    noise = rng.normal(0.0, sigma, image.shape)
    return np.clip(image.astype(np.float64) + noise, 0, 255).astype(np.uint8)


class _EventSource(Source):
    """Frames made on demand from ``_make(i)``; truth from ``_truth(i)``."""

    n_frames: int

    def __len__(self) -> int:
        return self.n_frames

    @property
    def has_truth(self) -> bool:
        return True

    def __iter__(self) -> Iterator[Frame]:
        for i in range(len(self)):
            yield self.frame(i)

    def frame(self, i: int) -> Frame:
        image, truth = self._make(i)
        noise_rng = np.random.default_rng([self.seed, i])
        return Frame(index=i, time=i / self.fps, image=_noisy(image, noise_rng, self.noise_sigma), truth=truth)

    def _make(self, i: int) -> tuple[np.ndarray, GroundTruth]:  # pragma: no cover - overridden
        raise NotImplementedError


class ZoomSource(_EventSource):
    """A ``zoom``-fold camera zoom onto the car over ``n_frames`` (see the module docstring)."""

    def __init__(self, seed: int = 0, n_frames: int = 60, zoom: float = 10.0, fps: float = 10.0,
                 size: tuple[int, int] = (1280, 720), noise_sigma: float = 2.0):
        self.seed, self.n_frames, self.zoom, self.fps = seed, int(n_frames), float(zoom), float(fps)
        self.size, self.noise_sigma = size, noise_sigma
        self.name = f"zoom-{seed}"
        # the canvas is 1/3 of the way to the final zoom's resolution: the car starts about 1/3 of
        # its canvas size and ends about zoom/3 times it
        self._start = 3.0
        w, h = size
        self.canvas, self.car_box = _canvas(seed, int(w * self._start), int(h * self._start))

    def window(self, i: int) -> tuple[float, float, float]:
        """(x0, y0, scale): the canvas window shown in frame ``i`` and canvas pixels per frame pixel."""
        W, H = self.size
        ch, cw = self.canvas.shape[:2]
        frac = i / max(self.n_frames - 1, 1)
        scale = self._start / self.zoom ** frac  # canvas pixels per frame pixel
        ww, wh = W * scale, H * scale
        x, y, bw, bh = self.car_box
        car = np.array([x + bw / 2, y + bh / 2])
        # the view centre moves from the canvas centre onto a point beside the car (so the car ends
        # up off centre by 12% of the frame's width)
        target = car - np.array([0.12 * ww, -0.08 * wh])
        centre = (1 - frac) * np.array([cw / 2, ch / 2]) + frac * target
        x0 = float(np.clip(centre[0] - ww / 2, 0, cw - ww))
        y0 = float(np.clip(centre[1] - wh / 2, 0, ch - wh))
        return x0, y0, scale

    def _make(self, i: int) -> tuple[np.ndarray, GroundTruth]:
        x0, y0, s = self.window(i)
        if s > 1:  # shrinking: area-average first so that the view does not alias, then shift
            small = cv2.resize(self.canvas, None, fx=1 / s, fy=1 / s, interpolation=cv2.INTER_AREA)
            m = np.array([[1.0, 0.0, -x0 / s], [0.0, 1.0, -y0 / s]])
            img = cv2.warpAffine(small, m, self.size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        else:  # frame pixel u sees canvas pixel x0 + s (u + 0.5) - 0.5
            m = np.array([[1 / s, 0.0, (0.5 - x0) / s - 0.5], [0.0, 1 / s, (0.5 - y0) / s - 0.5]])
            img = cv2.warpAffine(self.canvas, m, self.size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        x, y, bw, bh = self.car_box
        box = ((x - x0) / s, (y - y0) / s, bw / s, bh / s)
        return img, GroundTruth(box=box, visible_fraction=1.0)


class ExitSource(_EventSource):
    """The car leaves the frame on the right and comes back on the left (see the module docstring)."""

    def __init__(self, seed: int = 0, speed_lengths: float = 3.0, gap_s: float = 1.5, fps: float = 10.0,
                 size: tuple[int, int] = (1280, 720), noise_sigma: float = 2.0, after_s: float = 3.0):
        self.seed, self.fps, self.size, self.noise_sigma = seed, float(fps), size, noise_sigma
        self.name = f"exit-{seed}"
        w, h = size
        canvas, box = _canvas(seed, w, h)
        x, y, bw, bh = box
        x0, y0 = int(math.floor(x)) - 1, int(math.floor(y)) - 1
        x1, y1 = int(math.ceil(x + bw)) + 1, int(math.ceil(y + bh)) + 1
        self.patch = canvas[y0:y1, x0:x1].copy()
        mask = np.zeros(canvas.shape[:2], np.uint8)
        mask[y0:y1, x0:x1] = 255
        self.background = cv2.inpaint(canvas, mask, 5, cv2.INPAINT_TELEA)
        self.start = (float(x0), float(y0))
        length = max(bw, bh)
        self.speed = speed_lengths * length / self.fps  # pixels per frame
        pw = self.patch.shape[1]
        self.exit_frame = int(math.ceil((w - x0) / self.speed))  # first frame entirely out on the right
        self.gap_frames = int(round(gap_s * self.fps))
        self.return_frame = self.exit_frame + self.gap_frames  # first frame back (entering on the left)
        self.return_row = float(np.clip(y0 + (0.3 if y0 < h / 2 else -0.3) * h, 80, h - 80 - self.patch.shape[0]))
        self.n_frames = self.return_frame + int(math.ceil((pw + 0.3 * w) / self.speed)) + int(after_s * self.fps)
        self.n_frames = min(self.n_frames, self.return_frame + int((w * 0.6) / self.speed))

    def patch_origin(self, i: int) -> tuple[float, float] | None:
        """Top-left corner of the car's patch in frame ``i`` (None while out of the frame)."""
        if i < self.exit_frame:
            return (self.start[0] + i * self.speed, self.start[1])
        if i < self.return_frame:
            return None
        pw = self.patch.shape[1]
        return (-pw + (i - self.return_frame + 1) * self.speed, self.return_row)

    def _make(self, i: int) -> tuple[np.ndarray, GroundTruth]:
        img = self.background.copy()
        o = self.patch_origin(i)
        if o is None:
            return img, GroundTruth(box=None, visible_fraction=0.0)
        w, h = self.size
        ph, pw = self.patch.shape[:2]
        ox, oy = int(round(o[0])), int(round(o[1]))
        x0, x1 = max(ox, 0), min(ox + pw, w)
        y0, y1 = max(oy, 0), min(oy + ph, h)
        if x1 - x0 < 2 or y1 <= y0:
            return img, GroundTruth(box=None, visible_fraction=0.0)
        img[y0:y1, x0:x1] = self.patch[y0 - oy:y1 - oy, x0 - ox:x1 - ox]
        frac = (x1 - x0) * (y1 - y0) / float(pw * ph)
        # the truth is the body box (the patch less its 1 px margin), clipped to the frame
        bx0, by0 = max(ox + 1, 0), max(oy + 1, 0)
        bx1, by1 = min(ox + pw - 1, w), min(oy + ph - 1, h)
        return img, GroundTruth(box=(float(bx0), float(by0), float(bx1 - bx0), float(by1 - by0)), visible_fraction=frac)
