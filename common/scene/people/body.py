"""Articulated walking bodies: a 10-segment skeleton (head, torso, upper and lower arms and legs).

A person at time t is a torso position plus a walking phase; the joints follow from fixed
proportions of the person's height H and the limb angles of a simple gait (thighs swing by
+-leg_swing, the knee bends on the forward swing, arms swing opposite to the legs). Limbs are
seen from three-quarters: left and right limbs hang from shoulders and hips offset sideways, and
swing along the walking direction. Every part's ground truth is its segment's midpoint (the
head's and torso's centres), the 10-point model of Bhaskar and Mihaylova (2011, section 4.1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

PART_NAMES = (
    "head", "torso",
    "l_upper_arm", "l_lower_arm", "r_upper_arm", "r_lower_arm",
    "l_upper_leg", "l_lower_leg", "r_upper_leg", "r_lower_leg",
)  # fmt: skip
"""The 10 parts, in ground-truth column order."""

# Proportions, as fractions of the person's height H.
HIP_HEIGHT = 0.50  # hip joints above the feet
TORSO_LENGTH = 0.30  # hips to shoulders
TORSO_WIDTH = 0.20
HEAD_RADIUS = 0.07
NECK = 0.005  # gap between torso top and head bottom
SHOULDER_OFFSET = 0.09  # sideways from the body axis
SHOULDER_DROP = 0.02  # below the torso top
HIP_OFFSET = 0.05
UPPER_ARM, LOWER_ARM = 0.17, 0.16
UPPER_LEG, LOWER_LEG = 0.24, 0.24
ARM_WIDTH, LEG_WIDTH = 0.06, 0.085

SEGMENT_PARTS = PART_NAMES[2:]
"""The eight limb segments, drawn as thick lines."""


@dataclass(frozen=True)
class Pose:
    """One person's drawable pose in one frame (pixels)."""

    head_centre: np.ndarray  # (2,)
    head_radius: float
    torso_corners: np.ndarray  # (4, 2) polygon
    segments: np.ndarray  # (8, 2, 2): start and end of each limb segment, SEGMENT_PARTS order
    widths: np.ndarray  # (8,) line thickness of each segment
    centres: np.ndarray  # (10, 2) ground-truth part centres, PART_NAMES order


def _limb(start: np.ndarray, angle: float, length: float, direction: float) -> np.ndarray:
    """End point of a limb of ``length`` hanging from ``start`` rotated by ``angle`` (radians,
    positive = forward along the walking ``direction`` +-1)."""
    return start + length * np.array([direction * np.sin(angle), np.cos(angle)])


def pose(x: float, feet_y: float, height: float, direction: float, phase: float,
         leg_swing: float, arm_swing: float) -> Pose:
    """The pose of a person whose body axis is at image x ``x`` with feet on ``feet_y``.

    ``phase`` (radians) is the gait phase; ``leg_swing`` / ``arm_swing`` the swing amplitudes (radians).
    """
    h = height
    hip_y = feet_y - HIP_HEIGHT * h
    top_y = hip_y - TORSO_LENGTH * h
    torso_c = np.array([x, hip_y - 0.5 * TORSO_LENGTH * h])
    hw = 0.5 * TORSO_WIDTH * h
    torso = np.array([[x - hw, top_y], [x + hw, top_y], [x + 0.85 * hw, hip_y], [x - 0.85 * hw, hip_y]])
    head_c = np.array([x + direction * 0.01 * h, top_y - NECK * h - HEAD_RADIUS * h])
    segs, centres = [], [head_c, torso_c]
    for sign, ph in ((-1.0, 0.0), (1.0, np.pi)):  # left, right
        shoulder = np.array([x + sign * SHOULDER_OFFSET * h, top_y + SHOULDER_DROP * h])
        a_up = arm_swing * np.sin(phase + ph + np.pi)  # arms swing opposite to the same side's leg
        elbow = _limb(shoulder, a_up, UPPER_ARM * h, direction)
        a_lo = a_up + 0.35 * (1.0 + np.sin(phase + ph + np.pi))  # the forearm bends forward
        hand = _limb(elbow, a_lo, LOWER_ARM * h, direction)
        segs += [(shoulder, elbow), (elbow, hand)]
    for sign, ph in ((-1.0, 0.0), (1.0, np.pi)):  # left, right
        hip = np.array([x + sign * HIP_OFFSET * h, hip_y])
        a_up = leg_swing * np.sin(phase + ph)
        knee = _limb(hip, a_up, UPPER_LEG * h, direction)
        a_lo = a_up - 0.6 * max(0.0, np.cos(phase + ph))  # the knee bends while the leg swings forward
        ankle = _limb(knee, a_lo, LOWER_LEG * h, direction)
        segs += [(hip, knee), (knee, ankle)]
    segments = np.array(segs, dtype=float)
    centres += list(segments.mean(axis=1))
    widths = np.array([ARM_WIDTH * h] * 4 + [LEG_WIDTH * h] * 4)
    return Pose(head_c, HEAD_RADIUS * h, torso, segments, widths, np.array(centres, dtype=float))
