"""Every parameter of the multi-target articulated trackers, declared once with its meaning.

Units: pixels and seconds; sizes of body parts and structure tolerances in units of the
target's height H (so the same settings work for people of any size). Defaults follow Bhaskar
and Mihaylova (2011) where the paper gives a value (validation gate 15, residual resampling,
constant-velocity motion); the rest were set on the synthetic people scene and are marked so.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

UnitInterval = Annotated[float, Field(ge=0, le=1)]
"""A probability, share or factor: a number from 0 to 1."""


class _Frozen(BaseModel):
    """Settings that do not change once made and take no unknown keys; each field is documented by
    the docstring under it."""

    model_config = ConfigDict(frozen=True, extra="forbid", use_attribute_docstrings=True)


class HistogramConfig(_Frozen):
    """Colour-histogram binning (:mod:`.appearance`)."""

    hue_bins: int = Field(12, ge=1, le=180)
    """Hue bins for coloured pixels."""
    sat_bins: int = Field(3, ge=1, le=32)
    """Saturation bins for coloured pixels."""
    value_bins: int = Field(4, ge=1, le=32)
    """Brightness bins for grey pixels (low saturation or dark)."""
    min_saturation: int = Field(50, ge=0, le=255)
    """Pixels below this saturation (0-255) count as grey."""
    min_value: int = Field(40, ge=0, le=255)
    """Pixels below this value (0-255) count as grey (too dark for a hue)."""

    @property
    def n_bins(self) -> int:
        return self.hue_bins * self.sat_bins + self.value_bins


class MotionConfig(_Frozen):
    """Constant velocity applied jointly with the pictorial structure (paper section 4; :mod:`.motion`)."""

    body_accel: float = Field(15.0, ge=0)
    """Std of the acceleration shared by all parts of a body (white-noise acceleration), px/s per
    sqrt(s): the whole person speeds up, slows or turns. Set on the synthetic scene (seeds 100-119,
    three runs each): 40 learned the walking speed quicker but lost people in 10 of 60 runs (EPMCMC;
    JPDA-PF 15), against 6 (JPDA-PF 5) at 15; init_speed_spread gives the speed instead."""
    part_jitter: float = Field(8.0, ge=0)
    """Std of each limb part's own position noise, px per sqrt(s) (limbs swing about the body); the root
    (torso) and head get half of it."""
    structure_rate: float = Field(2.0, ge=0)
    """Rate (1/s) at which a part's offset from its parent relaxes to the preferred offset of the
    pictorial structure: per frame the gap shrinks by 1 - exp(-rate dt)."""
    velocity_coupling: UnitInterval = 0.5
    """Per frame, a part's velocity relative to its parent's is multiplied by this (0: parts move
    exactly with their parent; 1: independent constant velocity)."""


class LikelihoodConfig(_Frozen):
    """Log-likelihood of one target's configuration: a weighted sum (paper section 3.1) of the parts'
    fit to the image, the data-association term and the pairwise structure term (:mod:`.likelihood`)."""

    colour_lambda: float = Field(20.0, gt=0)
    """Part appearance: log p = -colour_lambda * (1 - rho), rho the Bhattacharyya coefficient of the
    part's box against its reference histogram (Perez et al. 2002)."""
    colour_floor: UnitInterval = 0.5
    """Robust appearance: rho below this counts as this (log p = -lambda (1 - max(rho, floor))), so a
    hidden part gives a flat likelihood instead of pulling the particles to the least-bad pixels; the
    association term and the motion carry the part through the occlusion."""
    hidden_similarity: UnitInterval | None = 0.75
    """Occlusion-aware appearance: the share of a part's box covered by targets in front of its target
    (their rest-pose boxes at the predicted torsos, :mod:`.occlusion`) counts as this similarity instead
    of its pixels' (which are the occluder's), so a person passing behind another is not pulled onto its
    own visible edge or a look-alike; a value near 1 would reward hiding. None: the pixels count (how
    0.75 was set: docs/results.md)."""
    visible_pixels_only: bool = False
    """With hidden_similarity: a partly covered part's rho is taken on the largest strip of its box that
    no target in front covers (:func:`.occlusion.visible_strip`), not on the whole box with the
    occluder's pixels in it, which makes a half-hidden part on its own spot score below one hidden whole
    behind the occluder. Off by default: it did not pay on fresh seeds (docs/results.md)."""
    w_appearance: float = Field(0.3, ge=0)
    """Weight of the parts' appearance terms (set on the synthetic scene: 0.3 gave a lower RMSE than 1.0
    for every method)."""
    w_association: float = Field(1.0, ge=0)
    """Weight of the parts' data-association (expected-likelihood) terms."""
    w_structure: float = Field(1.0, ge=0)
    """Weight of the pairwise pictorial-structure terms."""
    structure_sigma: float = Field(0.06, gt=0)
    """Pairwise term: log psi = -|offset - preferred offset|^2 / (2 (sigma H)^2), per edge, sigma in
    units of H (set on the synthetic scene)."""


