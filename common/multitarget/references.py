"""Reference colour histograms of every target's parts, from the pixels nobody stands in front of.

The filters identify a person by the histograms of its parts in the first frame. People who start
partly hidden behind others (the synthetic scene has several such seeds; any street scene does) would
otherwise take the occluder's clothing into their references, and then follow the occluder or look
like nothing at all. So a part's reference is the histogram of its box less the part boxes of the
targets in front of it (feet lower in the image, as in :mod:`.occlusion`):

* the box less the occluders' boxes is cut into rectangles at every occluder edge inside it, and the
  rectangles that no occluder covers are kept (exact for any number of overlapping occluders);
* every rectangle's histogram comes from the same batched :meth:`~.appearance.PartEvidence.histograms`
  call (so it works over the bus too), and they are summed weighted by their pixel counts;
* a part with less than ``min_visible`` of its box in view keeps its whole box's histogram: a few
  pixels at the edge of an occluder describe the part no better than the mixture does.

Boxes are taken on the whole-pixel grid the evidence uses (rounded, clipped to the image).
"""

from __future__ import annotations

import numpy as np

from .appearance import PartEvidence, part_boxes, pixel_boxes


def visible_cells(box: np.ndarray, occluders: np.ndarray) -> np.ndarray:
    """(C, 4) rectangles x0, y0, x1, y1 that tile ``box`` (4,) less the union of ``occluders`` (K, 4)."""
    x0, y0, x1, y1 = box
    if len(occluders) == 0:
        return box[None].copy()
    xs = np.unique(np.clip(np.concatenate([[x0, x1], occluders[:, 0], occluders[:, 2]]), x0, x1))
    ys = np.unique(np.clip(np.concatenate([[y0, y1], occluders[:, 1], occluders[:, 3]]), y0, y1))
    cx0, cy0 = np.meshgrid(xs[:-1], ys[:-1])
    cx1, cy1 = np.meshgrid(xs[1:], ys[1:])
    cells = np.stack([cx0, cy0, cx1, cy1], axis=-1).reshape(-1, 4)
    mid = 0.5 * (cells[:, :2] + cells[:, 2:])
    o = occluders[None]
    covered = np.any((mid[:, None, 0] > o[..., 0]) & (mid[:, None, 0] < o[..., 2])
                     & (mid[:, None, 1] > o[..., 1]) & (mid[:, None, 1] < o[..., 3]), axis=1)  # fmt: skip
    return cells[~covered]


def reference_histograms(evidence: PartEvidence, parts: np.ndarray, box_size: np.ndarray,
                         min_visible: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """Reference histograms (T, P, B) of every target's parts ``parts`` (T, P, 2) with boxes
    ``box_size`` (T, P, 2), and the visible share (T, P) of every part's box."""
    t_n, p_n = parts.shape[:2]
    boxes = pixel_boxes(part_boxes(parts, box_size), evidence.image_size)  # (T, P, 4)
    feet = boxes[..., 3].max(axis=1)  # (T,)
    area = np.prod(boxes[..., 2:] - boxes[..., :2], axis=-1)
    cells, owner, visible = [], [], np.ones((t_n, p_n))
    for t in range(t_n):
        occ = boxes[feet > feet[t]].reshape(-1, 4)
        for p in range(p_n):
            c = visible_cells(boxes[t, p], occ)
            seen = float(np.prod(c[:, 2:] - c[:, :2], axis=-1).sum())
            visible[t, p] = seen / area[t, p] if area[t, p] > 0 else 0.0
            if visible[t, p] < min_visible:
                c = boxes[t, p][None]
            cells.append(c)
            owner += [t * p_n + p] * len(c)
    cells = np.concatenate(cells)
    hist = evidence.histograms(cells)  # (C, B) normalised
    counts = hist * np.prod(cells[:, 2:] - cells[:, :2], axis=-1)[:, None]
    total = np.zeros((t_n * p_n, hist.shape[1]))
    np.add.at(total, np.asarray(owner), counts)
    n = total.sum(axis=1, keepdims=True)
    refs = np.divide(total, n, out=np.zeros_like(total), where=n > 0)
    return refs.reshape(t_n, p_n, -1).astype(np.float32), visible
