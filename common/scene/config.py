"""Difficulty knobs of the synthetic aerial scene, each documented once, in its ``Field``.

``SceneConfig()`` is the default scene: 1280x720 at 30 fps for 300 frames (10 s), a 4.5 m red
car that is about 50x24 px, a 1.5 s smoke blackout, a maroon decoy passing at 1.5 car lengths,
a building edge hiding half the car for a while, and a slowly drifting, rotating, zooming camera.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

RGB = tuple[int, int, int]

# The smoke is placed on a straight stretch of the target's path that spans this fraction of the
# run (see ``paths.SCHEDULE``); its blackout must fit in it.
MAX_SMOKE_FRACTION_OF_RUN = 0.25


class SceneConfig(BaseModel):
    """Everything that shapes a synthetic scene except the seed (pass that to ``SyntheticScene``)."""

    model_config = ConfigDict(frozen=True, extra="forbid", use_attribute_docstrings=True)

    # --- video -------------------------------------------------------------------------------
    width: int = Field(1280, ge=64, le=8192)
    """Image width in pixels."""
    height: int = Field(720, ge=64, le=8192)
    """Image height in pixels."""
    fps: float = Field(30.0, gt=0, le=1000)
    """Frame rate; frame i is captured at i / fps s."""
    n_frames: int = Field(300, ge=20, le=100_000)
    """Number of frames. The manoeuvres (turns, smoke, decoy pass, wall) are placed at fixed fractions
    of the run, so a shorter run squeezes them."""
    noise_sigma: float = Field(4.0, ge=0, le=64)
    """Std of the per-pixel, per-channel sensor noise in grey levels (0 = no noise)."""

    # --- vehicles ----------------------------------------------------------------------------
    car_length_m: float = Field(4.5, gt=1, le=20)
    """Length of the target (and decoy) car in metres."""
    car_width_m: float = Field(2.1, gt=0.5, le=5)
    """Width of the target (and decoy) car in metres."""
    speed_mps: float = Field(6.5, gt=0, le=40)
    """Nominal target speed in m/s (each seed varies it by +-10%; the car slows in the sharp turn)."""
    target_color: RGB = (205, 28, 32)
    """RGB body colour of the target car."""
    decoy: bool = True
    """Whether the look-alike decoy car is in the scene."""
    decoy_color: RGB = (128, 18, 38)
    """RGB body colour of the decoy car (same size and shape as the target)."""
    decoy_distance_car_lengths: float = Field(1.5, gt=0)
    """Closest centre-to-centre distance between decoy and target, in car lengths. The decoy drives the
    opposite way on a parallel line at this offset and passes the target at about 57.5% of the run."""

    # --- occlusion ---------------------------------------------------------------------------
    smoke_duration_s: float = Field(1.5, ge=0)
    """How long the smoke cloud hides the target completely (visible_fraction == 0), in seconds, rounded
    to whole frames. 0 removes the smoke."""
    smoke_edge_m: float = Field(1.5, gt=0, le=30)
    """Mean width in metres of the cloud's soft, semi-transparent rim."""
    wall_cover_fraction: float = Field(0.5, ge=0, le=0.95)
    """Fraction of the car's width hidden by the building edge while the car drives along it
    (visible_fraction is about 1 minus this). 0 removes the wall."""

    # --- camera ------------------------------------------------------------------------------
    pixels_per_metre: float = Field(50 / 4.5, gt=0.5, le=200)
    """Ground resolution at the image centre in the first frame (sets the zoom)."""
    camera_altitude_m: float = Field(120.0, gt=5, le=5000)
    """Height of the camera above the ground."""
    camera_tilt_deg: float = Field(5.0, ge=0, le=40)
    """Tilt of the optical axis away from nadir (adds mild perspective)."""
    camera_follow: float = Field(0.5, ge=0, le=1)
    """How much the camera follows the (heavily smoothed) target path: 0 hovers, 1 keeps the smoothed
    path at the image centre."""
    camera_drift_m: float = Field(6.0, ge=0, le=500)
    """Extra translation drift of the camera's ground point over the run, in metres."""
    camera_rotation_deg: float = Field(8.0, ge=-180, le=180)
    """Total yaw change of the camera over the run, in degrees."""
    camera_zoom_change: float = Field(0.08, gt=-0.5, le=1.0)
    """Fractional focal-length change over the run (+0.08: the last frame is 8% more zoomed in than the
    first)."""
    camera_jitter_m: float = Field(0.04, ge=0, le=10)
    """Amplitude of the small, smooth wobble of the camera position, in metres."""

    # --- ground ------------------------------------------------------------------------------
    texture_image: str | None = None
    """Optional path of an aerial photograph to use as ground texture instead of the procedural town
    (e.g. ../shared/data/opencv-aerial/aero1.jpg). Used only if the file exists; otherwise a warning is
    issued and the procedural ground is used."""
    n_parked_cars: int = Field(30, ge=0, le=2000)
    """Number of parked clutter cars (never red) along the side streets."""

    @field_validator("target_color", "decoy_color")
    @classmethod
    def _check_rgb(cls, v: RGB) -> RGB:
        if any(not 0 <= c <= 255 for c in v):
            raise ValueError(f"colour components must be in 0..255, got {v}")
        return v

    @model_validator(mode="after")
    def _check_consistency(self) -> SceneConfig:
        run_s = self.duration_s
        max_smoke = MAX_SMOKE_FRACTION_OF_RUN * run_s
        if self.smoke_duration_s > max_smoke:
            raise ValueError(
                f"smoke_duration_s={self.smoke_duration_s:g} s is too long for a run of "
                f"n_frames/fps = {self.n_frames}/{self.fps:g} = {run_s:g} s: the smoke must fit in "
                f"{MAX_SMOKE_FRACTION_OF_RUN:.0%} of the run, i.e. at most {max_smoke:g} s"
            )
        if 0 < self.smoke_duration_s * self.fps < 0.5:
            raise ValueError(
                f"smoke_duration_s={self.smoke_duration_s:g} s is shorter than half a frame at "
                f"{self.fps:g} fps; use 0 to remove the smoke"
            )
        min_gap = (self.car_width_m + 0.3) / self.car_length_m
        if self.decoy and self.decoy_distance_car_lengths < min_gap:
            raise ValueError(
                f"decoy_distance_car_lengths={self.decoy_distance_car_lengths:g} would make the cars "
                f"overlap: it must be at least (car_width_m + 0.3 m) / car_length_m = {min_gap:.3f}"
            )
        if self.car_width_m >= self.car_length_m:
            raise ValueError(
                f"car_width_m={self.car_width_m:g} must be smaller than car_length_m={self.car_length_m:g}"
            )
        return self

    @property
    def duration_s(self) -> float:
        """Length of the run in seconds (n_frames / fps)."""
        return self.n_frames / self.fps

    @property
    def decoy_distance_m(self) -> float:
        """Closest decoy distance in metres."""
        return self.decoy_distance_car_lengths * self.car_length_m