class GateConfig(_Frozen):
    """Validation gates and the measurements inside them (:mod:`.gating`)."""

    gate_size: float = Field(15.0, gt=0)
    """Gate radius in pixels (paper section 4.1: 15). Fixed gates (PDA, JPDA) use it throughout; the
    re-estimated gate (ELPDA) starts with R_0 = gate_size^2 / gamma I, keeps the std of R_k at most
    gate_size / sqrt(gamma), and searches up to twice gate_size (the particle spread adds to R_k)."""
    level: Literal["structure", "part"] = "structure"
    """Association unit: 'structure' gates and associates the whole pictorial structure, located by its
    root (paper section 3.2); 'part' gates and associates every part on its own."""
    core_deviation: float | None = Field(0.06, ge=0)
    """Structure-level gates: a measurement is where the target's *core* matches -- the parts whose
    offset from their parent may deviate at most this from the preferred one (units of H): the torso and
    head. The limbs swing by more than their boxes' width, so a match that shifts the predicted limbs
    with the torso is pulled off by them. None: all parts."""
    adaptive: bool = False
    """Re-estimate the gate from the data every frame: S = particle covariance + R_k with R_k from the
    weighted innovations (ELPDA); False: a fixed circle of radius gate_size."""
    p_gate: float = Field(0.95, gt=0, lt=1)
    """P_G, probability that the true measurement falls in the gate (sets gamma)."""
    innovation_rate: float = Field(0.3, gt=0, le=1)
    """Adaptive gate: R_k = (1 - rate) R_{k-1} + rate (sum_j beta_j nu_j nu_j^T + beta_0 R_max - P)
    (weighted innovations less the prediction's spread P, covariance matching); the gate can then grow
    up to twice gate_size."""
    min_sigma: float = Field(2.0, gt=0)
    """Adaptive gate: floor on the std of R_k, px."""
    r_in_likelihood: bool = True
    """Adaptive gate: the expected likelihood (eq. 13) uses the re-estimated R_k as the measurement
    covariance (the paper's N(z_k, z_j, R_k)); False: the fixed measurement_sigma^2 I."""
    stride: int = Field(2, ge=1, le=16)
    """Spacing of the candidate grid searched for measurements, px."""
    max_measurements: int = Field(6, ge=1, le=16)
    """At most this many measurements (the best peaks) per gate."""
    min_similarity: UnitInterval = 0.1
    """A measurement is a local maximum of the mean colour similarity of the shifted structure with rho
    >= this."""


