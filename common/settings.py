"""Tracker settings: every knob of a tracking run, with its documentation, in one place.

The same object configures the in-process run (``polartrack track``), the tracker service and
replay; it is recorded (as JSON) in the MCAP metadata.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from common.tracking import RBPFConfig, SIRConfig, WindowedMLConfig
from common.tracking.motion import NearConstantVelocity

FilterName = Literal["rbpf", "sir", "ml"]


class TemplateAdaptation(BaseModel):
    """Template update when the posterior is confident the target is visible (not in the papers)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    enabled: bool = Field(False, description="Adapt the template at all.")
    min_p_visible: float = Field(0.95, ge=0, le=1, description="Only when p(V=1|Z) is at least this.")
    min_score: float = Field(0.7, ge=-1, le=1, description="... and the estimate's own score is at least this.")
    rate: float = Field(0.1, ge=0, le=1, description="Blend weight of the new appearance per update.")
    anchor: float = Field(0.5, ge=0, le=1, description="Weight of the ORIGINAL template kept in every blend: "
                          "the guard against drift (the template never strays further from the original).")


class TrackerSettings(BaseModel):
    """Everything that determines a run's estimates (with the source and the initial box)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    filter: FilterName = Field("rbpf", description="rbpf (Pang), sir (Nelson) or ml (windowed search).")
    particles: int | None = Field(None, ge=1, description="Particles (rbpf, sir); None: the filter's default.")
    seed: int = Field(0, description="Seed of the filter's random generator.")
    rbpf: RBPFConfig = Field(default_factory=RBPFConfig)
    sir: SIRConfig = Field(default_factory=SIRConfig)
    ml: WindowedMLConfig = Field(default_factory=WindowedMLConfig)
    adaptation: TemplateAdaptation = Field(default_factory=TemplateAdaptation)
    stabilise: Literal["auto", "on", "off"] = Field(
        "auto", description="Estimate camera motion from the background when the source gives no homography "
        "(auto), always (on) or never (off: the image is the world frame).")
    init_pos_std: float = Field(0.0, ge=0, description="Initial spread of the particles' position (world units).")
    init_vel_std: float = Field(10.0, ge=0, description="Initial spread of the particles' velocity (world units "
                                "per second): the first box says where the target is, not how it moves.")


SYNTHETIC_BETA = {"a1": 5.69, "b1": 2.81, "a0": 0.25, "b0": 8.08}
"""Beta parameters fitted by ``polartrack calibrate synthetic:100 --frames 100 --per-frame 30``
(a scene seed kept out of every evaluation): visible Beta(5.69, 2.81), background
Beta(0.25, 8.08). Pang's Beta(5, 7) / Beta(1, 7) were fitted to their own detector and video."""


def profile_for(source, filter: FilterName = "rbpf", **kw) -> TrackerSettings:
    """Default settings for a source: the synthetic scene's calibrated profile, or Pang's model
    converted to the source's frame rate, in stabilised pixels, for real footage."""
    from common.tracking import BetaRatioLikelihood

    if getattr(source, "name", "").startswith("synthetic"):
        st = rate_adjusted_settings(source.fps, filter=filter, **kw)
        return st.model_copy(update={"rbpf": st.rbpf.model_copy(update={"likelihood": BetaRatioLikelihood(**SYNTHETIC_BETA)})})
    # Real footage: world = the first frame's (stabilised) pixels. Motion noise in px^2 s^-3
    # for targets a few tens of pixels long moving at up to ~100 px/s.
    kw.setdefault("init_vel_std", 50.0)
    return rate_adjusted_settings(source.fps, filter=filter, q_motion=400.0, **kw)


def rate_adjusted_settings(fps: float, filter: FilterName = "rbpf", q_motion: float = 4.0, **kw) -> TrackerSettings:
    """Pang's Table 1 model converted from its 3 fps sequence to a source at ``fps``.

    Table 1 gives per-step quantities at T = 1/3 s: orientation variance 16 deg^2 per step
    (48 deg^2 per second; raised to 150 deg^2/s for the sharper turns of the synthetic car, the
    per-frame variance scaling with the frame interval) and
    visibility switching probabilities 0.1 per step (here the per-frame probability with the
    same rate per second, 1 - 0.9^(3/fps)). The motion variance is refitted to the scene, as
    Pang's was ("empirically chosen and fitted to the video data"): the synthetic car drives
    smooth curves at about 10 m/s, so ``q = 4 m^2 s^-3`` (625 would let the cloud spread over
    tens of metres in one second of occlusion).
    """
    from common.tracking import OrientationRandomWalk, VisibilityMarkovChain

    p = 1.0 - 0.9 ** (3.0 / fps)
    motion = NearConstantVelocity(q_x=q_motion, q_y=q_motion)
    # 150 deg^2/s: the synthetic car turns at up to ~70 deg/s; Pang's 16 deg^2 per 1/3 s step
    # (48 deg^2/s) lags such turns by tens of degrees.
    orientation = OrientationRandomWalk(q_theta=150.0, per="second")
    visibility = VisibilityMarkovChain(p_nv=p, p_v=p)
    rbpf = RBPFConfig(motion=motion, orientation=orientation, visibility=visibility)
    sir = SIRConfig(motion=motion, orientation=orientation)
    return TrackerSettings(filter=filter, rbpf=rbpf, sir=sir, **kw)
