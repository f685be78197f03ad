"""DTCWT polar-matching detector (Pang et al. 2010 section 2; Nelson et al. section II).

See ``docs/polar-matching.md`` in the shared folder for the construction this implements.
"""

from common.detector.frame import PreparedFrame, prepare_frame, FrameCache
from common.detector.template import Template
from common.detector.matcher import PolarMatcher, ANGLES_DEG

__all__ = ["PreparedFrame", "prepare_frame", "FrameCache", "Template", "PolarMatcher", "ANGLES_DEG"]