class AssociationConfig(_Frozen):
    """PDA / ELPDA / JPDA association (paper eqs. 9-13; :mod:`.association`)."""

    p_detect: float = Field(0.9, gt=0, le=1)
    """P_D, probability that the part is detected."""
    clutter_density: float = Field(2e-3, gt=0)
    """Poisson clutter density lambda, measurements per pixel^2: mu_F(m) = Poisson(m; lambda V)."""
    occlusion_floor: UnitInterval | None = 0.05
    """Occlusion-aware detection: P_D of a target is p_detect times the share of its predicted bounding
    box not covered by nearer targets (feet lower in the image), at least this share
    (:mod:`.occlusion`); None: the constant p_detect."""
    measurement_sigma: float = Field(3.0, gt=0)
    """Std of a measurement about the part centre, px (R = sigma^2 I) of the fixed-gate methods (PDA,
    JPDA); ELPDA's eq. 13 uses the re-estimated R_k (GateConfig.r_in_likelihood)."""
    attribute_lambda: float = Field(12.0, gt=0)
    """ELPDA only: the measurement's colour similarity rho is an attribute with density lambda e^{lambda
    (rho - 1)} / (1 - e^{-lambda}) for the target and uniform for clutter; their ratio multiplies the
    target hypotheses (the 'local attribute information' of Marrs et al. 2002)."""


class EvolutionConfig(_Frozen):
    """Genetic moves and population MCMC (paper section 3.1, Algorithms 1-2; :mod:`.genetic`)."""

    ess_threshold_fraction: UnitInterval = 0.5
    """Resample-move when ESS <= fraction * N (Algorithm 1, N_thr1)."""
    mcmc_iterations: int = Field(2, ge=0, le=50)
    """t, population-MCMC sweeps after each resampling (Algorithm 1 (3a))."""
    crossover_prob: UnitInterval = 0.3
    """rho_c, probability that a particle pair crosses over (per sweep, and in the sampling step)."""
    mutation_prob_position: UnitInterval = 0.3
    """rho_m of each part-position component (x and y of every part)."""
    mutation_prob_velocity: UnitInterval = 0.0
    """rho_m of each velocity component; 0: velocities are never mutated (the paper's 'components that
    need no stochastic fluctuations')."""
    mutation_sigma: float = Field(0.03, gt=0)
    """Std of a mutation of a part offset, units of H."""
    exchange_prob: UnitInterval = 0.5
    """Algorithm 2 (3b): probability that a sweep proposes exchanges between two populations (targets)
    rather than crossovers within each."""
    prior_floor: float = Field(2.0, gt=0)
    """Floor on the std of the Gaussian fit to the predicted population (MCMC target), px or px/s."""
    couple_velocity: bool = True
    """The MCMC target's Gaussian keeps each part's position-velocity correlation (per axis), and a
    mutation moves the velocity with the position by the population's regression of one on the other;
    False: a diagonal Gaussian, and mutations leave velocities alone."""


class DepthConfig(_Frozen):
    """Who stands in front of whom where targets overlap: feet and pixels (:mod:`.depth`). Set on seeds
    100-119 (true torsos plus 1 px noise): the order was right in 98.5 % of the overlapping frames, against
    95.2 % by the feet alone."""

    evidence_gain: float = Field(20.0, ge=0)
    """Log-odds added per frame for a difference of 1 in the two cores' colour similarity inside the
    overlap (times the square root of the smaller core share there); 0: the feet alone decide."""
    feet_scale: float = Field(2.0, gt=0)
    """Feet this many px lower count as log-odds 1 of standing in front."""
    forget: UnitInterval = 0.98
    """The pixels' accumulated log-odds are multiplied by this every frame (0.98: about two seconds'
    memory at 25 fps), so that people who change lanes are reordered by their feet."""
    cap: float = Field(20.0, gt=0)
    """Bound on the pixels' accumulated log-odds."""
    core_deviation: float = Field(0.06, ge=0)
    """The parts compared inside the overlap: those whose offset may deviate at most this (units of H)
    from the rest pose (torso and head); the limbs swing off their rest-pose boxes."""


class PlacementConfig(_Frozen):
    """Placing a body in a person box: the shift search (:mod:`.placement`); set on the tuning seeds
    100-119 (docs/results.md)."""

    search_x: float = Field(0.08, ge=0, le=0.5)
    """Largest sideways shift searched, units of H (0 with search_y 0: no search)."""
    search_y: float = Field(0.04, ge=0, le=0.5)
    """Largest shift up or down searched, units of H."""
    ring: float = Field(0.25, gt=0, le=2)
    """Width of the ring around the box whose colours are the surroundings, units of H."""
    core_deviation: float = Field(0.06, ge=0)
    """The parts scored: those whose offset may deviate at most this from the rest pose (units of H):
    the torso and head; the limbs of a walking person are not where the rest pose puts them."""


