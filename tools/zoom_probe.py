"""Does the camera's zoom at the target predict the target's change of size?

A diagnostic for docs/real-footage.md. Between searches the scale state is predicted by the
stabiliser's frame-to-frame map: its zoom (sqrt det of the Jacobian) at the target's ground point
(:meth:`common.single_target.scale.ScaleTracker.predict`). That is the target's own zoom only while
the target stays on that ground point. This runs the stabiliser (``--model``, the real profile's
homography by default) with the ground-truth box's centre as the excluded target, and prints per
window of ``--window`` frames the product of the zooms at the true centre against the truth's size
change (sqrt of the box area ratio), then the RMS over windows of log(zoom) - log(truth) with the
zoom, without it (no prediction) and with half of it. Beside it, the target's own change of size
measured on its pixels in the true box (:mod:`common.single_target.target_flow`) and the
prediction the scale state makes (the two fused by inverse variance, ``ScaleTracker.predict``),
with the RMS of each; ``--grid`` adds the fused RMS for a grid of the fusion's two parameters
(``point_noise_px``, ``departure_time_constant_s``) and, given several sequences, the
leave-one-sequence-out choice from it.

    uv run python tools/zoom_probe.py ../shared/data/uav123-car16
    uv run python tools/zoom_probe.py ../shared/data/uav123-car16 --model similarity
    uv run python tools/zoom_probe.py ../shared/data/uav* --grid
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common.single_target.stabilise import CameraMotionEstimator, StabiliserConfig  # noqa: E402
from common.single_target.scale import fuse_with_zoom  # noqa: E402
from common.single_target.target_flow import TargetFlowConfig, measure_scale_change, noise_floor  # noqa: E402
from common.sources import open_source  # noqa: E402
from common.tracking.camera import homography_jacobian  # noqa: E402


def probe(path: str, model: str, exclusion_lengths: float, flow_cfg: TargetFlowConfig) -> dict | None:
    """Per frame pair: the ground's zoom at the true centre, the truth's size change (both log), the
    target's own measurement (log change, variance; NaN where none) and the frame interval."""
    src = open_source(path)
    truth = getattr(src, "truth", None)
    if not truth or truth[0] is None:
        return None
    gt = np.array([t if t is not None else (np.nan,) * 4 for t in truth], float)
    est = CameraMotionEstimator(StabiliserConfig(model=model))
    zoom, size, own, var, length = [], [], [], [], []
    prev_image = None
    for i, frame in enumerate(src):
        if i == 0:
            est.start(frame.image)
            prev_image = frame.image
            continue
        prev = gt[i - 1]
        centre = np.array([prev[0] + prev[2] / 2, prev[1] + prev[3] / 2])
        est.update(frame.image, centre, exclusion_lengths * max(prev[2], prev[3]))
        j = homography_jacobian(est.last.interframe, centre)
        zoom.append(0.5 * math.log(abs(float(np.linalg.det(j)))))
        size.append(0.5 * math.log(gt[i, 2] * gt[i, 3] / (prev[2] * prev[3])))
        m = measure_scale_change(flow_cfg, prev_image, frame.image, (*centre, prev[2], prev[3], 0.0),
                                 est.last.interframe) if np.all(np.isfinite(prev)) else None
        own.append(np.nan if m is None else m.dlog)
        # the variance without its floor (the floor is recomputed for each point noise below)
        var.append(np.nan if m is None else m.var - noise_floor(flow_cfg.point_noise_px, m.length_px))
        length.append(np.nan if m is None else m.length_px)
        prev_image = frame.image
    zoom, size = np.array(zoom), np.array(size)
    ok = np.isfinite(zoom) & np.isfinite(size)
    return {"zoom": np.where(ok, zoom, 0.0), "size": np.where(ok, size, 0.0), "own": np.array(own),
            "var": np.array(var), "work_length": np.array(length), "dt": 1.0 / src.fps}


