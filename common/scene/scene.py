"""``SyntheticScene``: a deterministic, seeded UAV video of a red car with ground truth.

Everything random comes from ``numpy.random.default_rng`` seeded with the scene's seed: scene
content from ``default_rng([seed, 2, k])`` (one stream per component k), the sensor noise of frame
``i`` from ``default_rng([seed, 1, i])``. So ``scene.frame(i)`` is bit-identical whether frames are
read in order or at random, in any process.

Events (``scene.events``; frame ranges ``(start, end)``, end exclusive, for the target):

- ``"smoke"``: the target is completely hidden (``visible_fraction == 0``); round(smoke_duration_s * fps) frames.
- ``"smoke_any"``: the smoke hides more than 0.5% of the target (contains ``"smoke"``).
- ``"wall"``: the building edge hides more than 0.5% of the target.
- ``"decoy_pass"``: the decoy's centre is within decoy distance + one car length of the target's.

An event whose occluder or decoy is switched off in the config is absent.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from .camera import camera_trajectory, project
from .car import body_corners, footprint_samples
from .config import SceneConfig
from .occluders import Smoke, Wall, make_smoke, make_wall
from .paths import Paths, VehiclePath, build_paths
from .render import Renderer
from .world import WorldTexture, build_world

_NOISE_TAG = 1
_CONTENT_TAG = 2
_STREAMS = ("paths", "smoke", "wall", "camera", "world")
_EVENT_THRESHOLD = 0.005
_SPEC = re.compile(r"synthetic(?::(\d+))?")


@dataclass(frozen=True)
class Truth:
    """Ground truth of one car in one frame."""

    image_xy: tuple[float, float]  # pixel centre of the car (x right, y down)
    world_xy: tuple[float, float]  # metres (x east, y north)
    heading_world_deg: float  # direction of travel on the ground, anticlockwise from east, (-180, 180]
    angle_image_deg: float  # long axis (forward) in the image, anticlockwise as displayed, (-180, 180]
    visible_fraction: float  # 0..1, share of the car's area not hidden by smoke or the wall
    box: tuple[float, float, float, float]  # (x, y, w, h) axis-aligned box of the car body in the image


@dataclass(frozen=True)
class SceneFrame:
    """One rendered frame with its camera and ground truth."""

    index: int
    time: float  # capture time, index / fps, seconds
    image: np.ndarray  # (H, W, 3) uint8 RGB
    homography: np.ndarray  # (3, 3) float64, ground (metres) -> image pixels
    truth: Truth  # the target
    decoy: Truth | None  # the decoy, None when it is off or out of view


def _wrap_deg(a: np.ndarray) -> np.ndarray:
    """Angles to (-180, 180]."""
    a = np.mod(np.asarray(a, float) + 180.0, 360.0) - 180.0
    return np.where(a <= -180.0, a + 360.0, a)


def _project_frames(hs: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Points (n, k, 2) on the ground of frame i through hs[i] -> (n, k, 2) pixels."""
    q = np.einsum("nij,nkj->nki", hs[:, :, :2], pts) + hs[:, None, :, 2]
    return q[..., :2] / q[..., 2:3]


def _run(mask: np.ndarray, containing: int | None = None) -> tuple[int, int] | None:
    """(start, end) of the longest run of True in ``mask`` (or of the run containing ``containing``)."""
    idx = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    runs = list(zip(idx[::2].tolist(), idx[1::2].tolist()))
    if not runs:
        return None
    if containing is not None:
        for a, b in runs:
            if a <= containing < b:
                return (a, b)
        return None
    return max(runs, key=lambda r: r[1] - r[0])