class MultiTargetConfig(_Frozen):
    """One tracker: filter, association and all component settings."""

    filter: Literal["epmcmc", "sir"] = "epmcmc"
    """epmcmc: evolving-population MCMC filter; sir: generic particle filter (the JPDA-PF baseline)."""
    association: Literal["elpda", "pda", "jpda"] = "elpda"
    """Data association of the gated measurements (see :mod:`.association`)."""
    n_parts: Literal[1, 2, 6, 10] = 10
    """Pictorial-structure model (paper Fig. 8 levels)."""
    n_particles: int = Field(500, ge=2, le=100_000)
    """Particles per target (paper section 4.1: 500; with fewer, one run's Monte Carlo spread outgrows
    the differences between the methods: docs/results.md)."""
    init_spread: float = Field(2.0, ge=0)
    """Std of the initial particles about the initial part positions, px."""
    init_speed_spread: float = Field(40.0, ge=0)
    """Std of the initial particles' body velocity, px/s (one draw per particle, shared by all its
    parts): the first frame gives positions only, so the filter must learn how fast and which way each
    person walks (0: every particle starts at rest)."""
    reference_min_visible: UnitInterval | None = 0.25
    """Reference histograms are taken from the first frame's pixels of each part's box that the targets
    in front do not cover (:mod:`.references`); a part with less than this share in view keeps its whole
    box. None: whole boxes (a person who starts behind another takes the occluder's colours)."""
    resampling: Literal["systematic", "stratified", "multinomial", "residual"] = "residual"
    """Resampling scheme (paper Algorithm 1 (a1): residual)."""
    histogram: HistogramConfig = Field(default_factory=HistogramConfig)
    motion: MotionConfig = Field(default_factory=MotionConfig)
    likelihood: LikelihoodConfig = Field(default_factory=LikelihoodConfig)
    gate: GateConfig = Field(default_factory=GateConfig)
    association_model: AssociationConfig = Field(default_factory=AssociationConfig)
    evolution: EvolutionConfig = Field(default_factory=EvolutionConfig)
    depth: DepthConfig = Field(default_factory=DepthConfig)
    placement: PlacementConfig = Field(default_factory=PlacementConfig)


METHODS = ("epmcmc-elpda", "epmcmc-pda", "jpda-pf")
"""The paper's proposed method and its two baselines (Table 1)."""


def method_config(method: str, **updates) -> MultiTargetConfig:
    """The config of ``method`` (one of :data:`METHODS`), with top-level field ``updates``.

    epmcmc-elpda: EPMCMC + ELPDA: association probabilities with the measurements' colour attributes,
    particle weights by the expected likelihood (eq. 13), gate re-estimated every frame; epmcmc-pda:
    the same filter with plain PDA: kinematic association probabilities, the PDAF's combined
    measurement, a fixed gate; jpda-pf: a generic particle filter (systematic resampling, no genetic
    moves) with joint PDA in fixed gates (Jaward et al. 2006).
    """
    presets = {
        "epmcmc-elpda": dict(filter="epmcmc", association="elpda", adaptive=True),
        "epmcmc-pda": dict(filter="epmcmc", association="pda", adaptive=False),
        "jpda-pf": dict(filter="sir", association="jpda", adaptive=False, resampling="systematic"),
    }
    if method not in presets:
        raise ValueError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
    p = dict(presets[method])
    adaptive = p.pop("adaptive")
    base = MultiTargetConfig(**p)
    gate = base.gate.model_copy(update={"adaptive": adaptive})
    if "gate" in updates:
        gate = updates.pop("gate").model_copy(update={"adaptive": adaptive})
    return base.model_copy(update={"gate": gate, **updates})
