"""Knobs of the synthetic surveillance scene of walking people, each documented once, in its ``Field``.

``PeopleSceneConfig()`` is the default: 384x288 at 25 fps (the CAVIAR format of Bhaskar and
Mihaylova 2011, section 4.1) for 80 frames, three people about 70 px tall ("the scales of the human
targets are fairly small in comparison with the resolution of the image", section 4.1; the INRIA-lobby
clips of its Table 1) walking across the floor in both directions so that they cross and occlude each
other, six clutter boxes in clothing-like colours, two look-alikes per person (people standing still in
clothes like the person's: whole-body clutter inside the validation gates, the "clutter or other
measurements that all fall within a validation gate" that the association has to tell from the
target), and a dimming of the light to 70% in the middle of the run.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class PeopleSceneConfig(BaseModel):
    """Everything that shapes a people scene except the seed (pass that to ``PeopleScene``)."""

    model_config = ConfigDict(frozen=True, extra="forbid", use_attribute_docstrings=True)

    width: int = Field(384, ge=128, le=4096)
    """Image width in pixels (CAVIAR: 384)."""
    height: int = Field(288, ge=128, le=4096)
    """Image height in pixels (CAVIAR: 288)."""
    fps: float = Field(25.0, gt=0, le=1000)
    """Frame rate; frame i is captured at i / fps s (CAVIAR: 25)."""
    n_frames: int = Field(80, ge=10, le=100_000)
    """Number of frames."""
    n_people: int = Field(3, ge=1, le=5)
    """Number of people (targets) in the scene, 1-5."""
    person_height_px: float = Field(70.0, ge=40, le=400)
    """Nominal standing height of a person in pixels; each person varies it by +-8% (seeded). At 70 px
    the paper's 15 px gate is 0.2 H, and a look-alike standing 10-15 px from the person is a measurement
    of its own (the whole-structure colour match has two peaks); at 110 px the two merge."""
    speed_px_s: float = Field(40.0, ge=0, le=400)
    """Nominal walking speed in px/s; each person varies it by +-20% (seeded)."""
    lane_spread_px: float = Field(14.0, ge=0, le=200)
    """Feet of different people walk on horizontal lanes within this many pixels of each other, so that
    people walking opposite ways overlap (the nearer one, lower in the image, is drawn in front)."""
    leg_swing_deg: float = Field(25.0, ge=0, le=60)
    """Amplitude of the thigh swing while walking."""
    arm_swing_deg: float = Field(22.0, ge=0, le=60)
    """Amplitude of the upper-arm swing (opposite to the legs)."""
    n_clutter: int = Field(6, ge=0, le=100)
    """Static background objects whose colours are the people's clothing colours with a small hue shift:
    measurements that look like a part but are clutter."""
    lookalikes_per_person: int = Field(2, ge=0, le=10)
    """Static person-shaped clutter (people standing still) per walking person, standing just behind the
    person's lane where it passes at stratified random times, in the person's shirt with its hue turned
    by lookalike_hue_deg and other trousers and skin: a whole-body candidate that enters the person's
    validation gate as it walks past, colour-similar but less so than the person itself."""
    lookalike_hue_deg: tuple[float, float] = (25.0, 40.0)
    """Range of the hue turn (degrees, random sign) of a look-alike's shirt against its person's (12 hue
    bins of 15 degrees: a turn within one or two bins leaves a look-alike as similar as the person
    itself)."""
    illumination_low: float = Field(0.7, gt=0.05, le=1.5)
    """Light level (gain on every pixel) after the illumination change; 1.0 disables it."""
    illumination_change: tuple[float, float] = (0.45, 0.6)
    """Fractions of the run over which the light ramps linearly from 1.0 to illumination_low."""
    noise_sigma: float = Field(3.0, ge=0, le=64)
    """Std of the per-pixel sensor noise, grey levels (0: none)."""
