"""The ground: a procedural town (grass, streets, roads along the vehicles' paths, buildings with
shadows, trees, parked cars, grain) pre-rendered once into a north-up texture.

Alternatively an aerial photograph can serve as the ground (``SceneConfig.texture_image``); the
vehicles' roads are then drawn over it.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .car import CarPalette, car_transform, draw_car
from .config import SceneConfig
from .noise import SensorNoise, fractal_noise
from .paths import VehiclePath

_SHIFT = 3
_LOW = 4  # smooth colour fields are computed at 1/_LOW of the texture resolution
_S = float(1 << _SHIFT)
MAX_TEXTURE_SIDE = 6000

PARKED_COLOURS = (
    (226, 226, 222), (172, 174, 178), (36, 36, 40), (40, 56, 102), (102, 104, 108),
    (192, 182, 152), (46, 72, 56), (122, 152, 188), (240, 240, 236), (70, 72, 78),
)
ROOF_COLOURS = (
    (152, 150, 144), (122, 122, 128), (172, 167, 157), (96, 99, 104), (140, 128, 112),
    (106, 112, 101), (150, 112, 92), (184, 182, 176),
)
ASPHALT = np.array([84, 86, 91], np.float32)
SIDEWALK = np.array([168, 166, 160], np.float32)
LINE_WHITE = (228, 228, 220)


@dataclass(frozen=True)
class WorldTexture:
    """North-up ground picture. ``tex_to_world`` maps texel (col, row) to world metres."""

    image: np.ndarray  # (h, w, 3) uint8 RGB
    tex_to_world: np.ndarray  # 3x3
    ppm: float  # texels per metre

    @property
    def world_to_tex(self) -> np.ndarray:
        return np.linalg.inv(self.tex_to_world)


class _Canvas:
    """World-metre drawing helpers on a texture."""

    def __init__(self, x0: float, y1: float, ppm: float, shape: tuple[int, int]):
        self.x0, self.y1, self.ppm = x0, y1, ppm
        self.shape = shape
        self.tex_to_world = np.array([[1 / ppm, 0, x0], [0, -1 / ppm, y1], [0, 0, 1.0]])
        self.world_to_tex = np.linalg.inv(self.tex_to_world)

    def px(self, pts) -> np.ndarray:
        p = np.asarray(pts, float)
        return np.stack([(p[..., 0] - self.x0) * self.ppm, (self.y1 - p[..., 1]) * self.ppm], axis=-1)

    def fixed(self, pts) -> np.ndarray:
        return np.round(self.px(pts) * _S).astype(np.int32)

    def width(self, metres: float) -> int:
        return max(1, int(round(metres * self.ppm)))

    def polyline(self, img, pts, metres, colour, closed=False):
        cv2.polylines(img, [self.fixed(pts)], closed, colour, self.width(metres), cv2.LINE_AA, _SHIFT)

    def fill(self, img, pts, colour):
        cv2.fillPoly(img, [self.fixed(pts)], colour, cv2.LINE_AA, _SHIFT)

    def fill_convex(self, img, pts, colour):
        cv2.fillConvexPoly(img, self.fixed(pts), colour, cv2.LINE_AA, _SHIFT)

    def circle(self, img, centre, radius_m, colour):
        c = np.round(self.px(centre) * _S).astype(int)
        cv2.circle(img, (int(c[0]), int(c[1])), max(1, int(round(radius_m * self.ppm * _S))), colour,
                   -1, cv2.LINE_AA, _SHIFT)


def _cells(ppm: float, *metres: float) -> tuple[int, ...]:
    return tuple(max(1, int(round(m * ppm))) for m in metres)


def _upsample(low: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A smooth low-resolution float colour field as a full-size uint8 image."""
    u8 = np.clip(np.round(low), 0, 255).astype(np.uint8)
    big = cv2.resize(u8, (u8.shape[1] * _LOW, u8.shape[0] * _LOW), interpolation=cv2.INTER_LINEAR)
    return np.ascontiguousarray(big[: shape[0], : shape[1]])


