"""Inputs and outputs of the multi-target trackers: :class:`MultiInit` and :class:`MultiTrackState`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common.tracking.state import InitError  # noqa: F401 (one error for every tracker; re-exported)

from .body import BodyModel

# A standing person's extent about the torso centre, in units of H (see common.scene.people.body):
# head top 0.295 H above, feet 0.65 H below.
_HEAD_TOP, _FEET = 0.295, 0.65


@dataclass(frozen=True, eq=False)
class MultiInit:
    """Initial part centres (T, P, 2) and heights (T,) of every target, pixels."""

    parts: np.ndarray
    height: np.ndarray

    @classmethod
    def from_boxes(cls, boxes_xywh: np.ndarray, body: BodyModel, image_size: tuple[int, int]) -> "MultiInit":
        """A standing body in each x, y, w, h person box (head top to feet), checked against the frame."""
        b = np.asarray(boxes_xywh, float)
        if b.ndim != 2 or b.shape[1] != 4 or len(b) == 0:
            raise InitError(f"expected one or more boxes x,y,w,h (one per line), got an array of shape {b.shape}")
        w, h = image_size
        for i, (x, y, bw, bh) in enumerate(b):
            if not np.all(np.isfinite([x, y, bw, bh])) or bw <= 0 or bh <= 0:
                raise InitError(f"box {i + 1} ({x:g},{y:g},{bw:g},{bh:g}): width and height must be positive numbers")
            if x < 0 or y < 0 or x + bw > w or y + bh > h:
                raise InitError(
                    f"box {i + 1} ({x:g},{y:g},{bw:g},{bh:g}) is not inside the {w}x{h} frame; give x,y,w,h of the "
                    f"person in the first frame's pixels with 0 <= x, x+w <= {w}, 0 <= y, y+h <= {h}"
                )
        height = b[:, 3] / (_HEAD_TOP + _FEET)
        centre = np.column_stack([b[:, 0] + 0.5 * b[:, 2], b[:, 1] + _HEAD_TOP * height])
        return cls(np.stack([body.place(c, hh) for c, hh in zip(centre, height)]), height)

    @classmethod
    def from_truth(cls, ten_points: np.ndarray, boxes_xywh: np.ndarray, body: BodyModel) -> "MultiInit":
        """From a 10-point ground truth (T, 10, 2) and person boxes (T, 4) (the paper initialises with a
        pictorial-structure detector, section 4.1; the synthetic scene's truth stands in for it)."""
        return cls(body.from_ten(np.asarray(ten_points, float)), np.asarray(boxes_xywh, float)[:, 3] / (_HEAD_TOP + _FEET))


def read_boxes(path) -> np.ndarray:
    """(T, 4) boxes from a text file: one ``x,y,w,h`` (commas or spaces) per line; '#' comments."""
    from pathlib import Path

    p = Path(path)
    if not p.is_file():
        raise InitError(f"{path}: no such file; give a text file with one x,y,w,h box per person per line")
    rows = []
    for n, line in enumerate(p.read_text().splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        try:
            vals = [float(v) for v in line.replace(",", " ").split()]
        except ValueError:
            vals = []
        if len(vals) != 4:
            raise InitError(f"{path}:{n}: expected four numbers x,y,w,h (pixels, first frame), got {line!r}")
        rows.append(vals)
    if not rows:
        raise InitError(f"{path}: no boxes; write one x,y,w,h line per person")
    return np.array(rows)


@dataclass(frozen=True, eq=False)
class MultiTrackState:
    """What a multi-target tracker reports for one frame (target order = initialisation order)."""

    time: float
    parts: np.ndarray
    """(T, P, 2) estimated part centres (weighted means), px."""
    velocity: np.ndarray
    """(T, P, 2) estimated part velocities, px/s."""
    n_eff: np.ndarray
    """(T,) effective sample size of each population after weighting, before resampling."""
    moved: np.ndarray
    """(T,) bool: the population was resampled (and moved by population MCMC)."""
    gate_area: np.ndarray
    """(T, Q) validation-gate area V of every association unit, px^2."""
    n_measurements: np.ndarray
    """(T, Q) measurements inside each gate."""
    acceptance: dict
    """Population-MCMC acceptance rates by move ('mutation', 'crossover', 'exchange'); empty if none ran."""

    def identical(self, other: "MultiTrackState") -> bool:
        """Bit-for-bit equality."""
        arrays = ("parts", "velocity", "n_eff", "moved", "gate_area", "n_measurements")
        return self.time == other.time and self.acceptance == other.acceptance and all(
            np.array_equal(getattr(self, a), getattr(other, a)) for a in arrays
        )
