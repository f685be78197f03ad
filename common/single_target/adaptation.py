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
"""

from __future__ import annotations

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