def _blend(img: np.ndarray, over: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``over`` where ``mask`` (uint8 coverage) is 255, ``img`` where 0, linear in between."""
    m3 = cv2.merge([mask, mask, mask])
    a = cv2.multiply(over, m3, scale=1.0 / 255.0)
    b = cv2.multiply(img, cv2.bitwise_not(m3), scale=1.0 / 255.0)
    return cv2.add(a, b)


def _offset(poly: np.ndarray, d: float) -> np.ndarray:
    """Polyline shifted by ``d`` metres to its left."""
    t = np.gradient(poly, axis=0)
    t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-9)
    return poly + d * np.stack([-t[:, 1], t[:, 0]], axis=1)


def _dashes(poly: np.ndarray, dash: float, gap: float) -> list[np.ndarray]:
    """Pieces of a polyline: ``dash`` metres drawn, ``gap`` metres skipped, repeatedly."""
    seg = np.linalg.norm(np.diff(poly, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    on = (s % (dash + gap)) < dash
    pieces, start = [], None
    for i, flag in enumerate(on):
        if flag and start is None:
            start = i
        elif not flag and start is not None:
            if i - start >= 1:
                pieces.append(poly[start: i + 1])
            start = None
    if start is not None and len(poly) - start >= 2:
        pieces.append(poly[start:])
    return pieces


def _densify(a: np.ndarray, b: np.ndarray, step: float) -> np.ndarray:
    n = max(2, int(np.ceil(np.linalg.norm(b - a) / step)) + 1)
    return a + np.linspace(0, 1, n)[:, None] * (b - a)


def _load_photo(path: str, shape: tuple[int, int]) -> np.ndarray | None:
    p = Path(path)
    img = cv2.imread(str(p), cv2.IMREAD_COLOR) if p.is_file() else None
    if img is None:
        warnings.warn(f"texture_image {path!r} not found or unreadable; using the procedural ground",
                      stacklevel=3)
        return None
    h, w = shape
    s = max(h / img.shape[0], w / img.shape[1])
    big = cv2.resize(img, (int(np.ceil(img.shape[1] * s)), int(np.ceil(img.shape[0] * s))),
                     interpolation=cv2.INTER_CUBIC)
    oy, ox = (big.shape[0] - h) // 2, (big.shape[1] - w) // 2
    return cv2.cvtColor(big[oy: oy + h, ox: ox + w], cv2.COLOR_BGR2RGB)


def build_world(
    cfg: SceneConfig,
    rng: np.random.Generator,
    region: tuple[float, float, float, float],
    ppm: float,
    target: VehiclePath,
    decoy: VehiclePath | None,
    target_road_offset: float,
    blocked: tuple[np.ndarray, ...] = (),
) -> WorldTexture:
    """Render the ground texture covering ``region`` = (x0, y0, x1, y1) metres at ``ppm`` texels/m.

    ``target_road_offset``: the target road's centre line, in metres to the target's left.
    ``blocked``: world polygons (e.g. the wall's building) to keep buildings and trees off.
    """
    x0, y0, x1, y1 = region
    ppm = min(ppm, MAX_TEXTURE_SIDE / max(x1 - x0, y1 - y0))
    w, h = int(np.ceil((x1 - x0) * ppm)), int(np.ceil((y1 - y0) * ppm))
    cv_ = _Canvas(x0, y1, ppm, (h, w))
    rngs = [np.random.default_rng(s) for s in rng.integers(0, 2**63, size=8)]

    photo = _load_photo(cfg.texture_image, (h, w)) if cfg.texture_image else None

    # ---- ground (smooth colour fields are made at 1/4 resolution and upsampled) ------------
    lh, lw = -(-h // _LOW), -(-w // _LOW)
    lppm = ppm / _LOW
    if photo is None:
        n1 = fractal_noise(rngs[0], (lh, lw), _cells(lppm, 30, 8, 2), (1.0, 0.6, 0.3))
        n2 = fractal_noise(rngs[0], (lh, lw), _cells(lppm, 18, 5), (1.0, 0.5))
        t = np.clip(0.5 + 0.3 * n1, 0, 1)[..., None]
        grass_a = np.array([78, 100, 54], np.float32)
        grass_b = np.array([124, 130, 80], np.float32)
        dirt = np.array([146, 132, 104], np.float32)
        low = grass_a + t * (grass_b - grass_a)
        d = np.clip((n2 - 0.9) * 2.0, 0, 1)[..., None]
        low += d * (dirt - low)
        img = _upsample(low, (h, w))
    else:
        img = photo

    # ---- roads: masks first (sidewalk, edge line, asphalt), then composite ----------------
    side_m = np.zeros((h, w), np.uint8)
    line_m = np.zeros((h, w), np.uint8)
    asph_m = np.zeros((h, w), np.uint8)
    path_m = np.zeros((h, w), np.uint8)  # keep-out around the vehicles' roads

    def road(poly, width, sidewalk=2.0, keep=False):
        cv_.polyline(side_m, poly, width + 2 * sidewalk, 255)
        cv_.polyline(line_m, poly, width, 255)
        cv_.polyline(asph_m, poly, width - 0.35, 255)
        if keep:
            cv_.polyline(path_m, poly, width + 2 * sidewalk + 3.0, 255)

    grid_angle = float(rngs[1].uniform(0, np.pi / 2))
    spacing = rngs[1].uniform(60, 95, size=2)
    phase = rngs[1].uniform(0, 1, size=2)
    e1 = np.array([np.cos(grid_angle), np.sin(grid_angle)])
    e2 = np.array([-e1[1], e1[0]])
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
    half = 0.5 * np.hypot(x1 - x0, y1 - y0) + 5
    streets = []  # (start, end) of straight side streets
    street_w = 9.0
    if photo is None:
        for e_along, e_across, sp, ph in ((e1, e2, spacing[0], phase[0]), (e2, e1, spacing[1], phase[1])):
            for k in range(int(-half // sp) - 1, int(half // sp) + 2):
                off = (k + ph) * sp
                a = centre + off * e_across - half * e_along
                b = centre + off * e_across + half * e_along
                streets.append((a, b))
                road(_densify(a, b, 50.0), street_w)

    tpoly = target.extended_polyline(60.0)
    t_road = _offset(tpoly, target_road_offset)
    target_w = 2 * (abs(target_road_offset) + cfg.car_width_m / 2 + 1.6)
    road(t_road, target_w, keep=True)
    if decoy is not None:
        road(decoy.extended_polyline(60.0), 8.0, keep=True)

    stains = fractal_noise(rngs[2], (lh, lw), _cells(lppm, 4, 1.5), (1.0, 0.7))[..., None]
    img = _blend(img, _upsample(SIDEWALK + 6 * stains, (h, w)), side_m)
    img = _blend(img, np.full_like(img, LINE_WHITE), line_m)
    img = _blend(img, _upsample(ASPHALT + 7 * stains, (h, w)), asph_m)

    # ---- markings ----------------------------------------------------------------------------
    for a, b in streets:
        for piece in _dashes(_densify(a, b, 1.0), 3.0, 5.0):
            cv_.polyline(img, piece, 0.15, LINE_WHITE)
    for piece in _dashes(t_road, 3.0, 6.0):
        cv_.polyline(img, piece, 0.15, LINE_WHITE)

    occupied = cv2.dilate(cv2.max(side_m, path_m), np.ones((3, 3), np.uint8))

    solid = np.zeros((h, w), np.uint8)  # buildings, trees and parked cars (not roads)
    for poly in blocked:
        cv_.fill(occupied, poly, 255)
        cv_.fill(solid, poly, 255)

    def free(poly_world, margin_m=1.0, mask=occupied) -> bool:
        q = cv_.px(poly_world)
        lo = np.floor(q.min(axis=0) - margin_m * ppm).astype(int)
        hi = np.ceil(q.max(axis=0) + margin_m * ppm).astype(int)
        if lo[0] < 0 or lo[1] < 0 or hi[0] >= w or hi[1] >= h:
            return False
        sub = np.zeros((hi[1] - lo[1] + 1, hi[0] - lo[0] + 1), np.uint8)
        cv2.fillConvexPoly(sub, np.round((q - lo) * _S).astype(np.int32), 255, cv2.LINE_8, _SHIFT)
        sub = cv2.dilate(sub, np.ones((2 * int(margin_m * ppm) + 1,) * 2, np.uint8))
        return not np.any(mask[lo[1]: hi[1] + 1, lo[0]: hi[0] + 1] & sub)

    def mark(poly_world):
        cv_.fill_convex(occupied, poly_world, 255)
        cv_.fill_convex(solid, poly_world, 255)

    if photo is None:
        shade = np.full((h, w), 255, np.uint8)
        sun = rngs[3].uniform(-np.pi, np.pi)
        shadow_dir = -np.array([np.cos(sun), np.sin(sun)])
        roofs = []
        # ---- buildings (placed in the blocks, off every road) ----------------------------
        area = (x1 - x0) * (y1 - y0)
        r = rngs[4]
        for _ in range(int(min(area / 110.0, 600))):
            c = np.array([r.uniform(x0, x1), r.uniform(y0, y1)])
            lx, ly = r.uniform(8, 28), r.uniform(8, 20)
            rot = grid_angle + (0.0 if r.random() < 0.85 else r.uniform(-0.3, 0.3))
            u = np.array([np.cos(rot), np.sin(rot)])
            v = np.array([-u[1], u[0]])
            poly = np.array([c + sx * lx / 2 * u + sy * ly / 2 * v
                             for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
            if not free(poly, 1.0):
                continue
            mark(poly)
            height = r.uniform(5, 25)
            roofs.append((poly, u, v, lx, ly, height, r.integers(len(ROOF_COLOURS)), r.random() < 0.35))
        for poly, *_rest, height, _c, _g in roofs:
            off = shadow_dir * 0.35 * height
            hull = cv2.convexHull(np.concatenate([poly, poly + off]).astype(np.float32))[:, 0, :]
            cv_.fill_convex(shade, hull, 135)
        # ---- trees --------------------------------------------------------------------------
        trees = []
        r = rngs[5]
        for _ in range(int(min(area / 60.0, 1500))):
            c = np.array([r.uniform(x0, x1), r.uniform(y0, y1)])
            rad = r.uniform(1.3, 3.4)
            sq = c + rad * np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]])
            if not free(sq, 0.3):
                continue
            mark(sq)
            trees.append((c, rad))
            cv_.circle(shade, c + shadow_dir * 0.35 * r.uniform(4, 9), rad, 150)
        img = cv2.multiply(img, cv2.merge([shade, shade, shade]), scale=1.0 / 255.0)
        for poly, u, v, lx, ly, _h, ci, gable in roofs:
            base = np.array(ROOF_COLOURS[ci], float) * rngs[6].uniform(0.9, 1.1)
            rim = tuple(int(x) for x in np.clip(base * 0.68, 0, 255))
            col = tuple(int(x) for x in np.clip(base, 0, 255))
            cv_.fill_convex(img, poly, rim)
            c = poly.mean(axis=0)
            inner = np.array([c + sx * (lx / 2 - 0.45) * u + sy * (ly / 2 - 0.45) * v
                              for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))])  # 0.45 m rim
            if gable:
                half1 = np.array([inner[0], inner[1], (inner[1] + inner[2]) / 2, (inner[0] + inner[3]) / 2])
                half2 = np.array([(inner[0] + inner[3]) / 2, (inner[1] + inner[2]) / 2, inner[2], inner[3]])
                cv_.fill_convex(img, half1, col)
                cv_.fill_convex(img, half2, tuple(int(x * 0.8) for x in col))
            else:
                cv_.fill_convex(img, inner, col)
                for _ in range(int(rngs[6].integers(0, 4))):  # roof units
                    p = c + rngs[6].uniform(-0.3, 0.3) * lx * u + rngs[6].uniform(-0.3, 0.3) * ly * v
                    a, b = rngs[6].uniform(0.5, 1.5), rngs[6].uniform(0.5, 1.2)
                    box = np.array([p + sa * a * u + sb * b * v for sa, sb in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
                    cv_.fill_convex(img, box + shadow_dir * 0.3, rim)
                    cv_.fill_convex(img, box, tuple(int(x) for x in np.clip(base * 1.22, 0, 255)))
        for c, rad in trees:
            cv_.circle(img, c, rad, (48, 74, 38))
            cv_.circle(img, c - shadow_dir * rad * 0.25, rad * 0.65, (64, 94, 48))
            cv_.circle(img, c - shadow_dir * rad * 0.4, rad * 0.3, (80, 110, 58))

        # ---- parked cars along the side streets ------------------------------------------
        r = rngs[7]
        placed = 0
        attempts = 0
        while placed < cfg.n_parked_cars and streets and attempts < 40 * max(cfg.n_parked_cars, 1):
            attempts += 1
            a, b = streets[int(r.integers(len(streets)))]
            d = b - a
            along = d / np.linalg.norm(d)
            left = np.array([-along[1], along[0]])
            side = 1 if r.random() < 0.5 else -1
            p = a + r.uniform(0, 1) * d + side * (street_w / 2 - 1.4) * left
            heading = np.arctan2(along[1], along[0]) + (0 if r.random() < 0.5 else np.pi)
            q = cv_.px(p)
            if not (8 <= q[0] < w - 8 and 8 <= q[1] < h - 8):
                continue
            if path_m[int(q[1]), int(q[0])]:
                continue
            fp = p + np.array([[-2.6, -1.3], [2.6, -1.3], [2.6, 1.3], [-2.6, 1.3]]) @ np.array([along, left])
            if not free(fp, 0.3, solid):
                continue
            mark(fp)
            colour = PARKED_COLOURS[int(r.integers(len(PARKED_COLOURS)))]
            m = cv_.world_to_tex @ car_transform(p, heading)
            length = cfg.car_length_m * r.uniform(0.9, 1.1)
            draw_car(img, m, length, cfg.car_width_m * r.uniform(0.92, 1.05), CarPalette.from_body(colour))
            placed += 1

    # ---- grain and optics ------------------------------------------------------------------
    img = SensorNoise(4.0).apply(img, rngs[2])
    img = cv2.GaussianBlur(img, (0, 0), 0.55 * ppm / cfg.pixels_per_metre)
    return WorldTexture(img, cv_.tex_to_world, ppm)
