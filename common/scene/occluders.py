"""Things above the cars: the smoke cloud (full blackout) and the building edge (partial cover).

Each occluder is defined on the ground plane by an exact ``alpha(points)`` (1 = hides completely),
which the ground truth uses, and carries a premultiplied RGBA texture of itself on the ground
(``WorldLayer``), which the renderer warps into the image and composites over the cars.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from .config import SceneConfig
from .noise import fractal_noise
from .paths import SCHEDULE, VehiclePath, frame_at
from .pixel_loops import alpha_over


@dataclass(frozen=True)
class WorldLayer:
    """An RGBA picture lying on the ground plane.

    ``rgba``: (h, w, 4) uint8, colour premultiplied by alpha. ``tex_to_world``: 3x3 map from texel
    coordinates (column, row; texel centres at integers) to world metres.
    """

    rgba: np.ndarray
    tex_to_world: np.ndarray


_EMPTY = WorldLayer(np.zeros((1, 1, 4), np.uint8), np.eye(3))  # placeholder while a layer is drawn
_RIM_MAX = 1.6  # the rim's width varies with angle between 0.35 and 1.6 x smoke_edge_m


def _smoothstep(q: np.ndarray) -> np.ndarray:
    q = np.clip(q, 0.0, 1.0)
    return q * q * (3.0 - 2.0 * q)


@dataclass(frozen=True)
class Smoke:
    """A thick, static smoke cloud: opaque within ``r_core`` of ``centre``, a soft irregular rim outside."""

    centre: np.ndarray  # (2,) metres
    r_core: float
    edge_m: float
    harmonics: np.ndarray  # (k, 3): order, amplitude, phase of the rim's angular modulation
    layer: WorldLayer

    def rim_width(self, phi: np.ndarray) -> np.ndarray:
        mod = np.ones_like(phi)
        for order, amp, phase in self.harmonics:
            mod = mod + amp * np.sin(order * phi + phase)
        return self.edge_m * np.clip(mod, 0.35, _RIM_MAX)

    def alpha(self, pts: np.ndarray, grow: float = 0.0) -> np.ndarray:
        """Opacity at ground points (..., 2); ``grow`` widens the opaque core (used for drawing)."""
        d = np.asarray(pts, float) - self.centre
        r = np.hypot(d[..., 0], d[..., 1])
        out = (r <= self.r_core + grow).astype(float)
        rim = (r > self.r_core + grow) & (r < self.radius + grow)
        if np.any(rim):
            dr = d[rim]
            q = (r[rim] - self.r_core - grow) / self.rim_width(np.arctan2(dr[:, 1], dr[:, 0]))
            out[rim] = 1.0 - _smoothstep(q)
        return out

    @property
    def radius(self) -> float:
        """Radius beyond which the cloud is fully transparent."""
        return self.r_core + _RIM_MAX * self.edge_m


def make_smoke(
    cfg: SceneConfig, path: VehiclePath, samples_world: np.ndarray, rng: np.random.Generator
) -> Smoke | None:
    """Place the cloud on the target's path so that exactly round(smoke_duration_s * fps) frames
    have every footprint sample inside the opaque core (visible_fraction == 0).

    ``samples_world``: (n_frames, n_samples, 2) the target's footprint samples in the world.
    """
    k = int(round(cfg.smoke_duration_s * cfg.fps))
    n_h = int(rng.integers(3, 8))  # always draw, so the stream does not depend on the config
    harmonics = np.column_stack([
        rng.choice(np.arange(2, 10), size=n_h, replace=False).astype(float),
        rng.uniform(0.1, 0.35, size=n_h),
        rng.uniform(0, 2 * np.pi, size=n_h),
    ])
    tex_rng = np.random.default_rng(rng.integers(0, 2**63))
    if k <= 0:
        return None
    i0 = frame_at(SCHEDULE.smoke_centre, cfg)
    # frames before and after the centre pair up at equal distances: for an even count, centre the
    # cloud between two frames
    centre = path.xy[i0].copy() if k % 2 else 0.5 * (path.xy[i0] + path.xy[i0 + 1])
    far = np.max(np.hypot(*(samples_world - centre).transpose(2, 0, 1)), axis=1)  # (n_frames,)
    order = np.sort(far)
    if k >= len(order):
        raise ValueError("smoke_duration_s covers the whole run")
    r_core = 0.5 * (order[k - 1] + order[k])
    smoke = Smoke(centre, float(r_core), cfg.smoke_edge_m, harmonics, _EMPTY)
    return replace(smoke, layer=_smoke_layer(smoke, cfg, tex_rng))


def _smoke_layer(smoke: Smoke, cfg: SceneConfig, rng: np.random.Generator) -> WorldLayer:
    res = 1.0 / (1.3 * cfg.pixels_per_metre * (1 + max(cfg.camera_zoom_change, 0)))  # metres per texel
    rad = smoke.radius + 2 * res
    n = int(np.ceil(2 * rad / res)) + 1
    x0, y1 = smoke.centre[0] - rad, smoke.centre[1] + rad
    a = np.arange(n)
    gx, gy = np.meshgrid(x0 + a * res, y1 - a * res)
    alpha = smoke.alpha(np.stack([gx, gy], axis=-1), grow=1.5 * res)
    cell = max(2, int(round(1.5 / res)))
    puff = fractal_noise(rng, (n, n), (4 * cell, 2 * cell, cell), (1.0, 0.6, 0.35))
    r = np.hypot(gx - smoke.centre[0], gy - smoke.centre[1]) / max(smoke.radius, 1e-6)
    shade = 206.0 - 22.0 * np.clip(1.0 - r, 0, 1) + 16.0 * puff  # darker, denser core; puffy texture
    rgb = np.stack([shade, shade * 0.99, shade * 0.96], axis=-1)
    rgba = np.empty((n, n, 4), np.uint8)
    rgba[..., :3] = np.clip(np.round(rgb * alpha[..., None]), 0, 255)
    rgba[..., 3] = np.clip(np.round(alpha * 255), 0, 255)
    tex_to_world = np.array([[res, 0, x0], [0, -res, y1], [0, 0, 1.0]])
    return WorldLayer(rgba, tex_to_world)


@dataclass(frozen=True)
class Wall:
    """A building's edge along a straight stretch of the target's path, hiding one side of the car.

    Local frame: ``u`` along the path from ``origin`` (0..length), ``v`` sideways towards the
    building; the building covers u in [0, length], v in [v0, v0 + depth]; the path is v = 0.
    """

    origin: np.ndarray  # (2,)
    along: np.ndarray  # (2,) unit
    side: np.ndarray  # (2,) unit, towards the building
    length: float
    v0: float
    depth: float
    layer: WorldLayer

    def local(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = np.asarray(pts, float) - self.origin
        return d @ self.along, d @ self.side

    def alpha(self, pts: np.ndarray) -> np.ndarray:
        u, v = self.local(pts)
        inside = (u >= 0) & (u <= self.length) & (v >= self.v0) & (v <= self.v0 + self.depth)
        return inside.astype(float)

    def polygon(self) -> np.ndarray:
        """(4, 2) world corners of the building block."""
        uv = np.array([[0, self.v0], [self.length, self.v0], [self.length, self.v0 + self.depth],
                       [0, self.v0 + self.depth]])
        return self.origin + uv[:, :1] * self.along + uv[:, 1:] * self.side


def make_wall(
    cfg: SceneConfig, path: VehiclePath, side_sign: int, rng: np.random.Generator
) -> Wall | None:
    """A building block beside the straight stretch ``SCHEDULE.wall``, its edge ``wall_cover_fraction``
    of the car's width inside the car's lane."""
    depth = float(rng.uniform(8.0, 12.0))
    tex_rng = np.random.default_rng(rng.integers(0, 2**63))
    if cfg.wall_cover_fraction <= 0:
        return None
    i0, i1 = frame_at(SCHEDULE.wall[0], cfg), frame_at(SCHEDULE.wall[1], cfg)
    origin = path.xy[i0].copy()
    along = path.forward[i0].copy()
    side = side_sign * path.left[i0]
    length = float((path.xy[i1] - origin) @ along)
    v0 = cfg.car_width_m / 2 - cfg.wall_cover_fraction * cfg.car_width_m
    wall = Wall(origin, along, side, length, v0, depth, _EMPTY)
    return replace(wall, layer=_wall_layer(wall, cfg, tex_rng))


def _wall_layer(wall: Wall, cfg: SceneConfig, rng: np.random.Generator) -> WorldLayer:
    res = 1.0 / (1.6 * cfg.pixels_per_metre * (1 + max(cfg.camera_zoom_change, 0)))
    m = 2 * res
    u_min, v_min = -m, wall.v0 - m
    nu = int(np.ceil((wall.length + 2 * m) / res)) + 1
    nv = int(np.ceil((wall.depth + 2 * m) / res)) + 1
    u = u_min + np.arange(nu) * res
    v = v_min + np.arange(nv) * res

    def cover(c, lo, hi):  # fraction of each texel (centre c, size res) inside [lo, hi]
        return np.clip(np.minimum(c + res / 2, hi) - np.maximum(c - res / 2, lo), 0, res) / res

    alpha = cover(v, wall.v0, wall.v0 + wall.depth)[:, None] * cover(u, 0.0, wall.length)[None, :]
    # texture rows follow v, columns follow u
    vv, uu = np.meshgrid(v - wall.v0, u, indexing="ij")
    cell = max(2, int(round(0.8 / res)))
    base = 150.0 + 9.0 * fractal_noise(rng, (nv, nu), (6 * cell, 2 * cell, cell), (1.0, 0.5, 0.4))
    rgb = np.repeat(base[..., None], 3, axis=2) * np.array([1.0, 0.985, 0.94])
    # roof seams every ~3 m across the block
    seam = (np.abs(((uu + 0.5) % 3.0) - 1.5) > 1.45)
    rgb[seam] *= 0.82
    # AC units / skylights
    for _ in range(int(rng.integers(3, 7))):
        cu = rng.uniform(1.5, max(wall.length - 1.5, 1.6))
        cv = rng.uniform(2.0, max(wall.depth - 1.5, 2.1))
        hu, hv = rng.uniform(0.4, 1.0), rng.uniform(0.3, 0.7)
        shadow = (np.abs(uu - cu - 0.25) < hu) & (np.abs(vv - cv - 0.25) < hv)
        rgb[shadow] *= 0.6
        box = (np.abs(uu - cu) < hu) & (np.abs(vv - cv) < hv)
        rgb[box] = rng.uniform(175, 205)
    # parapet: a darker rim along every edge, darkest (the facade's top) on the road side
    dist_edge = np.minimum.reduce([uu, wall.length - uu, vv, wall.depth - vv])
    rgb[dist_edge < 0.45] *= 0.66
    rgb[(vv < 0.22) & (uu > -1) & (uu < wall.length + 1)] = (58, 58, 62)
    rgba = np.empty((nv, nu, 4), np.uint8)
    rgba[..., :3] = np.clip(np.round(rgb * alpha[..., None]), 0, 255)
    rgba[..., 3] = np.clip(np.round(alpha * 255), 0, 255)
    # texel (col a, row b) -> local (u_min + a res, v_min + b res) -> world
    o = wall.origin + u_min * wall.along + v_min * wall.side
    tex_to_world = np.array([
        [wall.along[0] * res, wall.side[0] * res, o[0]],
        [wall.along[1] * res, wall.side[1] * res, o[1]],
        [0, 0, 1.0],
    ])
    return WorldLayer(rgba, tex_to_world)


def composite(img: np.ndarray, layer: WorldLayer, h: np.ndarray) -> None:
    """Warp ``layer`` into ``img`` (in place) through ground->image homography ``h``; alpha-over."""
    th, tw = layer.rgba.shape[:2]
    m = h @ layer.tex_to_world
    corners = np.array([[-1, -1], [tw, -1], [tw, th], [-1, th]], float)
    q = corners @ m[:, :2].T + m[:, 2]
    if np.any(q[:, 2] <= 0):
        return
    q = q[:, :2] / q[:, 2:3]
    x0 = max(int(np.floor(q[:, 0].min())), 0)
    y0 = max(int(np.floor(q[:, 1].min())), 0)
    x1 = min(int(np.ceil(q[:, 0].max())) + 1, img.shape[1])
    y1 = min(int(np.ceil(q[:, 1].max())) + 1, img.shape[0])
    if x1 <= x0 or y1 <= y0:
        return
    shift = np.array([[1, 0, -x0], [0, 1, -y0], [0, 0, 1.0]])
    warped = cv2.warpPerspective(
        layer.rgba, shift @ m, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0, 0),
    )
    alpha_over(img[y0:y1, x0:x1], warped)
