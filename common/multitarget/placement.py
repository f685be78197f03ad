"""Placing a body in a person box: shifted to where its core stands out from the surroundings.

A person box (head top to feet) says where a person is, not where its torso is: swinging arms
and legs make the box lopsided, so the box's centre line misses the body axis by up to 0.06 H
(4 px for a 70 px person on the synthetic scene, 2.6 px RMS), and the head-top convention of the
box source sets the height at which the torso sits. The reference histograms are taken where the
body is placed, so a misplaced body takes in background, and a reference with background in it
prefers the static background to the person walking off it (the figures, on the tuning seeds:
docs/results.md).

So each body placed in its box (:meth:`~.state.MultiInit.from_boxes`) is shifted, on a 1 px grid
within ``search_x`` H sideways and ``search_y`` H up or down, to where its core parts (torso and
head) differ most from the surroundings: the histogram of a ring of width ``ring`` H around the
box. Score of a shift: the area-weighted mean over the core parts of 1 - rho(part box, ring)
(Bhattacharyya coefficient rho); the highest wins, the nearest shift among equals. Two batched
histogram calls, through
:class:`~.appearance.PartEvidence` (so the tracker service does it over the bus).
"""

from __future__ import annotations

import numpy as np

from .appearance import PartEvidence, bhattacharyya, part_boxes, pixel_boxes
from .body import BodyModel
from .config import PlacementConfig
from .state import MultiInit


def surround_boxes(boxes_xywh: np.ndarray, margin: np.ndarray) -> np.ndarray:
    """(T, 4, 4) the ring of width ``margin`` (T,) around every x, y, w, h box as four rectangles
    x0, y0, x1, y1: left and right (full height), above and below (box width)."""
    x, y, w, h = np.asarray(boxes_xywh, float).T
    m = np.asarray(margin, float)
    return np.stack([
        np.stack([x - m, y - m, x, y + h + m], -1), np.stack([x + w, y - m, x + w + m, y + h + m], -1),
        np.stack([x, y - m, x + w, y], -1), np.stack([x, y + h, x + w, y + h + m], -1),
    ], axis=1)  # fmt: skip


def surround_histograms(evidence: PartEvidence, boxes_xywh: np.ndarray, margin: np.ndarray) -> np.ndarray:
    """(T, B) colour histogram of the ring of width ``margin`` (T,) around every box: its four rectangles
    on the frame's pixel grid (:func:`~.appearance.pixel_boxes`), weighted by the pixels each counts."""
    t_n = len(boxes_xywh)
    ring = pixel_boxes(surround_boxes(boxes_xywh, margin), evidence.image_size)  # (T, 4, 4), in the frame
    hist = evidence.histograms(ring.reshape(-1, 4)).reshape(t_n, 4, -1)
    area = np.prod(ring[..., 2:] - ring[..., :2], axis=-1)  # (T, 4) pixels counted
    return np.einsum("tr,trb->tb", area, hist) / np.maximum(area.sum(axis=1, keepdims=True), 1e-12)


def _offsets(rx: int, ry: int) -> np.ndarray:
    """(K, 2) integer shifts |dx| <= rx, |dy| <= ry, nearest first (stable in x, y order)."""
    gx, gy = np.meshgrid(np.arange(-rx, rx + 1, dtype=float), np.arange(-ry, ry + 1, dtype=float))
    off = np.stack([gx.ravel(), gy.ravel()], axis=-1)
    return off[np.argsort(np.sum(off * off, axis=-1), kind="stable")]


def place_in_boxes(init: MultiInit, boxes_xywh: np.ndarray, body: BodyModel, evidence: PartEvidence,
                   cfg: PlacementConfig) -> tuple[MultiInit, np.ndarray]:
    """``init`` (bodies placed in ``boxes_xywh`` by :meth:`~.state.MultiInit.from_boxes`) with every body
    shifted as the module doc says; returns the new init and the shifts (T, 2), px."""
    t_n = len(init.parts)
    height = np.asarray(init.height, float)
    shifts = np.zeros((t_n, 2))
    if cfg.search_x <= 0 and cfg.search_y <= 0:
        return init, shifts
    core = body.max_dev <= cfg.core_deviation
    background = surround_histograms(evidence, boxes_xywh, cfg.ring * height)
    size = body.box[core][None] * height[:, None, None]  # (T, C, 2)
    area = np.prod(size, axis=-1)  # (T, C)
    offsets = [_offsets(int(round(cfg.search_x * h)), int(round(cfg.search_y * h))) for h in height]
    pos = [init.parts[t][core][None] + off[:, None] for t, off in enumerate(offsets)]  # (K_t, C, 2) each
    boxes = np.concatenate([part_boxes(p, np.broadcast_to(size[t], p.shape)).reshape(-1, 4) for t, p in enumerate(pos)])
    hist = evidence.histograms(boxes)
    start = 0
    parts = np.array(init.parts, float)
    for t, off in enumerate(offsets):
        n = len(off) * int(core.sum())
        h = hist[start:start + n]
        start += n
        rho = bhattacharyya(h, np.broadcast_to(background[t].astype(np.float32), h.shape)).reshape(len(off), -1)
        score = ((1.0 - rho) * area[t]).sum(axis=-1) / area[t].sum()
        shifts[t] = off[int(np.argmax(score))]
        parts[t] += shifts[t]
    return MultiInit(parts, height), shifts


def start_from_boxes(boxes_xywh: np.ndarray, body: BodyModel, evidence: PartEvidence,
                     cfg: PlacementConfig) -> tuple[MultiInit, np.ndarray]:
    """Bodies placed in the person boxes (T, 4) x, y, w, h of the first frame ``evidence`` and shifted
    (:func:`place_in_boxes`); the box checks of :meth:`~.state.MultiInit.from_boxes` apply."""
    boxes = np.asarray(boxes_xywh, float)
    return place_in_boxes(MultiInit.from_boxes(boxes, body, evidence.image_size), boxes, body, evidence, cfg)