class _CarTrack:
    """Per-frame truth arrays of one car."""

    def __init__(self, cfg: SceneConfig, path: VehiclePath, hs: np.ndarray,
                 smoke: Smoke | None, wall: Wall | None):
        self.path = path
        fwd, left = path.forward, path.left
        half = 0.5 * cfg.car_length_m * fwd
        pts = np.stack([path.xy, path.xy + half, path.xy - half], axis=1)  # centre, front, back
        q = _project_frames(hs, pts)
        self.image_xy = q[:, 0]
        d = q[:, 1] - q[:, 2]
        self.angle_image = _wrap_deg(np.rad2deg(np.arctan2(-d[:, 1], d[:, 0])))
        self.heading_world = _wrap_deg(np.rad2deg(path.heading))
        corners = body_corners(cfg.car_length_m, cfg.car_width_m)
        cw = path.xy[:, None, :] + corners[None, :, :1] * fwd[:, None] + corners[None, :, 1:] * left[:, None]
        ci = _project_frames(hs, cw)
        lo, hi = ci.min(axis=1), ci.max(axis=1)
        self.box = np.concatenate([lo, hi - lo], axis=1)
        self.in_view = (lo[:, 0] < cfg.width) & (lo[:, 1] < cfg.height) & (hi[:, 0] > 0) & (hi[:, 1] > 0)
        s = footprint_samples(cfg.car_length_m, cfg.car_width_m)
        self.samples = path.xy[:, None, :] + s[None, :, :1] * fwd[:, None] + s[None, :, 1:] * left[:, None]
        self.set_occluders(smoke, wall)

    def set_occluders(self, smoke: Smoke | None, wall: Wall | None) -> None:
        a_s = smoke.alpha(self.samples) if smoke is not None else np.zeros(self.samples.shape[:2])
        a_w = wall.alpha(self.samples) if wall is not None else np.zeros(self.samples.shape[:2])
        self.smoke_hidden = a_s.mean(axis=1)
        self.wall_hidden = a_w.mean(axis=1)
        self.visible = ((1.0 - a_s) * (1.0 - a_w)).mean(axis=1)

    def truth(self, i: int) -> Truth:
        return Truth(
            image_xy=(float(self.image_xy[i, 0]), float(self.image_xy[i, 1])),
            world_xy=(float(self.path.xy[i, 0]), float(self.path.xy[i, 1])),
            heading_world_deg=float(self.heading_world[i]),
            angle_image_deg=float(self.angle_image[i]),
            visible_fraction=float(np.clip(self.visible[i], 0.0, 1.0)),
            box=tuple(float(v) for v in self.box[i]),
        )


