"""Log-likelihood of target configurations: the weighted sum of paper section 3.1.

For a configuration x of target t (part centres x_p, p = 1..P), with the target's reference
histograms q_p, height H and this frame's association terms:

    log L_t(x) = w_app  sum_p -lambda (1 - max(rho(box_p(x_p), q_p), floor))     (part fit to the image)
               + w_da   sum_units log EL_u(x)      (expected likelihood, eq. 13; plain PDA: combined measurement)
               - w_geo  sum_{(p, q) edges} |x_p - x_q - mu_p H|^2 / (2 (sigma H)^2)   (pairwise structure)

A part whose box the targets in front of its target cover (their boxes this frame, ``AssociationTerms.
occluders``) shows the occluder's pixels, not its own: the covered share of its box counts as
``hidden_similarity`` rather than as the pixels' rho (``LikelihoodConfig.hidden_similarity``); with
``visible_pixels_only`` rho is taken on the largest strip of the box that nobody covers.

Any configuration can be scored under any target's model (needed by the exchange move), in one
batched evidence call for all of them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .appearance import PartEvidence, part_boxes
from .association import expected_log_likelihood, pda_log_likelihood
from .body import BodyModel
from .config import LikelihoodConfig
from .occlusion import covered_share, visible_strip


@dataclass(frozen=True)
class AssociationTerms:
    """One frame's gated measurements and association probabilities, per target and association unit
    (the whole structure located by its root, or every part; see :mod:`.gating`)."""

    z: np.ndarray  # (T, Q, M, 2) measured positions of each unit's located part
    valid: np.ndarray  # (T, Q, M)
    beta: np.ndarray  # (T, Q, M+1)
    volume: np.ndarray  # (T, Q)
    r_cov: np.ndarray  # (T, Q, 2, 2) R used in N(z_j; h(x), R)
    p_gate: float
    located: np.ndarray  # (Q,) the part whose position each unit's measurements measure
    centre: np.ndarray  # (T, Q, 2) gate centres z^
    combined: bool = False  # True: plain PDA's combined-measurement likelihood instead of eq. 13
    occluders: np.ndarray | None = None  # (T, T, 4) boxes of the targets in front of each (occlusion.occluder_boxes)


@dataclass(frozen=True, eq=False)
class TargetModels:
    """What identifies each target: its body model, size and appearance."""

    body: BodyModel
    height: np.ndarray
    """(T,) person height H, px."""
    references: np.ndarray
    """(T, P, B) reference colour histogram of every part."""

    @property
    def box_size(self) -> np.ndarray:
        """(T, P, 2) part box sizes, px."""
        return self.body.box[None] * self.height[:, None, None]


def _area(boxes: np.ndarray) -> np.ndarray:
    return np.maximum(boxes[..., 2] - boxes[..., 0], 0.0) * np.maximum(boxes[..., 3] - boxes[..., 1], 0.0)


def log_likelihood(pos: np.ndarray, model: np.ndarray, targets: TargetModels, evidence: PartEvidence,
                   assoc: AssociationTerms | None, cfg: LikelihoodConfig) -> np.ndarray:
    """(K, N) log L of configurations ``pos`` (K, N, P, 2) under the targets ``model`` (K,)."""
    k_n, n_n, p_n = pos.shape[:3]
    body = targets.body
    model = np.asarray(model, np.intp)
    total = np.zeros((k_n, n_n))
    if cfg.w_appearance > 0:
        size = np.broadcast_to(targets.box_size[model][:, None], pos.shape)
        ref = np.broadcast_to((model[:, None, None] * p_n + np.arange(p_n)), pos.shape[:3])
        boxes = part_boxes(pos, size)
        scored, hidden = boxes, None
        if cfg.hidden_similarity is not None and assoc is not None and assoc.occluders is not None:
            occ = assoc.occluders[model]  # (K, T, 4)
            occ = occ[:, occ.any(axis=(0, 2))]  # only the targets in front of some scored model
            if occ.shape[1]:
                if cfg.visible_pixels_only:
                    scored = visible_strip(boxes, occ[:, None, None])
                    hidden = 1.0 - _area(scored) / np.maximum(_area(boxes), 1e-12)  # (K, N, P)
                else:
                    hidden = covered_share(boxes, occ[:, None, None])
        rho = evidence.similarity(scored.reshape(-1, 4), targets.references.reshape(-1, targets.references.shape[-1]),
                                  ref.ravel())  # fmt: skip
        rho = np.maximum(rho.reshape(k_n, n_n, p_n), cfg.colour_floor)
        if hidden is not None:
            rho = (1.0 - hidden) * rho + hidden * cfg.hidden_similarity
        total += cfg.w_appearance * np.sum(-cfg.colour_lambda * (1.0 - rho), axis=-1)
    if cfg.w_association > 0 and assoc is not None:
        if assoc.combined:
            ctr = assoc.centre[model]
            el = pda_log_likelihood((assoc.z - assoc.centre[:, :, None])[model][:, None], assoc.beta[model][:, None],
                                    assoc.valid[model][:, None], pos[:, :, assoc.located] - ctr[:, None],
                                    assoc.r_cov[model][:, None])  # fmt: skip
        else:
            diff = assoc.z[model][:, None] - pos[:, :, assoc.located, None, :]  # (K, N, Q, M, 2)
            el = expected_log_likelihood(diff, assoc.beta[model][:, None], assoc.valid[model][:, None],
                                         assoc.volume[model][:, None], assoc.r_cov[model][:, None], assoc.p_gate)
        total += cfg.w_association * el.sum(axis=-1)
    if cfg.w_structure > 0 and p_n > 1:
        h = targets.height[model][:, None, None, None]
        d = body.to_relative(pos)[:, :, 1:] - body.offset[1:] * h
        total -= cfg.w_structure * np.sum(d * d, axis=(-1, -2)) / (2.0 * (cfg.structure_sigma * h[..., 0, 0]) ** 2)
    return total
