"""The car model seen from above: polygons in the car's frame, drawn anti-aliased through a homography.

Car frame: metres, x forward, y to the car's left, origin at the centre of the body. The body is
a rounded rectangle with a dark rim; windscreen, roof, rear window, side windows, mirrors, head
and tail lights give it internal structure and a distinct front and back.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

_SHIFT = 4  # cv2 fixed-point fraction bits: vertices at 1/16 px
_SCALE = float(1 << _SHIFT)

GLASS = (38, 44, 56)
HEADLIGHT = (228, 226, 196)
TAILLIGHT = (110, 12, 16)


def _rounded_rect(half_l: float, half_w: float, r: float, n_arc: int = 4) -> np.ndarray:
    pts = []
    for cx, cy, a0 in ((half_l - r, half_w - r, 0.0), (-half_l + r, half_w - r, 90.0),
                       (-half_l + r, -half_w + r, 180.0), (half_l - r, -half_w + r, 270.0)):
        for a in np.deg2rad(np.linspace(a0, a0 + 90.0, n_arc + 1)):
            pts.append((cx + r * np.cos(a), cy + r * np.sin(a)))
    return np.array(pts)


def _rect(x0: float, x1: float, y0: float, y1: float) -> np.ndarray:
    return np.array([(x0, y0), (x1, y0), (x1, y1), (x0, y1)], float)


def _trapezoid(x0: float, x1: float, hw0: float, hw1: float) -> np.ndarray:
    return np.array([(x0, -hw0), (x1, -hw1), (x1, hw1), (x0, hw0)], float)


@lru_cache(maxsize=32)
def car_parts(length: float, width: float) -> tuple[tuple[str, np.ndarray], ...]:
    """(role, polygon) pairs in drawing order; roles pick the colour (see ``CarPalette``)."""
    L, W = length, width
    hl, hw = L / 2, W / 2
    rim = 0.09 * W
    parts = [
        ("rim", _rounded_rect(hl, hw, 0.16 * W)),
        ("body", _rounded_rect(hl - rim, hw - rim, 0.16 * W - rim)),
        ("hood", _trapezoid(0.27 * L, 0.47 * L, 0.40 * W, 0.36 * W)),
        ("glass", _trapezoid(0.08 * L, 0.25 * L, 0.44 * W, 0.37 * W)),  # windscreen
        ("roof", _rect(-0.23 * L, 0.08 * L, -0.40 * W, 0.40 * W)),
        ("glass", _trapezoid(-0.23 * L, -0.37 * L, 0.40 * W, 0.34 * W)),  # rear window
        ("glass", _rect(-0.22 * L, 0.07 * L, 0.405 * W, 0.445 * W)),  # side windows
        ("glass", _rect(-0.22 * L, 0.07 * L, -0.445 * W, -0.405 * W)),
        ("rim", _rect(0.12 * L, 0.16 * L, 0.47 * W, 0.56 * W)),  # mirrors
        ("rim", _rect(0.12 * L, 0.16 * L, -0.56 * W, -0.47 * W)),
        ("headlight", _rect(0.455 * L, 0.485 * L, 0.22 * W, 0.40 * W)),
        ("headlight", _rect(0.455 * L, 0.485 * L, -0.40 * W, -0.22 * W)),
        ("taillight", _rect(-0.49 * L, -0.465 * L, 0.22 * W, 0.40 * W)),
        ("taillight", _rect(-0.49 * L, -0.465 * L, -0.40 * W, -0.22 * W)),
    ]
    for _, p in parts:
        p.setflags(write=False)
    return tuple(parts)


@dataclass(frozen=True)
class CarPalette:
    """Colours (RGB) of a car's parts, derived from its body colour."""

    body: tuple[int, int, int]
    rim: tuple[int, int, int]
    hood: tuple[int, int, int]
    roof: tuple[int, int, int]
    glass: tuple[int, int, int] = GLASS
    headlight: tuple[int, int, int] = HEADLIGHT
    taillight: tuple[int, int, int] = TAILLIGHT

    @classmethod
    def from_body(cls, body: tuple[int, int, int]) -> CarPalette:
        b = np.asarray(body, float)
        rim = tuple(int(v) for v in np.round(b * 0.32 + 8))
        hood = tuple(int(v) for v in np.clip(np.round(b * 1.08 + 6), 0, 255))
        roof = tuple(int(v) for v in np.clip(np.round(b * 0.86 + 10), 0, 255))
        return cls(tuple(int(v) for v in body), rim, hood, roof)

    def colour(self, role: str) -> tuple[int, int, int]:
        return getattr(self, role)


def car_transform(xy, heading: float) -> np.ndarray:
    """3x3 map from the car frame to the world for a car at ``xy`` heading ``heading`` (radians)."""
    c, s = np.cos(heading), np.sin(heading)
    return np.array([[c, -s, xy[0]], [s, c, xy[1]], [0, 0, 1.0]])


def draw_car(img: np.ndarray, m: np.ndarray, length: float, width: float, palette: CarPalette) -> None:
    """Draw a car in place; ``m`` maps the car frame (metres) to ``img`` pixels (a homography)."""
    for role, poly in car_parts(length, width):
        q = poly @ m[:, :2].T + m[:, 2]
        q = q[:, :2] / q[:, 2:3]
        pts = np.round(q * _SCALE).astype(np.int32)
        cv2.fillPoly(img, [pts], palette.colour(role), lineType=cv2.LINE_AA, shift=_SHIFT)


def body_corners(length: float, width: float) -> np.ndarray:
    """(4, 2) corners of the car's body rectangle in the car frame."""
    return _rect(-length / 2, length / 2, -width / 2, width / 2)


@lru_cache(maxsize=32)
def footprint_samples(length: float, width: float, nl: int = 30, nw: int = 14) -> np.ndarray:
    """(nl*nw, 2) cell centres of a regular grid over the body rectangle, in the car frame.

    Averages over these are area fractions of the car (used for ``visible_fraction``).
    """
    xs = (np.arange(nl) + 0.5) / nl * length - length / 2
    ys = (np.arange(nw) + 0.5) / nw * width - width / 2
    g = np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1).reshape(-1, 2)
    g.setflags(write=False)
    return g
