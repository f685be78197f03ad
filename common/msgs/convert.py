"""TrackState -> Estimate / ParticleCloud messages (no bus code)."""

from __future__ import annotations

import time

import numpy as np

from common.msgs import Estimate, ParticleCloud, pack


def estimate_msg(frame_index: int, capture_ns: int, state, filter_name: str, skipped: int = 0,
                 step_ms: float = 0.0) -> Estimate:
    m, mm = state.map_estimate, state.mmse_estimate
    return Estimate(
        frame_index=frame_index, time_s=state.time, observed=state.observed, filter=filter_name,
        x=m.image_x, y=m.image_y, theta_deg=m.theta, p_visible=state.p_visible, world_x=m.x, world_y=m.y,
        vx=m.vx, vy=m.vy, speed=state.speed, mmse_x=mm.image_x, mmse_y=mm.image_y,
        n_eff=float(state.n_eff) if np.isfinite(state.n_eff) else 0.0, resampled=bool(state.resampled),
        frames_skipped=skipped, step_ms=step_ms, latency_ms=(time.time_ns() - capture_ns) / 1e6)


def particles_msg(frame_index: int, state) -> ParticleCloud | None:
    if state.particles is None:
        return None
    n = len(state.particles)
    pv = state.particle_visibility if state.particle_visibility is not None else np.full(n, state.p_visible)
    return ParticleCloud(frame_index=frame_index, time_s=state.time, count=n, particles=pack(state.particles),
                         image_xy=pack(state.particles_image), weights=pack(state.weights), p_visible=pack(pv))
