"""Which targets hide which: the detection probability of a partly hidden target.

A person further from the camera (feet higher in the image) is hidden where a nearer one stands in
front of it. While it is hidden its measurements are not its own: the structure's colour match
slides onto the visible pixels around the occluder, or onto the occluder itself. With a constant
P_D the association keeps trusting those measurements and the target is dragged off its path; with
P_D scaled by the visible share of the target, beta_0 ("no measurement is the target's") takes
over as the target disappears, and the filter coasts on its motion model until it reappears.

    P_D,t = P_D * max(1 - covered_t, floor)

``covered_t``: the share of target t's predicted bounding box (the union box of its predicted part
boxes) covered by the bounding boxes of the targets in front of it (feet lower in the image, or the
running order of :mod:`.depth`, which also reads the pixels where two targets overlap), summed over
those targets and capped at 1. The union of two occluders' boxes is over-counted only where they
overlap each other, which the cap absorbs. The filters pass every body in its rest pose at
its predicted root (:meth:`~.tracker.MultiTargetFilter.detection_probability`), so that the noisy
limb estimates do not decide who stands in front.
"""

from __future__ import annotations

import numpy as np

from .appearance import part_boxes


def bounding_boxes(parts: np.ndarray, box_size: np.ndarray) -> np.ndarray:
    """(T, 4) x0, y0, x1, y1 of the union box of every target's part boxes; ``parts`` and
    ``box_size`` (T, P, 2)."""
    b = part_boxes(parts, box_size)
    return np.concatenate([b[..., :2].min(axis=1), b[..., 2:].max(axis=1)], axis=-1)


def covered_fraction(boxes: np.ndarray, front: np.ndarray | None = None) -> np.ndarray:
    """(T,) share of each box (T, 4) covered by the boxes in front of it, capped at 1.

    ``front`` (T, T) bool, [t, u] = u stands in front of t (:class:`~.depth.DepthOrder`); None: the
    box with the larger y1 (feet lower) is nearer, and ties hide neither box."""
    return covered_share(boxes, _in_front(boxes, front))


def detection_probability(p_detect: float, parts: np.ndarray, box_size: np.ndarray, floor: float,
                          front: np.ndarray | None = None) -> np.ndarray:
    """(T,) P_D of every target: ``p_detect`` times its visible share (at least ``floor``); ``front`` as
    in :func:`covered_fraction`."""
    return p_detect * np.maximum(1.0 - covered_fraction(bounding_boxes(parts, box_size), front), floor)


def feet_order(boxes: np.ndarray) -> np.ndarray:
    """(T, T) bool, [t, u] = box u stands in front of box t: its lower edge y1 is lower in the image."""
    return boxes[None, :, 3] > boxes[:, None, 3]


def _in_front(boxes: np.ndarray, front: np.ndarray | None = None) -> np.ndarray:
    """(T, T, 4): [t, u] box u if it stands in front of box t, else an empty box."""
    front = feet_order(boxes) if front is None else np.asarray(front, bool)
    return np.where(front[..., None], boxes[None], 0.0)


def occluder_boxes(parts: np.ndarray, box_size: np.ndarray, front: np.ndarray | None = None) -> np.ndarray:
    """(T, T, 4): [t, u] the bounding box of target u if u stands in front of t, else an empty box (so
    that it covers nothing); ``parts`` and ``box_size`` (T, P, 2), ``front`` as in :func:`covered_fraction`."""
    return _in_front(bounding_boxes(parts, box_size), front)


def covered_share(boxes: np.ndarray, occluders: np.ndarray) -> np.ndarray:
    """(...,) share of each box (..., 4) covered by ``occluders`` (..., K, 4) (broadcasting against
    the boxes' leading axes), summed over the occluders and capped at 1."""
    b, o = boxes[..., None, :], occluders
    w = np.maximum(np.minimum(b[..., 2], o[..., 2]) - np.maximum(b[..., 0], o[..., 0]), 0.0)
    h = np.maximum(np.minimum(b[..., 3], o[..., 3]) - np.maximum(b[..., 1], o[..., 1]), 0.0)
    area = np.maximum((boxes[..., 2] - boxes[..., 0]) * (boxes[..., 3] - boxes[..., 1]), 1e-12)
    return np.minimum(np.sum(w * h, axis=-1) / area, 1.0)


def visible_strip(boxes: np.ndarray, occluders: np.ndarray) -> np.ndarray:
    """(..., 4) the largest rectangle of each box (..., 4) that no occluder (..., K, 4) covers, found
    occluder by occluder: of the box's strips left, right, above and below an occluder that overlaps it,
    the largest is kept (exact for one occluder; people side by side leave a strip). A box covered
    whole becomes empty (x0 = x1)."""
    out = np.array(np.broadcast_to(boxes, np.broadcast_shapes(boxes.shape, occluders.shape[:-2] + (4,))), float)
    for k in range(occluders.shape[-2]):
        o = np.broadcast_to(occluders[..., k, :], out.shape)
        x0, y0, x1, y1 = (out[..., i] for i in range(4))
        hits = (np.minimum(x1, o[..., 2]) > np.maximum(x0, o[..., 0])) & (np.minimum(y1, o[..., 3]) > np.maximum(y0, o[..., 1]))
        if not hits.any():
            continue
        cands = np.stack([
            np.stack([x0, y0, np.minimum(x1, o[..., 0]), y1], -1), np.stack([np.maximum(x0, o[..., 2]), y0, x1, y1], -1),
            np.stack([x0, y0, x1, np.minimum(y1, o[..., 1])], -1), np.stack([x0, np.maximum(y0, o[..., 3]), x1, y1], -1),
        ], axis=-2)  # (..., 4 strips, 4)  # fmt: skip
        area = np.maximum(cands[..., 2] - cands[..., 0], 0.0) * np.maximum(cands[..., 3] - cands[..., 1], 0.0)
        best = np.take_along_axis(cands, np.argmax(area, axis=-1)[..., None, None], axis=-2)[..., 0, :]
        best = np.where((area.max(axis=-1) > 0)[..., None], best, np.stack([x0, y0, x0, y0], -1))
        out = np.where(hits[..., None], best, out)
    return out
