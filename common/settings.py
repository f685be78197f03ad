"""Tracker settings: every knob of a tracking run, with its documentation, in one place.

The same object configures the in-process run (``polartrack track``), the tracker service and
replay; it is recorded (as JSON) in the MCAP metadata.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from common.single_target.stabilise import StabiliserConfig
from common.single_target.target_flow import TargetFlowConfig
from common.tracking import RBPFConfig, SIRConfig, WindowedMLConfig
from common.tracking.motion import NearConstantVelocity

FilterName = Literal["rbpf", "sir", "ml"]
ProfileName = Literal["synthetic", "real"]
"""The named profiles (:data:`PRESETS`)."""


class TemplateAdaptation(BaseModel):
    """Template update when the posterior is confident the target is visible (not in the papers).

    The P-matrix sampled on the current frame (at the current matching scale) where the current
    template matches best near the MAP (``align_lengths``) is rotated back by the refined angle there
    to the template's orientation (:func:`common.detector.template.rotate_pmatrix`), normalised, and
    blended into an adaptive part ``A <- normalise((1 - rate) A + rate F)``; the template used is
    ``normalise(anchor * H0 + (1 - anchor) * A)`` with ``H0`` the normalised original: however
    many updates, the original keeps weight ``anchor`` (see :mod:`common.single_target.adaptation`)."""

    model_config = ConfigDict(frozen=True, extra="forbid", use_attribute_docstrings=True)

    enabled: bool = False
    """Adapt the template at all (the real-footage profile does)."""
    min_p_visible: float = Field(0.95, ge=0, le=1)
    """Only when p(V=1|Z) is at least this."""
    min_score: float = Field(0.7, ge=-1, le=1)
    """... and the estimate's own score (refined over the angle) is at least this (the real-footage
    profile: 0.5, see REAL_ADAPTATION)."""
    rate: float = Field(0.1, ge=0, le=1)
    """Blend weight of the new appearance per update."""
    anchor: float = Field(0.5, ge=0, le=1)
    """Weight of the ORIGINAL template kept in every blend: the guard against drift (the template never
    strays further from the original)."""
    interval_s: float = Field(0.1, ge=0)
    """At most one update per this many seconds (0: every frame that passes the gates); keeps the
    adaptation rate per second, not per frame, whatever the frame rate."""
    hold_after_restart_s: float = Field(0.5, ge=0)
    """No update for this many seconds after a re-acquisition restarts the filter: the restart is
    where the search registered the target, its cloud ``reacquisition.restart_pos_lengths`` wide, and
    until the cloud has settled on the peak an update would take in a view off the target's centre,
    which the template then keeps matching
    (the synthetic re-entry: 5 px off for good, when the first update came the frame after it)."""
    align_lengths: float = Field(0.25, ge=0)
    """The update is taken where the template being matched registers the target best within this
    many target lengths of the MAP (a grid a sixteenth of a length apart, then a sixty-fourth about
    its best), and skipped where that best lies farther (0: at the MAP itself). The posterior's
    mode lags the target and carries the motion prior's smoothing; a sample taken off the target's
    centre is kept by the template, which then matches best off the centre too, and the offsets add
    up update after update (Matthews, Ishikawa and Baker's template-update problem)."""


class SegmentRegistration(BaseModel):
    """The template re-registered on a segmentation of the target (not in the papers; see
    :mod:`common.single_target.segment`).

    Template adaptation registers each update where the template itself matches best, so an error
    in its registration is kept and grows (Matthews, Ishikawa and Baker's template-update problem);
    the anchor to the original bounds the drift but not the offset. Every ``interval_s`` while the
    target is held but matched poorly, GrabCut segments it in a square about the estimate (the colour of what is
    inside against what is around it: independent of the template); where the segment is shaped
    like a vehicle, the template is built again at the segment's centre and the matching scale set
    from the segment's length, in the relation the first box's own segment had to the first box's
    length."""

    model_config = ConfigDict(frozen=True, extra="forbid", use_attribute_docstrings=True)

    enabled: bool = False
    """Re-register at all (the real-footage profile does; needs the frames' pixels, i.e. a stabilising
    tracker)."""
    interval_s: float = Field(1.0, gt=0)
    """At most one segmentation per this many seconds: the adaptation's time constant (about a
    second, ``REAL_ADAPTATION``), within which its registration error builds up."""
    min_p_visible: float = Field(0.5, ge=0, le=1)
    """Only while p(V=1|Z) is at least this (the target held, as ``reacquisition.lost_p_visible``)."""
    score_quantile: float = Field(0.5, gt=0, le=1)
    """... and while the estimate's own score is below this quantile of the likelihood's Beta for a
    visible target (the median, 0.69 for the synthetic fit): the template's registration is in
    question only where it matches the target it holds worse than it matches a visible target
    half the time. A template that matches well is not moved: GrabCut's segment of a two-tone
    vehicle is bistable (a dark windscreen in or out of it), and would otherwise move a template
    that holds the target to within a pixel (docs/real-footage.md, stop 35)."""
    reach_lengths: float = Field(1.0, gt=0)
    """GrabCut's rectangle: this many target lengths either side of the estimate (the target inside
    it whatever its orientation, for a registration error up to half a length)."""
    margin_lengths: float = Field(1.0, gt=0)
    """... inside a crop a further this many lengths wide: the background the colour models learn."""
    work_px: int = Field(128, ge=32)
    """The crop is worked at this size (its long side): the CPU per segmentation stays bounded
    whatever the target's size."""
    iterations: int = Field(3, ge=1)
    """GrabCut's iterations (OpenCV's example uses a few; the segment changes little after three)."""
    area_range: tuple[float, float] = (0.2, 2.0)
    """The segment (its largest connected component) counts only when its area is within this range
    of the track's box's: a loose first box holds a vehicle in a fifth of it; above twice the box, the
    segment has taken in the road or a neighbour."""
    centre_box: bool = True
    """Fit the reported box to the target's segment as well, every ``interval_s`` while held, where
    the template is not re-registered (it matches well): the template holds a point of the target,
    not always its centre (a car's textured end: car16's rear light for 30 frames, 20 px off), and
    its box is the first box times the scale, whatever the target's outline now; a template that
    matches well is not moved (``score_quantile``), so the box takes the segment's centre and extent
    instead, kept in the target's own axes relative to the point the template holds and to the
    track's box (turned and grown with them). Kept only while that point lies inside the box so
    fitted; dropped when the template is re-registered or the filter restarted. It changes the
    reported box alone, never what is tracked (docs/real-footage.md, stop 58)."""
    min_solidity: float = Field(0.7, ge=0, le=1)
    """... and when it fills at least this much of its minimum-area rectangle. A vehicle is about a
    box: seen from above its outline is a rounded rectangle (0.85-1.0), and seen obliquely, as from
    a drone that follows it, a hexagon, which fills at least 3/4 of its rectangle from any view (the
    regular hexagon's share). As the segment's pixels measure it at ``work_px``, a car's outline at
    its worst view fills 0.72-0.75; 0.7 is that less a margin. A part of one with road or shadow
    about it is ragged (a part of uavdt-S0310's bus with road about it, 0.46-0.72; docs/real-footage.md,
    stops 35 and 56)."""


class ScaleSettings(BaseModel):
    """Matching at the target's scale (see :mod:`common.single_target.scale` and :mod:`common.detector.resample`).

    The frame is matched resampled by ``k = u / s_t``: ``u`` enlarges a small target so that its
    long side is about ``target_size_px`` (chosen once from the initial box), ``s_t`` is the
    target's apparent size relative to the first frame, so the template's fixed footprint
    always sees the target at about its original size."""

    model_config = ConfigDict(frozen=True, extra="forbid", use_attribute_docstrings=True)

    mode: Literal["auto", "homography", "search", "off"] = "auto"
    """How s_t is kept: 'homography' from the source's ground-plane homography (the Jacobian at the
    estimate relative to the first frame's); 'search' by comparing the MAP's match score at neighbouring
    scales every search_interval_s (the camera's frame-to-frame zoom, when stabilising, predicts between
    searches); 'auto' = homography when the source gives one, else search; 'off' = s_t = 1."""
    target_size_px: float | None = Field(48.0, gt=0)
    """Upsample a target whose initial box's long side is shorter than this so that it is about this
    long in the matched image (the footprint the P-matrix layout was designed for: a ~50 px car); one
    longer than the template's whole footprint (128 px) is reduced to it. None: never resampled."""
    max_upsample: float = Field(4.0, ge=1)
    """Largest enlargement of the matched image while a target shrinks (k at most this or u, the
    larger): a target first boxed 12-48 px long is followed down to 12 px, a longer one down to a
    quarter of its first size, a shorter one (enlarged more, ``max_initial_upsample``) down to its
    own first size."""
    max_initial_upsample: float = Field(8.0, ge=1)
    """Largest enlargement u of the first box's target (a first box down to ``target_size_px`` / 8 =
    6 px long is matched at the template's design size). Enlarged less, a small target fills a small
    part of the template's footprint, the ground about it the rest, and the match slides along the
    road with the ground it carries (docs/real-footage.md, stop 46)."""
    min_factor: float = Field(1 / 16, gt=0, le=1)
    """Smallest overall resampling factor k (a target grown 16x beyond u is matched at 1/16 resolution,
    no less): with the upsampling, a 64x range of apparent size."""
    steps_per_octave: int = Field(12, ge=1)
    """k is quantised to 2^(n / this) (k = 1 exactly near 1)."""
    search_interval_s: float = Field(0.2, gt=0)
    """Seconds between two scale searches (the growth rate extrapolates between them)."""
    search_ratio: float = Field(1.12, gt=1)
    """Scales tried: s / ratio, s, s * ratio."""
    search_max_steps: int = Field(2, ge=0)
    """When the best of the three is at an end, move the three scales that way, at most this many steps
    (a fast-growing target), and never to a scale that cannot be scored."""
    search_below_footprint: bool = True
    """Where the template's footprint at the held scale (or the next larger) is not whole in the frame
    about the estimate, compare the largest scale whose footprint is (at most ``search_max_steps``
    below) with the next smaller, and move down when the smaller scores better: a scale run too large
    is otherwise never measured again, and a target as large as the frame shows is not shrunk by it."""
    search_gain: float = Field(1.0, gt=0, le=1)
    """Fraction of the measured log-scale correction applied."""
    search_rate_gain: float = Field(0.3, ge=0, le=1)
    """Scale-rate gain (the beta of an alpha-beta filter on log s): each search's correction also
    updates a growth rate d log(s)/dt extrapolated between searches (a target steadily approaching or
    receding). 0: no rate."""
    max_rate: float = Field(2.0, gt=0)
    """Largest |d log(s)/dt| (1/s): e^2 = 7x a second."""
    search_min_score: float = Field(0.5, ge=-1, le=1)
    """Search only when the best score is at least this (the target is seen well enough to measure its
    size)."""
    search_min_p_visible: float = Field(0.5, ge=0, le=1)
    """... and p(V=1|Z) at least this."""
    searches_after_restart: int = Field(3, ge=0)
    """After a re-acquisition restarts the filter, this many searches are made whatever the score and
    p(V=1|Z): the detection was confident, but its scale is the sweep's nearest step, and a target
    matched at the wrong scale scores below the minimum above, which would keep the search off."""
    flow: TargetFlowConfig = Field(default_factory=TargetFlowConfig)
    """The target's own change of size, measured from its pixels and fused with the camera's zoom in the
    prediction between searches (stabilised sources)."""


class ReacquisitionSettings(BaseModel):
    """Loss detection and the search that re-acquires a lost target (see :mod:`common.single_target.reacquire`)."""

    model_config = ConfigDict(frozen=True, extra="forbid", use_attribute_docstrings=True)

    enabled: bool = False
    """Search for the target once it is lost (the real-footage profile does)."""
    lost_p_visible: float = Field(0.5, ge=0, le=1)
    """The target counts as held while p(V=1|Z) is at least this and the estimate is inside the frame."""
    lost_after_s: float = Field(0.5, ge=0)
    """Lost once it has not been held for this many seconds in a row."""
    false_alarms_per_s: float = Field(0.05, gt=0)
    """Accept a detection whose score the background would reach this often a second over all the
    hypotheses searched (sets the score threshold from the likelihood's background Beta)."""
    min_score: float | None = Field(None, ge=-1, le=1)
    """A fixed acceptance score instead (None: from false_alarms_per_s)."""
    tile_px: int = Field(384, ge=64)
    """Side of a search tile in matched (resampled) pixels: bounds the search's CPU per frame."""
    tiles_per_frame: int = Field(1, ge=1)
    """Tiles searched per frame while lost."""
    tile_interval_s: float = Field(0.1, ge=0)
    """Least time between two frames whose tiles are searched (0: every searched frame): the tiles'
    CPU per second of footage. A tile costs more than a held frame (its crop's DTCWT, every angle);
    at 0.1 s, ten tiles a second, a 30 fps source searches them on every third searched frame, a
    source at 10 fps or less on every one. Each tile's threshold allows the false alarms of the whole
    time since the tiles searched before, so the false alarms a second do not depend on it."""
    grid_lengths: float = Field(0.3, gt=0)
    """Spacing of the candidate centres, in target lengths."""
    restart_pos_lengths: float = Field(0.25, gt=0)
    """The filter's position spread (1 sigma per axis, target lengths) when it restarts on a confirmed
    detection: how far the detection may lie from the target's centre. The search finds the target
    with a template of an earlier view (the view change is usually why the track was lost), and a
    view the template has not seen registers on a part of the target, a fraction of its length off
    its centre, not within the search grid's step; the likelihood pulls a cloud this wide onto the
    target over the next frames, where a narrower one holds the displaced registration as its mode
    and follows it off the target."""
    refine_candidates: int = Field(3, ge=1)
    """The best coarse candidates of a tile refined on finer grids."""
    scale_ratio: float = Field(2 ** 0.5, gt=1)
    """Successive sweeps of the frame search at the last held scale, then this much smaller and larger,
    ..."""
    scale_steps: int = Field(8, ge=0)
    """... up to this many ratios either way (8 ratios of sqrt(2): 16x), within the range the matching
    can follow."""
    assumed_interval_s: float = Field(0.1, gt=0)
    """Frame interval assumed for the threshold on the first search (later: the measured one)."""
    motion_search: bool = True
    """Where the tracker has the moving-target cue, look first for the frame's strongest mover each
    searched frame (a target that comes back looking different still moves over the ground)."""
    mover_tail_quantile: float = Field(0.9, gt=0.5, lt=1)
    """The movers' background tail is fitted beyond this quantile of the boxes' motion z-scores (an
    exponential tail over the threshold, as in peaks-over-threshold extreme-value fits)."""
    mover_tail_without_blob: bool = True
    """Fit the movers' background tail without the strongest mover's own moving blob (the boxes
    overlapping it): in boxes smaller than the target its other parts are not background. A blob
    larger than any target the frame could show (merged with its surroundings) is not left out."""
    mover_confirm_locally: bool = True
    """The confirming frame tests the pending mover's own hypothesis: the strongest box within the reach
    of the pending mover, its expected false alarms counted over the boxes within that reach (the
    hypotheses the confirmation searches), not over the whole frame's; a frame on which that fails
    is searched as any other."""
    mover_near_estimate: bool = True
    """Before the frame's strongest mover, test the strongest within a target length of where the
    filter's cloud is now (its MAP carried into the frame), its expected false alarms counted over
    the boxes there (the hypotheses that test searches): a target lost because its template stopped
    matching (its scale gone stale while it grew) is often still under the cloud, and the frame's
    strongest mover may be another vehicle (docs/real-footage.md, stop 52)."""
    mover_confirm_within_target: bool = True
    """Confirm a pending mover when the next frame's strongest mover lies within the target length it
    was matched at (at least a box length): in boxes smaller than the target the strongest one may lie
    on any of its parts from frame to frame."""
    movers_in_doubt: bool = False
    """While the hold is in doubt (p(V=1|Z) under ``lost_p_visible`` for less than ``lost_after_s``),
    test the strongest mover within a target length of the filter's cloud every frame, as
    ``mover_near_estimate`` does once lost, at ``doubt_false_alarms_per_s`` (the frame's other movers
    and the tiles wait for the lost state): a target that turned or swerved out of its template's
    match still moves under the cloud."""
    doubt_false_alarms_per_s: float = Field(0.005, gt=0)
    """The movers' false alarms a second allowed while the hold is in doubt (``false_alarms_per_s`` once
    lost): a tenth, since a restart in doubt replaces a cloud that may still be on the target (one
    hidden for a moment, a car under trees beside another) where once lost there is none to lose."""
    doubt_mover_off_lengths: float = Field(0.5, ge=0)
    """In doubt, a mover is pending only where it lies at least this many target lengths (at the held
    scale) from the cloud's point: nearer, it lies on the target as the cloud holds it (half a length
    either side of its centre), and a restart could only move a cloud that may be right to the
    matcher's peak at the moving blob's scale, off the target (a car under trees, 4 px off before
    such a restart and 18 px after)."""


class MotionCueSettings(BaseModel):
    """The moving-target cue of stabilised runs (see :mod:`common.single_target.motion_cue`): the
    motion energy of the stabiliser's double difference, an independent likelihood ratio for the
    target's position."""

    model_config = ConfigDict(frozen=True, extra="forbid", use_attribute_docstrings=True)

    enabled: bool = False
    """Use the cue where the tracker stabilises (the real-footage profile does); sources with their own
    homography, and runs that do not stabilise, have no cue."""
    baseline_s: float = Field(0.1, gt=0)
    """D, the time between the frames differenced (the current frame against D and 2 D before): a car
    at an urban 10 m/s moves about a quarter of its 4.5 m length in 0.1 s, enough for its edges to
    show, little enough for the difference to stay on it."""
    z_cap: float = Field(5.0, gt=0)
    """The largest robust z-score of a box's motion energy that counts: five sigma (a Gaussian tail of
    3e-7, log ratio 14.4), the usual bar for a detection; beyond it the background's tail is not
    known well enough (a real one is heavier than a Gaussian's) for more evidence to count."""
    region_lengths: float = Field(6.0, gt=0)
    """Half the side of the square about the last estimate where the energy and its background
    statistics are taken, in target lengths."""
    analysis_length_px: float = Field(32.0, gt=4)
    """The cue works on the pyramid level at which the target is at most this long (its CPU per frame
    stays bounded for a large target)."""
    min_boxes: int = Field(16, ge=4)
    """No cue on a frame whose region holds fewer target-sized boxes (at half a box's spacing) than
    this: too few for the background's median and spread."""


class TrackerSettings(BaseModel):
    """Everything that determines a run's estimates (with the source and the initial box)."""

    model_config = ConfigDict(frozen=True, extra="forbid", use_attribute_docstrings=True)

    filter: FilterName = "rbpf"
    """rbpf (Pang), sir (Nelson) or ml (windowed search)."""
    seed: int = Field(0, ge=0)
    """Seed of the filter's random generator."""
    rbpf: RBPFConfig = Field(default_factory=RBPFConfig)
    sir: SIRConfig = Field(default_factory=SIRConfig)
    ml: WindowedMLConfig = Field(default_factory=WindowedMLConfig)
    adaptation: TemplateAdaptation = Field(default_factory=TemplateAdaptation)
    scale: ScaleSettings = Field(default_factory=lambda: ScaleSettings(mode="off", target_size_px=None))
    """Matching scale. Default here: off (the services' pipeline); the real-footage profile uses
    ScaleSettings()'s own defaults (upsample small targets, track the scale)."""
    reacquisition: ReacquisitionSettings = Field(default_factory=ReacquisitionSettings)
    motion_cue: MotionCueSettings = Field(default_factory=MotionCueSettings)
    segment: SegmentRegistration = Field(default_factory=SegmentRegistration)
    stabilise: Literal["auto", "on", "off"] = "auto"
    """Estimate camera motion from the background when the source gives no homography (auto), always
    (on: replacing a source's homography; the world is then the first frame's pixels) or never (off: the
    image is the world frame)."""
    stabiliser: StabiliserConfig = Field(default_factory=StabiliserConfig)
    stabilised_world: Literal["first_frame", "previous_frame"] = "previous_frame"
    """World frame of a stabilised run's motion model: the first frame's pixels (world -> image
    homographies accumulated over the whole run: a long camera move makes that map strongly projective,
    so a fixed motion noise in world pixels means very different noise in the image), or the previous
    frame's pixels (the particles are carried into each new frame through the frame-to-frame homography,
    velocities through its Jacobian; the world unit is the target's current length, so the motion model
    is in target lengths whatever the zoom or the target's distance). The stabiliser accumulates the
    first-frame homography either way."""
    compensate_camera_rotation: bool = False
    """Turn the particles' orientation by the camera's own frame-to-frame image rotation at the target
    (from the homographies), so the orientation walk models the target's turns only."""
    motion_noise_lengths: float | None = Field(None, ge=0)
    """If set, the position filters' driving noise is sqrt(q) = this many target lengths per s^1.5 per
    axis, the target length being the initial box's long side in world units (q = (this * L)^2,
    overriding rbpf/sir.motion); None keeps the configured q."""
    jump_std_lengths: float | None = Field(None, gt=0)
    """If set, the RBPF's jump std (``rbpf.jump_std``) is this many target lengths (as above)."""
    init_vel_lengths: float | None = Field(None, ge=0)
    """If set, init_vel_std = this many target lengths per second (as above)."""
    init_pos_std: float = Field(0.0, ge=0)
    """Initial spread of the particles' position (world units)."""
    init_vel_std: float = Field(10.0, ge=0)
    """Initial spread of the particles' velocity (world units per second): the first box says where the
    target is, not how it moves."""

    @model_validator(mode="before")
    @classmethod
    def _one_particle_knob(cls, data):
        """The particle count is the filter's own (``rbpf.n_particles``, ``sir.n_particles``). Settings
        written before (recordings' run metadata) had a top-level ``particles`` as well, which
        replaced both: read as that."""
        if isinstance(data, dict) and "particles" in data:
            data = dict(data)
            n = data.pop("particles")
            if n is not None:
                for name in ("rbpf", "sir"):
                    sub = data.get(name, {})
                    sub = sub.model_dump() if isinstance(sub, BaseModel) else dict(sub)
                    data[name] = {**sub, "n_particles": n}
        return data


SYNTHETIC_BETA = {"a1": 5.69, "b1": 2.81, "a0": 0.25, "b0": 8.08}
"""Beta parameters fitted by ``polartrack calibrate synthetic:100 --frames 100 --per-frame 30``
(a scene seed kept out of every evaluation): visible Beta(5.69, 2.81), background
Beta(0.25, 8.08). Pang's Beta(5, 7) / Beta(1, 7) were fitted to their own detector and video."""


RECOVERY_PROPOSAL = {"candidates": 3, "jump_candidates": 2, "jump_probability": 0.01, "jump_std": 2.0}
"""RBPF settings beyond Pang for occlusion recovery (``polartrack study``'s ``rbpf+jumps`` row; all
off by default): a jump component in the motion model for visible targets (probability 0.01 a
step, 2 m per axis), explored by two of three candidates per particle (the filter carries N
particles and scores 3N hypotheses a frame in its one batched query). It lets the cloud leave a
secondary peak of the score surface (a car emerging from the smoke matches best half a car length
ahead), which the plain NCV cannot; the figures are in docs/results.md."""


CAR_LENGTH_M = 4.5
"""A typical car's length: converts the physical bounds below into target lengths."""
CAR_MAX_ACCEL_MPS2 = 0.8 * 9.81
"""The hardest manoeuvre a car makes (braking or cornering at about 0.8 g)."""
REAL_MOTION_NOISE_LENGTHS = round(2.0 * CAR_MAX_ACCEL_MPS2 / CAR_LENGTH_M, 1)
"""sqrt(q) for real footage, target lengths per s^1.5 (see ``motion_noise_lengths``): with the
white-noise-acceleration model the velocity changes by sqrt(q T) (1 sigma) over T seconds. Twice a
0.8 g manoeuvre's 1.7 lengths/s over T = 1 s gives sqrt(q) = 3.5 lengths/s^1.5: such a manoeuvre
is half a sigma, the rest is the image's own accelerations (a car crossing an oblique view's
perspective, the stabiliser's residual). The car's physics alone (sqrt(q) = 1.7) kept a passing
look-alike off uavdt-S1001's car on every seed but lost uav123-car16's accelerating car within 45
frames (docs/real-footage.md, stop 29). Real footage's world unit follows the target's length
(stabilised runs, see ``stabilised_world``), so the same figure holds for a 15 px and a 150 px car."""
REAL_ADAPTATION = TemplateAdaptation(enabled=True, min_score=0.5)
"""Template adaptation for real footage: 0.5 is the 99th percentile of Pang's background Beta(1, 7)
(1 - 0.5^7), a score the background rarely reaches; an update at most every 0.1 s blending in 10
percent (a time constant of about a second, the time a car takes to turn), the original keeping
half the weight."""
REAL_PARTICLES = 400
"""Particles for real footage (Pang: 200). The cloud must cover the prior's spread of a car that
may brake or turn hard (above) with the prior as proposal (``particles`` overrides it; the
measurement behind the figure is in docs/real-footage.md)."""
REAL_INIT_VEL_LENGTHS = round(10.0 / CAR_LENGTH_M, 1)
"""Initial velocity spread for real footage, target lengths per second: an urban speed of
10 m/s (2.2 lengths/s) at 1 sigma; the first box says where the target is, not how it moves."""

REAL_JUMP_STD_LENGTHS = 0.5
"""The RBPF's jump component for real footage (``jump_std_lengths``): half a target length per
axis. A small target's template is mostly its surroundings, and its score surface has a
secondary peak where the target *was* on the ground (uav123-truck4: the best match 7-14 px behind
an 11 px truck, docs/real-footage.md): a cloud on that peak can only leave it by a move of about
a target length, which the near-constant-velocity noise does not make in one step."""
REAL_LIKELIHOOD_TEMPER = 0.5
"""The exponent on the matcher's likelihood for real footage (``rbpf.temper``): each frame's scores
count as half an independent observation. The Beta ratio was fitted on the synthetic scene
hypothesis by hypothesis; in real footage the errors it does not model (the same ground, the same
look-alike, the same mismatch of a template to a turned car) persist from frame to frame, so the
product over frames counts one error again on every frame, and a look-alike that outscores a
half-hidden car for a few frames takes the whole cloud. A power likelihood is the standard
correction for a misspecified model (Bissiri, Holmes and Walker 2016); a half is the round figure
between the model as fitted and the third that over-spread the cloud on the dev set. The
moving-target cue is not tempered (tempered with the scores, it held real targets less well). The
gates on the match read the score within the MAP's bandwidth (``TrackState.score``), which a wider
cloud does not lower. Measured, with the leave-one-sequence-out choice, in docs/real-footage.md
(stop 55)."""
REAL_JUMP_RATE_PER_S = 0.3
"""... at 0.3 jumps a second for a visible target (``rbpf.jump_rate_per_s``; 0.01 a step at 30 fps,
the occlusion study's RECOVERY_PROPOSAL rate): a rare event, so a held track's cloud keeps
almost all its particles on the NCV."""


PRESETS: dict[ProfileName, dict] = {
    # The synthetic scene: Pang's model at the scene's frame rate, with this detector's own
    # likelihood (SYNTHETIC_BETA) instead of Pang's fit to his detector.
    "synthetic": {"rbpf": {"likelihood": {"kind": "beta_ratio", **SYNTHETIC_BETA}}},
    # Real footage: the same likelihood; the motion noise and the initial velocity spread in
    # target lengths (the world is then stabilised pixels, or target lengths; see
    # REAL_MOTION_NOISE_LENGTHS), with a jump component (REAL_JUMP_STD_LENGTHS), the likelihood
    # tempered (REAL_LIKELIHOOD_TEMPER); the per-frame
    # mechanisms (see the fields): template adaptation, matching at the target's scale (upsampling
    # a small target, tracking its size), turning the particles with the camera, re-acquisition,
    # the template re-registered on the target's segment;
    # stabilisation is on by default ("auto") for any source without a homography.
    "real": {
        "rbpf": {"likelihood": {"kind": "beta_ratio", **SYNTHETIC_BETA}, "temper": REAL_LIKELIHOOD_TEMPER,
                 "n_particles": REAL_PARTICLES, "jump_rate_per_s": REAL_JUMP_RATE_PER_S},
        "sir": {"n_particles": REAL_PARTICLES},
        "adaptation": REAL_ADAPTATION.model_dump(exclude_defaults=True),
        "scale": ScaleSettings().model_dump(),
        "compensate_camera_rotation": True,
        "motion_noise_lengths": REAL_MOTION_NOISE_LENGTHS,
        "init_vel_lengths": REAL_INIT_VEL_LENGTHS,
        "jump_std_lengths": REAL_JUMP_STD_LENGTHS,
        "reacquisition": {"enabled": True, "movers_in_doubt": True},
        "motion_cue": {"enabled": True},
        "segment": {"enabled": True},
    },
}
"""The named profiles: tracker settings (nested, as a run file's ``[settings]``) laid over Pang's
model converted to the source's frame rate (:func:`rate_adjusted_settings`). ``profile_for``
takes ``synthetic`` for the built-in scenes and ``real`` for everything else."""


def preset_for(source) -> str:
    """The profile a source gets: ``synthetic`` for the built-in scene, ``real`` for the rest."""
    return "synthetic" if getattr(source, "name", "").startswith("synthetic") else "real"


def profile_for(source, filter: FilterName = "rbpf", seed: int = 0, particles: int | None = None,
                preset: str | None = None) -> TrackerSettings:
    """The settings for ``source`` (its frame rate and kind): the named ``preset`` (default
    :func:`preset_for`) over Pang's model at the source's frame rate; ``particles`` replaces the
    preset's count."""
    name = preset or preset_for(source)
    if name not in PRESETS:
        raise ValueError(f"no profile {name!r}; one of {', '.join(PRESETS)}")
    st = with_overrides(rate_adjusted_settings(source.fps, filter=filter, seed=seed), PRESETS[name])
    if particles is not None:
        st = with_overrides(st, {"rbpf": {"n_particles": particles}, "sir": {"n_particles": particles}})
    return st


def rate_adjusted_settings(fps: float, filter: FilterName = "rbpf", q_motion: float = 4.0, particles: int | None = None,
                           **kw) -> TrackerSettings:
    """Pang's Table 1 model converted from its 3 fps sequence to a source at ``fps``.

    Table 1 gives per-step quantities at T = 1/3 s: orientation variance 16 deg^2 per step
    (48 deg^2 per second; raised to 150 deg^2/s for the sharper turns of the synthetic car, the
    per-frame variance scaling with the frame interval) and
    visibility switching probabilities 0.1 per step (here the per-frame probability with the
    same rate per second, 1 - 0.9^(3/fps)). ``particles`` sets both particle filters' count (None:
    Pang's 200 for the RBPF, Nelson's 300 for the SIR). The motion variance is refitted to the scene, as
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
    count = {} if particles is None else {"n_particles": particles}  # None: each filter's paper's
    rbpf = RBPFConfig(motion=motion, orientation=orientation, visibility=visibility, **count)
    sir = SIRConfig(motion=motion, orientation=orientation, **count)
    return TrackerSettings(filter=filter, rbpf=rbpf, sir=sir, **kw)


def with_overrides(settings: BaseModel, overrides: dict) -> BaseModel:
    """``settings`` with nested ``overrides`` (tables of its own field names, as a TOML file
    writes them) applied and validated; ValueError naming the first unknown or bad key."""
    from pydantic import ValidationError

    data = settings.model_dump()

    def merge(node: dict, over: dict, where: str) -> None:
        for key, value in over.items():
            path = f"{where}{key}"
            if key not in node:
                raise ValueError(f"no setting {path!r}")
            if isinstance(value, dict):
                if not isinstance(node[key], dict):
                    raise ValueError(f"{path!r} is not a group of settings")
                merge(node[key], value, path + ".")
            else:
                node[key] = value

    merge(data, overrides, "")
    try:
        return type(settings).model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        raise ValueError(f"{'.'.join(str(v) for v in err['loc'])}: {err['msg']}") from None


class RunSpec(BaseModel):
    """What one run tracks, and with which settings: the one place a deployment states it.

    ``deploy/run.toml`` is one (``polartrack config run --source ... --init ...`` writes it);
    compose's ingest and tracker both read it (``--run``), ingest publishing the resolved run
    config that the recorder keeps. The settings are the source's profile
    (:func:`profile_for`: the synthetic scene's calibration, or the real-footage one at the
    source's frame rate) with ``settings`` applied on top."""

    model_config = ConfigDict(frozen=True, extra="forbid", use_attribute_docstrings=True)

    source: str
    """video file, image folder, camera:N or synthetic[:SEED], as the services see it"""
    init_box: tuple[float, float, float, float]
    """the target's box x, y, w, h in the first frame"""
    fps: float | None = Field(None, gt=0)
    """the source's frame rate (the profile converts the motion model to it); unset: read from the
    source when a service starts"""
    frames: int | None = Field(None, ge=1)
    """only the first N frames"""
    pace: Literal["consumer", "realtime", "max"] = "consumer"
    """consumer: each frame waits for the tracker (nothing dropped); realtime: at the source's frame
    rate, stale frames skipped; max: as fast as the source reads"""
    image_format: str = "auto"
    """frames on the bus and in the recording: auto (a JPEG/PNG file's own bytes; raw for the synthetic
    scenes; jpeg:90 for video and cameras), raw, png, jpeg or jpeg:QUALITY; run and track with the same
    format give the same estimates"""
    filter: FilterName = "rbpf"
    """rbpf (Pang), sir (Nelson) or ml (windowed search)"""
    seed: int = Field(0, ge=0)
    """seed of the filter's random generator"""
    particles: int | None = Field(None, ge=1)
    """particles of the particle filters (rbpf, sir); unset: the profile's"""
    profile: ProfileName | None = None
    """the settings profile (common.settings.PRESETS); unset: synthetic for the built-in scenes, real
    for the rest"""
    settings: dict = Field(default_factory=dict)
    """tracker settings (common.settings.TrackerSettings, nested tables) that replace the profile's"""

    def tracker_settings(self) -> TrackerSettings:
        """The run's settings: the profile for the source, then ``settings``; ValueError (one
        line) when an override is not a setting or not valid, or the source cannot be read."""
        from types import SimpleNamespace

        if self.fps is not None:
            synthetic = self.source == "synthetic" or self.source.startswith("synthetic:")
            source = SimpleNamespace(name="synthetic" if synthetic else self.source, fps=self.fps)
        else:
            from common.sources import SourceError, open_source

            try:
                source = open_source(self.source, n_frames=self.frames)
            except SourceError as exc:
                raise ValueError(str(exc)) from None
        st = profile_for(source, filter=self.filter, seed=self.seed, particles=self.particles, preset=self.profile)
        return with_overrides(st, self.settings) if self.settings else st
