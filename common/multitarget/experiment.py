"""Run the multi-target trackers side by side on a people scene and score them.

:func:`evaluate_scene` is what ``polartrack eval-multi`` runs per scene seed and setting. Every
method sees the same frames and the same :class:`~.appearance.HistogramEvidence` (built once per
frame, timed separately as ``evidence_ms_per_frame``); ``ms_per_frame`` is the tracker's own
``step`` time. Filters are initialised from the first frame's ground truth (the paper initialises
with a pictorial-structure detector, section 4.1) or, with ``init="boxes"``, from the people's
bounding boxes alone, as ``polartrack run`` / ``track`` start (a standing body in each box, shifted
to where its core stands out: :mod:`.placement`), and seeded with the scene seed.

Monte Carlo runs (``runs``, the paper's "Monte Carlo cycles", section 4.1: its per-clip RMSE is a mean
over 100 of them, Figs. 5-6): every method tracks the same frames ``runs`` times with independent
filter seeds (:func:`filter_seed`; run 0 is seeded with the scene seed, as a single run is), and a
method's figures for the scene are the means over the runs, so that a per-scene comparison of two
methods compares their expected errors rather than one draw of each filter's randomness.
"""

from __future__ import annotations

import time

import numpy as np

from ..scene.people import PeopleScene, PeopleSceneConfig
from . import make_filter
from .appearance import HistogramEvidence
from .body import body_model
from .config import MultiTargetConfig
from .metrics import combined_rmse, identities_kept, mot_metrics, ospa
from .placement import start_from_boxes
from .state import MultiInit


def filter_seed(seed: int, run: int) -> int | np.random.SeedSequence:
    """Seed of Monte Carlo run ``run`` on scene ``seed``: the scene seed for run 0 (a single run is
    seeded as it always was), an independent ``SeedSequence((seed, run))`` for the others."""
    return seed if run == 0 else np.random.SeedSequence((seed, run))


def evaluate_scene(scene_config: PeopleSceneConfig, seed: int, configs: dict[str, MultiTargetConfig],
                   runs: int = 1, init: str = "truth") -> dict:
    """Track scene ``seed`` with every config ``runs`` times (Monte Carlo runs with independent filter
    seeds, on the same frames and evidence); per method: RMSE per target, timings, MOT scores and
    tracks, means over the runs, with the per-run RMSE and identity checks. ``init``: ``truth`` (the
    first frame's part positions) or ``boxes`` (the people's boxes only)."""
    if runs < 1:
        raise ValueError("runs must be at least 1")
    if init not in ("truth", "boxes"):
        raise ValueError(f"init must be 'truth' or 'boxes', got {init!r}")
    scene = PeopleScene(scene_config, seed=seed)
    first = scene.frame(0)
    ev = HistogramEvidence(first.image, next(iter(configs.values())).histogram)
    filters = {}
    for name, cfg in configs.items():
        body = body_model(cfg.n_parts)
        if init == "truth":
            start = MultiInit.from_truth(first.truth.parts, first.truth.boxes, body)
        else:
            start, _ = start_from_boxes(first.truth.boxes, body, ev, cfg.placement)
        filters[name] = [make_filter(cfg, start, ev, filter_seed(seed, r)) for r in range(runs)]
    est = {k: [[] for _ in range(runs)] for k in configs}
    elapsed = {k: 0.0 for k in configs}
    ev_time = 0.0
    truth = []
    for i in range(len(scene)):
        frame = first if i == 0 else scene.frame(i)
        if i:
            t0 = time.perf_counter()
            ev = HistogramEvidence(frame.image, next(iter(configs.values())).histogram)
            ev_time += time.perf_counter() - t0
        for name, flts in filters.items():
            for r, flt in enumerate(flts):
                t0 = time.perf_counter()
                state = flt.step(frame.time, ev)
                elapsed[name] += time.perf_counter() - t0
                est[name][r].append(state.parts)
        truth.append(frame.truth.parts)
    truth = np.array(truth)  # (F, T, 10, 2)
    heights = np.array([w.height for w in scene.walkers])
    last_cross = max((c[2] for c in scene.crossings), default=0)
    out = {"seed": seed, "runs": runs, "init": init, "crossings": scene.crossings, "n_frames": len(scene),
           "evidence_ms_per_frame": 1e3 * ev_time / max(len(scene) - 1, 1), "methods": {}}
    for name, cfg in configs.items():
        body = filters[name][0].body
        gt = body.from_ten(truth)
        per_run = []
        for r in range(runs):
            e = np.array(est[name][r])
            torso_e, torso_t = e[:, :, 0], gt[:, :, 0]
            kept = identities_kept(torso_e, torso_t, max_error=0.25 * heights.min(),
                                   last=max(1, min(10, len(scene) - last_cross)))
            per_run.append({
                "rmse_per_target": combined_rmse(e, gt), "identities_kept": bool(kept.all()),
                "ospa": float(np.mean([ospa(a, b) for a, b in zip(torso_e, torso_t)])),
                **mot_metrics(torso_e, torso_t, match_radius=0.25 * heights.min()),
                "error_per_frame": np.sqrt(np.sum((e - gt) ** 2, axis=-1).mean(axis=2)),  # (F, T)
            })
        rmse = np.mean([p["rmse_per_target"] for p in per_run], axis=0)
        out["methods"][name] = {
            "rmse": float(rmse.mean()), "rmse_per_target": rmse.tolist(),
            "rmse_runs": [float(p["rmse_per_target"].mean()) for p in per_run],
            "ms_per_frame": 1e3 * elapsed[name] / (len(scene) * runs),
            "identities_kept": all(p["identities_kept"] for p in per_run),
            "identities_kept_runs": [p["identities_kept"] for p in per_run],
            "ospa": float(np.mean([p["ospa"] for p in per_run])),
            "mota": float(np.mean([p["mota"] for p in per_run])),
            "idf1": float(np.mean([p["idf1"] for p in per_run])),
            "id_switches": int(sum(p["id_switches"] for p in per_run)),
            "error_per_frame": np.mean([p["error_per_frame"] for p in per_run], axis=0).tolist(),  # (F, T)
        }
    return out
