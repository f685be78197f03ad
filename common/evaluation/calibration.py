"""Beta calibration of the detector's score distributions (Pang et al. 2010 section 5, Fig. 5).

Visible-target scores are sampled uniformly within 5 pixels of the true target position (at
the true relative angle when the source knows it, else the best of the 48 angles); background
scores at uniformly random in-support positions and angles. ``Z = max(0, score)``; each set is
fitted with a Beta distribution by maximum likelihood (scipy).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from common.detector import FrameCache, PolarMatcher, Template
from common.detector.layout import SUPPORT_RADIUS_PX
from common.detector.observation import DetectorObservation
from common.sources import Source

EPS = 1e-4


@dataclass
class Calibration:
    visible: np.ndarray
    background: np.ndarray
    visible_ab: tuple[float, float]
    background_ab: tuple[float, float]
    frames: int

    def as_dict(self) -> dict:
        return {
            "visible": {"a": round(self.visible_ab[0], 4), "b": round(self.visible_ab[1], 4),
                        "n": int(self.visible.size), "mean": round(float(self.visible.mean()), 4)},
            "background": {"a": round(self.background_ab[0], 4), "b": round(self.background_ab[1], 4),
                           "n": int(self.background.size), "mean": round(float(self.background.mean()), 4)},
            "frames": self.frames,
        }


def fit_beta(z: np.ndarray) -> tuple[float, float]:
    """Maximum-likelihood Beta(a, b) on [0, 1] of ``z`` (clipped into the open interval)."""
    z = np.clip(np.asarray(z, float), EPS, 1 - EPS)
    a, b, _, _ = stats.beta.fit(z, floc=0.0, fscale=1.0)
    return float(a), float(b)


def sample_scores(source: Source, rng: np.random.Generator, frames: int = 100, per_frame: int = 20,
                  radius: float = 5.0, min_visible: float = 0.99) -> tuple[np.ndarray, np.ndarray, int]:
    """Visible and background scores over the first ``frames`` frames with the target visible
    (visible fraction at least ``min_visible`` where the source knows it)."""
    if not source.has_truth:
        raise ValueError(f"{source.name}: calibration needs ground truth (a UAV123 folder or the synthetic scene)")
    it = iter(source)
    first = next(it)
    if first.truth is None or first.truth.box is None:
        raise ValueError(f"{source.name}: the target must be visible in the first frame")
    template = Template.from_image(first.image, first.truth.centre, box=first.truth.box)
    matcher = PolarMatcher(template)
    cache = FrameCache(max_frames=1)
    theta0 = first.truth.angle_deg
    vis, bg = [], []
    used = 0
    for frame in [first, *it]:
        if used >= frames:
            break
        t = frame.truth
        if t is None or t.box is None or (t.visible_fraction is not None and t.visible_fraction < min_visible):
            continue
        w, h = frame.size
        obs = DetectorObservation(frame.index, frame.time, frame.image, matcher, cache)
        r = radius * np.sqrt(rng.uniform(0, 1, per_frame))
        phi = rng.uniform(0, 2 * np.pi, per_frame)
        cx, cy = t.centre
        xy = np.c_[cx + r * np.cos(phi), cy + r * np.sin(phi)]
        if theta0 is not None and t.angle_deg is not None:
            s, ok = obs.score_at(np.c_[xy, np.full(per_frame, t.angle_deg - theta0)])
        else:
            g, ok = obs.score_grid(xy)
            s = g.max(axis=1)
        vis.append(s[ok])
        m = SUPPORT_RADIUS_PX
        bxy = np.c_[rng.uniform(m, w - 1 - m, per_frame * 5), rng.uniform(m, h - 1 - m, per_frame * 5)]
        far = np.hypot(bxy[:, 0] - cx, bxy[:, 1] - cy) > 4 * radius
        bxy = bxy[far]
        s, ok = obs.score_at(np.c_[bxy, rng.uniform(-180, 180, len(bxy))])
        bg.append(s[ok])
        used += 1
    if used == 0:
        raise ValueError(f"{source.name}: no frame with the target visible")
    return np.maximum(0, np.concatenate(vis)), np.maximum(0, np.concatenate(bg)), used


def calibrate(source: Source, seed: int = 0, frames: int = 100, per_frame: int = 20) -> Calibration:
    rng = np.random.default_rng(seed)
    vis, bg, used = sample_scores(source, rng, frames=frames, per_frame=per_frame)
    return Calibration(vis, bg, fit_beta(vis), fit_beta(bg), used)


def plot_calibration(cal: Calibration, path: str, title: str = "") -> None:
    """Pang Figure 5: the two histograms with their fitted Beta densities."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    z = np.linspace(0.001, 0.999, 400)
    for ax, data, (a, b), name in ((axes[0], cal.visible, cal.visible_ab, "visible target"),
                                    (axes[1], cal.background, cal.background_ab, "occluded target / background")):
        ax.hist(data, bins=40, range=(0, 1), density=True, alpha=0.6, label=f"{name} (n={data.size})")
        ax.plot(z, stats.beta.pdf(z, a, b), "k-", label=f"Beta({a:.2f}, {b:.2f})")
        ax.set_xlabel("Z = max(0, polar score)")
        ax.set_ylabel("density")
        ax.legend()
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
