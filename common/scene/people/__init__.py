"""Synthetic surveillance scene of several walking, articulated people with per-part ground truth.

>>> from common.scene.people import PeopleScene, PeopleSceneConfig
>>> scene = PeopleScene(PeopleSceneConfig(n_people=3), seed=0)
>>> f = scene.frame(0)
>>> f.image.shape, f.truth.parts.shape, scene.crossings

Modules: ``config`` (the knobs), ``body`` (the 10-part skeleton and its gait), ``render``
(background, clutter, drawing, light) and ``scene`` (the public class and its ground truth).
"""

from .body import PART_NAMES
from .config import PeopleSceneConfig
from .scene import PeopleFrame, PeopleScene, PeopleTruth

__all__ = ["PART_NAMES", "PeopleFrame", "PeopleScene", "PeopleSceneConfig", "PeopleTruth"]
