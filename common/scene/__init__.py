"""Built-in synthetic aerial scene: a red car seen from a UAV, with decoy, smoke, wall and ground truth.

>>> from common.scene import SceneConfig, SyntheticScene
>>> scene = SyntheticScene(SceneConfig(), seed=0)      # or SyntheticScene.from_spec("synthetic:0")
>>> f = scene.frame(0)
>>> f.image.shape, f.truth.image_xy, scene.events

Modules: ``config`` (the knobs), ``paths`` (vehicle paths), ``camera`` (pose -> homography),
``car`` (the car model), ``world`` (ground texture), ``occluders`` (smoke, wall), ``noise``,
``render`` (compositing) and ``scene`` (the public class and its ground truth).
"""

from .config import SceneConfig
from .scene import SceneFrame, SyntheticScene, Truth

__all__ = ["SceneConfig", "SceneFrame", "SyntheticScene", "Truth"]