def fused(d: dict, noise: float, time_constant: float, departure: float) -> np.ndarray:
    """The scale state's predicted change of log size per frame: ScaleTracker.predict's fusion with
    the departure's variance estimated from the innovations, for point noise ``noise``."""
    q_rate = departure ** 2
    out = d["zoom"].copy()
    for i, (z, m) in enumerate(zip(d["zoom"], d["own"])):
        if np.isfinite(m):
            r = d["var"][i] + noise_floor(noise, d["work_length"][i])
            out[i], q_rate = fuse_with_zoom(z, m, r, q_rate, d["dt"], time_constant)
    return out


def window_rms(pred: np.ndarray, size: np.ndarray, window: int) -> float:
    rows = [(pred[s:s + window].sum() - size[s:s + window].sum()) for s in range(0, len(pred) - window + 1, window)]
    return float(np.sqrt(np.mean(np.square(rows)))) if rows else float("nan")


GRID_NOISE = (0.1, 0.25, 0.5, 1.0)
GRID_TIME_CONSTANT = (0.5, 1.0, 2.0)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("sequence", nargs="+")
    p.add_argument("--window", type=int, default=30, help="frames per window")
    p.add_argument("--model", choices=["homography", "affine", "similarity"], default="homography",
                   help="the stabiliser's frame-to-frame model")
    p.add_argument("--exclusion-lengths", type=float, default=StabiliserConfig().exclusion_lengths,
                   help="radius of the featureless disc about the target, in target lengths")
    p.add_argument("--grid", action="store_true",
                   help="the fused RMS over a grid of (point_noise_px, departure_time_constant_s), and the "
                        "leave-one-sequence-out choice from it")
    a = p.parse_args(argv)
    cfg = TargetFlowConfig()
    data = {}
    for path in a.sequence:
        d = probe(path, a.model, a.exclusion_lengths, cfg)
        if d is None:
            print(f"zoom_probe: {path} has no ground truth (groundtruth_rect.txt)", file=sys.stderr)
            return 2
        name = Path(path).name
        data[name] = d
        pred = fused(d, cfg.point_noise_px, cfg.departure_time_constant_s, cfg.departure_per_sqrt_s)
        print(f"{path}: {len(d['zoom'])} frame pairs, {a.model}; the target's own change measured on "
              f"{np.isfinite(d['own']).mean():.0%} of them")
        for s in range(0, len(d["zoom"]), a.window):
            sl = slice(s, s + a.window)
            own = np.where(np.isfinite(d["own"][sl]), d["own"][sl], 0.0).sum()
            print(f"  frames {s + 1:4d}-{min(s + a.window, len(d['zoom'])):4d}: camera zoom at the target "
                  f"{math.exp(d['zoom'][sl].sum()):6.2f}  target's own {math.exp(own):6.2f}  "
                  f"fused {math.exp(pred[sl].sum()):6.2f}  truth {math.exp(d['size'][sl].sum()):6.2f}")
        z, t = d["zoom"], d["size"]
        print(f"  RMS log error per window: with the zoom {window_rms(z, t, a.window):.3f}, without "
              f"{window_rms(0 * z, t, a.window):.3f}, half of it {window_rms(0.5 * z, t, a.window):.3f}, "
              f"fused with the target's own {window_rms(pred, t, a.window):.3f}")
    if a.grid:
        table = {(n, tau): {k: window_rms(fused(d, n, tau, cfg.departure_per_sqrt_s), d["size"], a.window)
                            for k, d in data.items()}
                 for n in GRID_NOISE for tau in GRID_TIME_CONSTANT}
        print("fused RMS log error per window, point_noise_px x departure_time_constant_s: " + ", ".join(data))
        for (x, n), row in table.items():
            print(f"  {x:4.2f} {n:4.2f}: " + " ".join(f"{v:.3f}" for v in row.values()) +
                  f"  mean {np.mean(list(row.values())):.3f}")
        if len(data) > 1:
            print("leave one sequence out (parameters minimising the others' mean; the held-out RMS):")
            for k in data:
                best = min(table, key=lambda xn: np.mean([v for kk, v in table[xn].items() if kk != k]))
                print(f"  {k}: {best[0]:.2f} {best[1]:.2f} -> {table[best][k]:.3f} "
                      f"(configured {table.get((cfg.point_noise_px, cfg.departure_time_constant_s), {}).get(k, float('nan')):.3f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
