"""Who stands in front of whom: the depth order of overlapping targets, from their feet and their pixels.

Seen from a camera above the ground, a nearer person's feet are lower in the image. Judged on that
alone (the lower edges of the bodies' rest-pose boxes at their predicted torsos, :mod:`.occlusion`),
two people whose lanes are a pixel or two apart are ordered by the estimation error and by how well
the rest pose fits the walking body: the rest-pose feet sit about a pixel off the true ones on the
synthetic scene. On seed 0 the order of two walkers 1 px apart flipped back and forth while one
passed behind the other, and the hidden one, treated as in front for those frames, had its hidden
pixels scored as its own and was dragged off its path.

Where two targets overlap, the pixels show who is in front: the nearer person's parts show their own
colours there, the hidden person's show the nearer one's. For every pair (t, u) whose boxes overlap,
each one's core part boxes (torso and head, the parts held rigidly to the torso) are cut to the
overlap rectangle and compared with the target's own reference histograms: s_t and s_u, the
area-weighted mean Bhattacharyya coefficients (one batched histogram call for all pairs). The
log-odds that t stands in front of u:

    L_tu = (feet_t - feet_u) / feet_scale + E_tu,
    E_tu <- clip(forget E_tu + gain sqrt(a_tu) (s_t - s_u), -cap, cap),

with a_tu the smaller of the two cores' shares inside the overlap (a sliver at the edge of a box says
little). E is antisymmetric and kept from frame to frame, so the order seen while the two overlap
holds while one of them is fully hidden (the evidence then keeps saying the same thing). u stands in
front of t where L_ut > 0; a tie hides neither.

The weights were set on the tuning seeds 100-119; how often the order is right, by the feet alone
and with the pixels, is in docs/results.md.
"""

from __future__ import annotations

import numpy as np

from .appearance import PartEvidence, bhattacharyya, part_boxes
from .config import DepthConfig
from .occlusion import bounding_boxes


def overlap_evidence(evidence: PartEvidence, parts: np.ndarray, box_size: np.ndarray, references: np.ndarray,
                     core: np.ndarray, min_side: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """Per pair of targets, how well each one's core explains the pixels where their boxes overlap.

    ``parts`` (T, P, 2) part centres, ``box_size`` (T, P, 2), ``references`` (T, P, B), ``core`` (P,) bool.
    Returns ``score`` (T, T): [t, u] = s_t, the area-weighted mean similarity of t's core boxes cut to
    the overlap of t's and u's bounding boxes (NaN where that cut is empty), and ``share`` (T, T): [t, u]
    = a_t, the share of t's core box area inside the overlap. Cuts narrower than ``min_side`` px are
    left out."""
    t_n = len(parts)
    core = np.asarray(core, bool)
    score = np.full((t_n, t_n), np.nan)
    share = np.zeros((t_n, t_n))
    if t_n < 2:
        return score, share
    bb = bounding_boxes(parts, box_size)  # (T, 4)
    cb = part_boxes(parts[:, core], box_size[:, core])  # (T, C, 4)
    t_idx, u_idx = np.nonzero(~np.eye(t_n, dtype=bool))  # ordered pairs: [t, u] scores t
    o = np.concatenate([np.maximum(bb[t_idx, :2], bb[u_idx, :2]), np.minimum(bb[t_idx, 2:], bb[u_idx, 2:])], axis=-1)
    cut = np.concatenate([np.maximum(cb[t_idx, :, :2], o[:, None, :2]), np.minimum(cb[t_idx, :, 2:], o[:, None, 2:])],
                         axis=-1)  # (pairs, C, 4)  # fmt: skip
    side = cut[..., 2:] - cut[..., :2]
    ok = np.all(side >= min_side, axis=-1)  # (pairs, C)
    area = np.where(ok, np.prod(np.maximum(side, 0.0), axis=-1), 0.0)
    core_area = np.prod(cb[..., 2:] - cb[..., :2], axis=-1).sum(axis=-1)  # (T,)
    share[t_idx, u_idx] = area.sum(axis=-1) / np.maximum(core_area[t_idx], 1e-12)
    if not ok.any():
        return score, share
    k, c = np.nonzero(ok)
    ref = references[:, core][t_idx[k], c]  # (Q, B)
    rho = bhattacharyya(evidence.histograms(cut[k, c]), np.asarray(ref, np.float32)).astype(float)
    num = np.zeros(len(t_idx))
    np.add.at(num, k, rho * area[k, c])
    tot = area.sum(axis=-1)
    score[t_idx, u_idx] = np.where(tot > 0, num / np.maximum(tot, 1e-12), np.nan)
    return score, share


class DepthOrder:
    """The running depth order of T targets (see the module doc); one per filter."""

    def __init__(self, n_targets: int, config: DepthConfig) -> None:
        self.config = config
        self.evidence = np.zeros((n_targets, n_targets))
        """E (T, T), antisymmetric: the pixels' accumulated log-odds that t stands in front of u."""

    def update(self, parts: np.ndarray, box_size: np.ndarray, references: np.ndarray, core: np.ndarray,
               evidence: PartEvidence) -> np.ndarray:
        """Take this frame's evidence for bodies at ``parts`` (T, P, 2); returns ``front`` (T, T) bool,
        [t, u] = u stands in front of t."""
        cfg = self.config
        if cfg.evidence_gain > 0:
            s, a = overlap_evidence(evidence, parts, box_size, references, core)
            seen = ~(np.isnan(s) | np.isnan(s.T))
            delta = np.where(seen, cfg.evidence_gain * np.sqrt(np.minimum(a, a.T)) * (np.nan_to_num(s) - np.nan_to_num(s.T)), 0.0)
            self.evidence = np.clip(cfg.forget * self.evidence + delta, -cfg.cap, cfg.cap)
        return self.front(parts, box_size)

    def log_odds(self, parts: np.ndarray, box_size: np.ndarray) -> np.ndarray:
        """L (T, T): the log-odds that t stands in front of u, for bodies at ``parts`` (T, P, 2)."""
        feet = bounding_boxes(parts, box_size)[:, 3]
        return (feet[:, None] - feet[None, :]) / self.config.feet_scale + self.evidence

    def front(self, parts: np.ndarray, box_size: np.ndarray) -> np.ndarray:
        """(T, T) bool, [t, u] = u stands in front of t (L_ut > 0), with no new evidence."""
        return self.log_odds(parts, box_size).T > 0