class SyntheticScene:
    """A seeded synthetic UAV video of an urban ground plane with a red target car.

    >>> scene = SyntheticScene(SceneConfig(), seed=0)
    >>> f = scene.frame(42); f.image.shape, f.truth.image_xy, scene.events["smoke"]
    """

    def __init__(self, config: SceneConfig | None = None, seed: int = 0):
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
        cfg = config if config is not None else SceneConfig()
        if not isinstance(cfg, SceneConfig):
            raise TypeError(f"config must be a SceneConfig, got {type(cfg).__name__}")
        self.config = cfg
        self.seed = int(seed)
        rng = {name: np.random.default_rng([self.seed, _CONTENT_TAG, k]) for k, name in enumerate(_STREAMS)}

        self.paths: Paths = build_paths(cfg, rng["paths"])
        target = self.paths.target
        poses, hs = camera_trajectory(cfg, target.xy, rng["camera"])
        self.camera_poses = poses
        self._h = hs
        self._h.setflags(write=False)

        self._target = _CarTrack(cfg, target, hs, None, None)
        self.smoke: Smoke | None = make_smoke(cfg, target, self._target.samples, rng["smoke"])
        self.wall: Wall | None
        self._decoy: _CarTrack | None
        self.wall, self._decoy, self.decoy_side = self._choose_layout(hs)
        self._target.set_occluders(self.smoke, self.wall)

        self.world: WorldTexture = build_world(
            cfg, rng["world"], self._world_region(), self._texture_ppm(), target,
            self._decoy.path if self._decoy is not None else None,
            target_road_offset=self.decoy_side * min(cfg.decoy_distance_m / 2, 4.0),
            blocked=(self.wall.polygon(),) if self.wall is not None else (),
        )
        self._renderer = Renderer(cfg, self.world, self.wall, self.smoke)
        self.decoy_closest_frame: int | None = None  # set with the decoy: frame of closest approach
        self.decoy_min_distance_m: float | None = None  # and the distance then, metres
        self._events = self._find_events()

    # ---- construction helpers --------------------------------------------------------------
    def _choose_layout(self, hs: np.ndarray) -> tuple[Wall | None, _CarTrack | None, int]:
        """Pick the wall's side and the decoy's path among the seed's candidates.

        The pick hides the decoy least (by smoke or wall, while it is in view), keeps it in view
        most, never brings it closer to the target than configured, and lets the wall hide the
        target only during its own event. Ties go to the seed's preference order.
        """
        cfg = self.config
        pref = self.paths.wall_side
        tr = self._target
        best, best_score = (None, None, pref), np.inf
        for wall_side in (pref, -pref):
            rng = np.random.default_rng([self.seed, _CONTENT_TAG, _STREAMS.index("wall")])
            wall = make_wall(cfg, self.paths.target, wall_side, rng)
            off = 0.0
            if wall is not None:
                hidden = wall.alpha(tr.samples).mean(axis=1)
                main = _run(hidden > _EVENT_THRESHOLD)
                if main is not None:
                    hidden[main[0]: main[1]] = 0.0
                off = 10.0 * float(hidden.sum())
            for side, dpath in self.paths.decoy_candidates or ((pref, None),):
                score, track = off, None
                if dpath is not None:
                    track = _CarTrack(cfg, dpath, hs, self.smoke, wall)
                    seen = track.in_view
                    score += float((1.0 - track.visible)[seen].sum()) + 0.05 * float((~seen).sum())
                    dist = np.hypot(*(dpath.xy - tr.path.xy).T)
                    if np.any(dist < cfg.decoy_distance_m - 1e-6):
                        score += 1e6
                if score < best_score - 1e-9:
                    best, best_score = (wall, track, side), score
            if wall is None:
                break
        return best

    def _texture_ppm(self) -> float:
        cfg = self.config
        return 1.3 * cfg.pixels_per_metre * (1.0 + max(cfg.camera_zoom_change, 0.0))

    def _world_region(self) -> tuple[float, float, float, float]:
        cfg = self.config
        w, h = cfg.width, cfg.height
        border = np.array([[0, 0], [w / 2, 0], [w, 0], [w, h / 2], [w, h], [w / 2, h], [0, h], [0, h / 2]], float)
        border += np.array([[-0.5, -0.5]])
        pts = np.concatenate([project(np.linalg.inv(hh), border) for hh in self._h])
        margin = 8.0
        lo, hi = pts.min(axis=0) - margin, pts.max(axis=0) + margin
        return (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))

    def _find_events(self) -> dict[str, tuple[int, int]]:
        cfg = self.config
        tr = self._target
        ev: dict[str, tuple[int, int]] = {}
        if self.smoke is not None:
            ev["smoke"] = _run(tr.visible <= 0.0)
            ev["smoke_any"] = _run(tr.smoke_hidden > _EVENT_THRESHOLD, containing=ev["smoke"][0])
        if self.wall is not None:
            w = _run(tr.wall_hidden > _EVENT_THRESHOLD)
            if w is not None:
                ev["wall"] = w
        if self._decoy is not None:
            dist = self.decoy_distances()
            k = int(np.argmin(dist))
            self.decoy_closest_frame = k
            self.decoy_min_distance_m = float(dist[k])
            ev["decoy_pass"] = _run(dist <= cfg.decoy_distance_m + cfg.car_length_m, containing=k)
        return {k: (int(a), int(b)) for k, (a, b) in ev.items()}

    # ---- public API --------------------------------------------------------------------------
    @classmethod
    def from_spec(cls, spec: str, config: SceneConfig | None = None) -> SyntheticScene:
        """Build from a source string ``synthetic`` (seed 0) or ``synthetic:SEED``."""
        if not isinstance(spec, str):
            raise ValueError(f"scene spec must be a string like 'synthetic' or 'synthetic:7', got {spec!r}")
        m = _SPEC.fullmatch(spec.strip())
        if m is None:
            raise ValueError(
                f"bad scene spec {spec!r}: expected 'synthetic' or 'synthetic:SEED' with SEED a "
                f"non-negative integer, e.g. 'synthetic:7'"
            )
        return cls(config, seed=int(m.group(1)) if m.group(1) is not None else 0)

    def __len__(self) -> int:
        return self.config.n_frames

    @property
    def fps(self) -> float:
        return float(self.config.fps)

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return (self.config.width, self.config.height)

    @property
    def events(self) -> dict[str, tuple[int, int]]:
        """Named frame ranges (start, end exclusive); see the module docstring."""
        return dict(self._events)

    @property
    def homographies(self) -> np.ndarray:
        """(n_frames, 3, 3) ground -> image homographies (read-only)."""
        return self._h

    def total_rotation_deg(self) -> float:
        """Sum over frames of the absolute change of the target's image angle, in degrees."""
        return float(np.abs(_wrap_deg(np.diff(self._target.angle_image))).sum())

    def decoy_distances(self) -> np.ndarray:
        """(n_frames,) centre-to-centre ground distance decoy - target, metres (inf without decoy)."""
        if self._decoy is None:
            return np.full(len(self), np.inf)
        return np.hypot(*(self._decoy.path.xy - self._target.path.xy).T)

    def _check(self, i: int) -> int:
        if isinstance(i, bool) or not isinstance(i, (int, np.integer)):
            raise TypeError(f"frame index must be an integer, got {i!r}")
        if not 0 <= i < len(self):
            raise IndexError(f"frame {i} out of range 0..{len(self) - 1}")
        return int(i)

    def truth(self, i: int) -> Truth:
        """The target's truth at frame ``i`` (no rendering)."""
        return self._target.truth(self._check(i))

    def decoy_truth(self, i: int) -> Truth | None:
        """The decoy's truth at frame ``i``, None when it is off or out of view (no rendering)."""
        i = self._check(i)
        if self._decoy is None or not self._decoy.in_view[i]:
            return None
        return self._decoy.truth(i)

    def render(
        self, i: int, *, draw_target: bool = True, draw_decoy: bool = True,
        draw_occluders: bool = True, add_noise: bool = True,
    ) -> np.ndarray:
        """The image of frame ``i`` with parts optionally left out (for tests and diagnostics).

        With all options on this is exactly ``frame(i).image``.
        """
        i = self._check(i)
        tr = self._target.path
        target = (tr.xy[i], float(tr.heading[i])) if draw_target else None
        decoy = None
        if draw_decoy and self._decoy is not None and self._decoy.in_view[i]:
            decoy = (self._decoy.path.xy[i], float(self._decoy.path.heading[i]))
        noise_rng = np.random.default_rng([self.seed, _NOISE_TAG, i]) if add_noise else None
        return self._renderer.render(self._h[i], target, decoy, draw_occluders, noise_rng)

    def frame(self, i: int) -> SceneFrame:
        """Frame ``i`` (0 <= i < len(scene)), rendered on demand; deterministic."""
        i = self._check(i)
        return SceneFrame(
            index=i,
            time=i / self.fps,
            image=self.render(i),
            homography=self._h[i].copy(),
            truth=self._target.truth(i),
            decoy=self.decoy_truth(i),
        )

    def __getitem__(self, i: int) -> SceneFrame:
        return self.frame(i)

    def __iter__(self):
        for i in range(len(self)):
            yield self.frame(i)

    def __repr__(self) -> str:
        c = self.config
        return f"SyntheticScene(seed={self.seed}, {c.width}x{c.height}, {c.n_frames} frames at {c.fps:g} fps)"
