"""Placing a body in a person box (:mod:`common.multitarget.placement`)."""

import numpy as np
import pytest

from common.multitarget import HistogramEvidence, MultiInit, body_model
from common.multitarget.config import PlacementConfig
from common.multitarget.placement import place_in_boxes, surround_boxes, surround_histograms

H = 60.0
TORSO = np.array([80.0, 100.0])


def _person(arm: bool = True):
    """A red torso, a skin head, dark legs and (optionally) a blue arm stretched out to the right on a
    grey floor; the person box x, y, w, h from head top to feet, arm included."""
    img = np.full((200, 160, 3), 128, np.uint8)
    x, y = TORSO
    img[int(y - 0.15 * H):int(y + 0.15 * H), int(x - 0.1 * H):int(x + 0.1 * H)] = (200, 30, 30)  # torso 0.2 x 0.3 H
    img[int(y - 0.3 * H):int(y - 0.16 * H), int(x - 0.07 * H):int(x + 0.07 * H)] = (230, 180, 140)  # head
    img[int(y + 0.15 * H):int(y + 0.65 * H), int(x - 0.08 * H):int(x + 0.08 * H)] = (40, 40, 60)  # legs
    right = x + 0.1 * H
    if arm:
        img[int(y - 0.12 * H):int(y - 0.06 * H), int(x + 0.1 * H):int(x + 0.25 * H)] = (30, 30, 200)
        right = x + 0.25 * H
    top = y - 0.295 * H
    box = np.array([[x - 0.1 * H, top, right - (x - 0.1 * H), 0.945 * H]])
    return HistogramEvidence(img), box


def test_surround_boxes_by_hand():
    ring = surround_boxes(np.array([[10.0, 20.0, 30.0, 40.0]]), np.array([5.0]))
    assert ring.tolist() == [[[5, 15, 10, 65], [40, 15, 45, 65], [10, 15, 40, 20], [10, 60, 40, 65]]]


def test_a_lopsided_box_is_corrected_to_the_torso():
    body = body_model(10)
    ev, box = _person(arm=True)
    init = MultiInit.from_boxes(box, body, ev.image_size)
    assert init.parts[0, 0, 0] - TORSO[0] == pytest.approx(0.075 * H, abs=0.1)  # the arm pulls the box centre 4.5 px right
    placed, shift = place_in_boxes(init, box, body, ev, PlacementConfig())
    assert abs(placed.parts[0, 0, 0] - TORSO[0]) <= 1.0 and abs(placed.parts[0, 0, 1] - TORSO[1]) <= 1.0
    assert shift[0, 0] == pytest.approx(placed.parts[0, 0, 0] - init.parts[0, 0, 0])
    np.testing.assert_allclose(placed.parts - init.parts, np.broadcast_to(shift[:, None], init.parts.shape))  # rigid shift
    assert placed.height == pytest.approx(init.height)
    # negative control: without the search the body stays where the box put it
    same, none = place_in_boxes(init, box, body, ev, PlacementConfig(search_x=0.0, search_y=0.0))
    assert not none.any() and np.array_equal(same.parts, init.parts)


def test_nothing_to_find_keeps_the_box_placement():
    """On a blank frame every shift scores the same: the nearest (no shift) wins."""
    body = body_model(10)
    ev = HistogramEvidence(np.full((200, 160, 3), 128, np.uint8))
    box = np.array([[70.0, 80.0, 20.0, 56.0]])
    init = MultiInit.from_boxes(box, body, ev.image_size)
    placed, shift = place_in_boxes(init, box, body, ev, PlacementConfig())
    assert not shift.any() and np.array_equal(placed.parts, init.parts)


def test_the_surroundings_count_only_the_pixels_in_the_frame():
    img = np.full((100, 100, 3), 128, np.uint8)
    img[:, 0:2] = (20, 20, 220)  # the only blue: the 2 px of the left ring inside the frame
    ev = HistogramEvidence(img)
    box = np.array([[2.0, 30.0, 20.0, 40.0]])  # ring of 10 px: left x -8..2 (2 px in the frame), right 22..32
    bg = surround_histograms(ev, box, np.array([10.0]))[0]
    blue = ev.histograms(np.array([[0.0, 0.0, 2.0, 100.0]]))[0]
    grey = ev.histograms(np.array([[50.0, 0.0, 60.0, 100.0]]))[0]
    share = (2 * 60) / (2 * 60 + 10 * 60 + 2 * 20 * 10)  # left in frame, right, above and below
    np.testing.assert_allclose(bg, share * blue + (1 - share) * grey, atol=1e-6)
    assert share == pytest.approx(0.107, abs=1e-3)  # counting the whole left rectangle would give 0.375
