"""The benchmarks' axis-aligned box of an oriented estimate: the turned extent, not the envelope."""

from __future__ import annotations

import math

import pytest

from common.tracking.state import Estimate, TrackState, oriented_to_axis_aligned, oriented_to_moment_box


def test_moment_box_by_hand():
    # a 20 x 10 box about (100, 50): unchanged at 0 and 180 degrees, sides swapped at 90 and -90,
    # a square of side sqrt((20^2 + 10^2) / 2) = sqrt(250) at 45
    assert oriented_to_moment_box(100, 50, 20, 10, 0) == pytest.approx((90, 45, 20, 10))
    assert oriented_to_moment_box(100, 50, 20, 10, 180) == pytest.approx((90, 45, 20, 10))
    for turn in (90, -90, 270):
        assert oriented_to_moment_box(100, 50, 20, 10, turn) == pytest.approx((95, 40, 10, 20))
    side = math.sqrt(250.0)
    assert oriented_to_moment_box(100, 50, 20, 10, 45) == pytest.approx((100 - side / 2, 50 - side / 2, side, side))
    # the squared sides add up to the box's own at every angle (the extent's trace)
    for th in (12.0, 33.0, 61.0, 137.0):
        _, _, w, h = oriented_to_moment_box(0, 0, 20, 10, th)
        assert w * w + h * h == pytest.approx(500.0)


def test_an_angle_error_hardly_grows_the_moment_box():
    """One step of the matcher's angle grid (7.5 degrees) grows a 2:1 box's short side by 2.5 %
    turned as an extent; the envelope of the turned box (the negative control) by 25 %."""
    _, _, w, h = oriented_to_moment_box(0, 0, 20, 10, 7.5)
    assert w == pytest.approx(19.87, abs=0.01) and h == pytest.approx(10.25, abs=0.01)
    _, _, hw, hh = oriented_to_axis_aligned(0, 0, 20, 10, 7.5)
    assert hh / 10 > 1.24 and hw / 20 > 1.05


def test_the_states_box_is_the_moment_box():
    est = Estimate(x=0.0, y=0.0, vx=0.0, vy=0.0, theta=30.0, image_x=200.0, image_y=120.0)
    state = TrackState(time=0.0, observed=True, map_estimate=est, mmse_estimate=est, p_visible=1.0, n_eff=1.0,
                       speed=0.0, orientation=30.0, size=(40.0, 16.0))
    assert state.axis_aligned_box() == pytest.approx(oriented_to_moment_box(200.0, 120.0, 40.0, 16.0, 30.0))
    assert state.axis_aligned_box() != pytest.approx(oriented_to_axis_aligned(200.0, 120.0, 40.0, 16.0, 30.0))
    assert TrackState(time=0.0, observed=True, map_estimate=est, mmse_estimate=est, p_visible=1.0, n_eff=1.0,
                      speed=0.0, orientation=30.0).axis_aligned_box() is None
