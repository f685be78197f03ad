"""Template adaptation with an anchor to the original (settings: :class:`common.settings.TemplateAdaptation`).

The target's appearance drifts (lighting, viewpoint, a turn that shows its side), so a template
taken once on the first frame matches less and less. When the posterior is confident that the
target is visible and the estimate matches well, the P-matrix sampled at the estimate is turned
back to the template's orientation (:func:`common.detector.template.rotate_pmatrix` by minus the
refined MAP angle) and blended into an adaptive part. The template actually matched is

    T = normalise(anchor * H0 + (1 - anchor) * A),   A <- normalise((1 - rate) A + rate F)

with ``H0`` the normalised original and ``F`` the normalised, rotated-back sample: the original
always keeps weight ``anchor``, so however many (possibly wrong) updates happen, the template's
correlation with the original stays at least ``anchor / sqrt(anchor^2 + (1 - anchor)^2)`` (0.71
for anchor 0.5) whenever ``A`` is not anti-correlated with it.

Where the sample is taken: at the point where the template being matched registers the target
best near the estimate (:func:`registered_point`), not at the estimate itself, whose lag behind the
target each update would otherwise take in and the next keep (Matthews, Ishikawa and Baker 2004).
"""

from __future__ import annotations

import math

import numpy as np

from common.detector.template import Template, rotate_pmatrix


def _unit(p: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(p))
    return p / n if n > 0 else p


class TemplateAdapter:
    """Keeps the original template and the adaptive part; ``update`` returns the new template."""

    def __init__(self, template: Template, rate: float, anchor: float):
        self.original = template
        self.rate = float(rate)
        self.anchor = float(anchor)
        self._norm = float(np.linalg.norm(template.pmatrix))
        self._h0 = _unit(np.asarray(template.pmatrix, np.complex128))
        self._a = self._h0.copy()
        self.updates = 0

    def blend(self, sample: np.ndarray, theta_deg: float) -> Template:
        """Blend ``sample`` (a P-matrix taken on a target turned by ``theta_deg`` relative to the
        template) into the adaptive part and return the template to match with from now on."""
        f = _unit(np.asarray(rotate_pmatrix(sample, -float(theta_deg)), np.complex128))
        self._a = _unit((1.0 - self.rate) * self._a + self.rate * f)
        t = _unit(self.anchor * self._h0 + (1.0 - self.anchor) * self._a) * self._norm
        self.updates += 1
        o = self.original
        return Template(pmatrix=t.astype(np.complex64), centre=o.centre, box=o.box)


def registered_point(obs, xy: tuple[float, float], length_px: float,
                     reach_lengths: float) -> tuple[float, float] | None:
    """Where ``obs``'s template matches best (over all angles) within ``reach_lengths`` target
    lengths of ``xy``: a grid a sixteenth of ``length_px`` apart over the square of that half-side,
    then a 5x5 grid a sixty-fourth apart about its best; None when that best lies beyond the
    reach (the square's corners) or nothing there can be scored."""
    x, y = float(xy[0]), float(xy[1])
    reach = reach_lengths * length_px
    best = None
    for half, step in ((reach, length_px / 16.0), (length_px / 32.0, length_px / 64.0)):
        step = max(step, 0.25)
        n = max(1, int(math.floor(half / step + 1e-9)))
        offsets = np.arange(-n, n + 1) * step
        gx, gy = np.meshgrid(x + offsets, y + offsets)
        pts = np.stack([gx.ravel(), gy.ravel()], axis=1)
        scores, ok = obs.score_grid(pts)
        per = np.where(np.asarray(ok, bool)[:, None], np.asarray(scores, float), -np.inf)
        if not np.isfinite(per).any():
            return None
        i = int(np.argmax(per.max(axis=1)))
        x, y = float(pts[i, 0]), float(pts[i, 1])
        best = (x, y)
    if best is None or math.hypot(best[0] - xy[0], best[1] - xy[1]) > reach + 1e-9:
        return None
    return best
