"""Pictorial-structure body models (Felzenszwalb and Huttenlocher 2005; Bhaskar and Mihaylova 2011, section 4).

A body model is a tree of parts: each part has a parent (the torso is the root), a preferred
offset from its parent's centre and a box size (both in units of the person's height H), and a
limit on how far the offset may stray from the preferred one (the structure constraint the genetic
moves keep). The four levels of the paper's Fig. 8:

* 1 part: torso;
* 2 parts: head, torso;
* 6 parts: head, torso, two arms, two legs (an arm or leg as one part);
* 10 parts: head, torso, upper and lower arms and legs (the 10-point annotation of section 4.1).

``gt_matrix`` maps the scene's 10-point ground truth to the model's part centres (a whole arm's
centre is the mean of its upper and lower arm centres), so every model is scored on its own parts.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

TEN = ("head", "torso", "l_upper_arm", "l_lower_arm", "r_upper_arm", "r_lower_arm",
       "l_upper_leg", "l_lower_leg", "r_upper_leg", "r_lower_leg")  # fmt: skip
"""The 10-point ground-truth order (same as ``common.scene.people.PART_NAMES``)."""

# name: (parent, preferred offset from the parent / H, box (w, h) / H, max offset deviation / H,
#        10-point ground-truth parts it stands for)
_PARTS = {
    "torso": (None, (0.0, 0.0), (0.18, 0.26), 0.0, ("torso",)),
    "head": ("torso", (0.0, -0.23), (0.11, 0.12), 0.06, ("head",)),
    "l_upper_arm": ("torso", (-0.09, -0.04), (0.06, 0.14), 0.10, ("l_upper_arm",)),
    "l_lower_arm": ("l_upper_arm", (0.0, 0.16), (0.06, 0.13), 0.12, ("l_lower_arm",)),
    "r_upper_arm": ("torso", (0.09, -0.04), (0.06, 0.14), 0.10, ("r_upper_arm",)),
    "r_lower_arm": ("r_upper_arm", (0.0, 0.16), (0.06, 0.13), 0.12, ("r_lower_arm",)),
    "l_upper_leg": ("torso", (-0.05, 0.27), (0.08, 0.20), 0.10, ("l_upper_leg",)),
    "l_lower_leg": ("l_upper_leg", (0.0, 0.23), (0.08, 0.20), 0.14, ("l_lower_leg",)),
    "r_upper_leg": ("torso", (0.05, 0.27), (0.08, 0.20), 0.10, ("r_upper_leg",)),
    "r_lower_leg": ("r_upper_leg", (0.0, 0.23), (0.08, 0.20), 0.14, ("r_lower_leg",)),
    "l_arm": ("torso", (-0.09, 0.04), (0.07, 0.26), 0.14, ("l_upper_arm", "l_lower_arm")),
    "r_arm": ("torso", (0.09, 0.04), (0.07, 0.26), 0.14, ("r_upper_arm", "r_lower_arm")),
    "l_leg": ("torso", (-0.05, 0.39), (0.09, 0.40), 0.16, ("l_upper_leg", "l_lower_leg")),
    "r_leg": ("torso", (0.05, 0.39), (0.09, 0.40), 0.16, ("r_upper_leg", "r_lower_leg")),
}

LEVELS = {
    1: ("torso",),
    2: ("torso", "head"),
    6: ("torso", "head", "l_arm", "r_arm", "l_leg", "r_leg"),
    10: ("torso", "head", "l_upper_arm", "l_lower_arm", "r_upper_arm", "r_lower_arm",
         "l_upper_leg", "l_lower_leg", "r_upper_leg", "r_lower_leg"),
}  # fmt: skip
"""Part lists of the 1-, 2-, 6- and 10-part models; parents always come before their children."""


@dataclass(frozen=True, eq=False)
class BodyModel:
    """A pictorial structure: parts in tree order (root first), all sizes in units of H."""

    names: tuple[str, ...]
    parent: np.ndarray
    """(P,) index of each part's parent, -1 for the root."""
    offset: np.ndarray
    """(P, 2) preferred offset of each part's centre from its parent's (root: 0)."""
    box: np.ndarray
    """(P, 2) box width and height of each part."""
    max_dev: np.ndarray
    """(P,) the structure constraint: |offset - preferred offset| <= max_dev (root: unconstrained)."""
    gt_matrix: np.ndarray
    """(P, 10) rows average the 10-point ground truth into this model's part centres."""

    @property
    def n_parts(self) -> int:
        return len(self.names)

    @property
    def edges(self) -> np.ndarray:
        """(P-1, 2) (child, parent) pairs: the neighbour graph."""
        c = np.flatnonzero(self.parent >= 0)
        return np.column_stack([c, self.parent[c]])

    def neighbours(self, p: int) -> set[int]:
        """Parts joined to part ``p`` by an edge."""
        return {int(c) for c, q in self.edges if q == p} | ({int(self.parent[p])} if self.parent[p] >= 0 else set())

    def subtree(self, p: int) -> np.ndarray:
        """(P,) bool mask of part ``p`` and all its descendants (a connected piece of the graph)."""
        mask = np.zeros(self.n_parts, bool)
        mask[p] = True
        for q in range(p + 1, self.n_parts):  # tree order: a parent precedes its children
            if self.parent[q] >= 0 and mask[self.parent[q]]:
                mask[q] = True
        return mask

    def to_relative(self, pos: np.ndarray) -> np.ndarray:
        """(..., P, D) absolute centres (D = 2; or 4 with the velocities) -> root position and offsets
        from each part's parent."""
        rel = pos.copy()
        c = self.parent >= 0
        rel[..., c, :] = pos[..., c, :] - pos[..., self.parent[c], :]
        return rel

    def to_absolute(self, rel: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`to_relative` (parents first)."""
        pos = rel.copy()
        for q in range(1, self.n_parts):
            pos[..., q, :] = rel[..., q, :] + pos[..., self.parent[q], :]
        return pos

    def deviation(self, pos: np.ndarray, height: float | np.ndarray) -> np.ndarray:
        """(..., P) |offset - preferred offset| / H of every part (0 for the root)."""
        rel = self.to_relative(pos)
        h = np.asarray(height, float)[..., None, None]
        d = rel - self.offset * h
        d[..., 0, :] = 0.0
        return np.linalg.norm(d, axis=-1) / h[..., 0]

    def satisfies(self, pos: np.ndarray, height: float | np.ndarray, tol: float = 1e-9) -> np.ndarray:
        """(...) bool: every part within its structure constraint."""
        return np.all(self.deviation(pos, height) <= self.max_dev + tol, axis=-1)

    def place(self, centre_xy, height: float) -> np.ndarray:
        """(P, 2) part centres of a standing body whose torso centre is ``centre_xy``."""
        rel = self.offset * height
        rel[0] = centre_xy
        return self.to_absolute(rel)

    def from_ten(self, ten: np.ndarray) -> np.ndarray:
        """(..., 10, 2) ground-truth points -> (..., P, 2) this model's part centres."""
        return np.einsum("pk,...kd->...pd", self.gt_matrix, ten)


@cache
def body_model(n_parts: int) -> BodyModel:
    """The 1-, 2-, 6- or 10-part model."""
    if n_parts not in LEVELS:
        raise ValueError(f"no {n_parts}-part body model; choose from {sorted(LEVELS)}")
    names = LEVELS[n_parts]
    index = {n: i for i, n in enumerate(names)}
    parent = np.array([-1 if _PARTS[n][0] is None else index[_PARTS[n][0]] for n in names])
    gt = np.zeros((len(names), 10))
    for i, n in enumerate(names):
        for g in _PARTS[n][4]:
            gt[i, TEN.index(g)] = 1.0 / len(_PARTS[n][4])
    return BodyModel(
        names=names, parent=parent,
        offset=np.array([_PARTS[n][1] for n in names], float),
        box=np.array([_PARTS[n][2] for n in names], float),
        max_dev=np.array([_PARTS[n][3] for n in names], float),
        gt_matrix=gt,
    )  # fmt: skip
