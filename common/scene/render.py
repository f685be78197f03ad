"""Per-frame compositing: ground warp, cars, building edge, smoke, sensor noise."""

from __future__ import annotations

import cv2
import numpy as np

from .car import CarPalette, car_transform, draw_car
from .config import SceneConfig
from .noise import SensorNoise
from .occluders import Smoke, Wall, composite
from .world import WorldTexture


class Renderer:
    """Draws frames of one scene; everything expensive was prepared at construction."""

    def __init__(self, cfg: SceneConfig, world: WorldTexture, wall: Wall | None, smoke: Smoke | None):
        self.cfg = cfg
        self.world = world
        self.layers = [o.layer for o in (wall, smoke) if o is not None]  # wall below smoke
        self.noise = SensorNoise(cfg.noise_sigma)
        self.target_palette = CarPalette.from_body(cfg.target_color)
        self.decoy_palette = CarPalette.from_body(cfg.decoy_color)

    def render(
        self,
        h: np.ndarray,
        target: tuple[np.ndarray, float] | None,
        decoy: tuple[np.ndarray, float] | None,
        occluders: bool = True,
        noise_rng: np.random.Generator | None = None,
    ) -> np.ndarray:
        """One RGB frame through ground->image homography ``h``.

        ``target`` / ``decoy``: (world xy, heading in radians) or None to leave the car out.
        ``noise_rng``: generator for the sensor noise, or None for a noise-free frame.
        """
        cfg = self.cfg
        img = cv2.warpPerspective(
            self.world.image, h @ self.world.tex_to_world, (cfg.width, cfg.height),
            flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE,
        )
        for pose, palette in ((decoy, self.decoy_palette), (target, self.target_palette)):
            if pose is not None:
                draw_car(img, h @ car_transform(*pose), cfg.car_length_m, cfg.car_width_m, palette)
        if occluders:
            for layer in self.layers:
                composite(img, layer, h)
        if noise_rng is not None:
            img = self.noise.apply(img, noise_rng)
        return img
