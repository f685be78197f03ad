"""Reference histograms from the pixels no nearer target covers (common/multitarget/references.py)."""

import numpy as np

from common.multitarget import HistogramEvidence, MultiInit, make_filter, method_config
from common.multitarget.appearance import bhattacharyya
from common.multitarget.references import reference_histograms, visible_cells


def test_visible_cells_tile_the_box_less_the_union_of_overlapping_occluders():
    box = np.array([10.0, 20.0, 50.0, 70.0])
    occ = np.array([[0.0, 30.0, 25.0, 40.0], [20.0, 35.0, 35.0, 90.0], [45.0, 0.0, 48.0, 25.0], [60.0, 0.0, 80.0, 100.0]])
    cells = visible_cells(box, occ)
    mask = np.zeros((100, 100), bool)
    for x0, y0, x1, y1 in cells.astype(int):
        assert not mask[y0:y1, x0:x1].any()  # disjoint
        mask[y0:y1, x0:x1] = True
    want = np.zeros_like(mask)
    want[20:70, 10:50] = True
    for x0, y0, x1, y1 in occ.astype(int):
        want[y0:y1, x0:x1] = False
    assert np.array_equal(mask, want)
    assert np.array_equal(visible_cells(box, np.empty((0, 4))), box[None])


def _scene():
    """Two 'people' of one torso box each: A (red, feet at y 80) half behind B (blue, feet at y 90)."""
    img = np.full((120, 160, 3), 128, np.uint8)
    img[40:80, 40:60] = (220, 20, 20)  # A
    img[50:90, 50:70] = (20, 20, 220)  # B, in front: its box covers the right half of A's
    parts = np.array([[[50.0, 60.0]], [[60.0, 70.0]]])
    size = np.full((2, 1, 2), [20.0, 40.0])
    return img, parts, size


def test_a_part_behind_another_target_takes_its_reference_from_its_own_pixels():
    img, parts, size = _scene()
    ev = HistogramEvidence(img)
    refs, visible = reference_histograms(ev, parts, size)
    red = ev.histograms(np.array([[40.0, 40.0, 50.0, 80.0]]))[0]
    blue = ev.histograms(np.array([[50.0, 50.0, 70.0, 90.0]]))[0]
    assert np.allclose(visible[:, 0], [0.625, 1.0])  # A: 10 x 40 + 10 x 10 of 20 x 40 in view
    assert bhattacharyya(refs[0, 0], red) > 0.99 and bhattacharyya(refs[0, 0], blue) < 0.01
    assert np.allclose(refs[1, 0], ev.histograms(np.array([[50.0, 50.0, 70.0, 90.0]]))[0], atol=1e-6)  # B: whole box
    # negative control: A's whole box mixes in B's blue
    whole = ev.histograms(np.array([[40.0, 40.0, 60.0, 80.0]]))[0]
    assert bhattacharyya(whole, blue) > 0.3
    # below min_visible the whole box is kept
    refs_min, _ = reference_histograms(ev, parts, size, min_visible=0.7)
    assert np.allclose(refs_min[0, 0], whole, atol=1e-6)


def test_filters_take_visible_references_unless_switched_off():
    img, parts, size = _scene()
    init = MultiInit(parts=parts, height=size[:, 0, 1] / 0.26)  # the 1-part model's torso box is 0.18 H x 0.26 H
    ev = HistogramEvidence(img)
    blue = ev.histograms(np.array([[50.0, 50.0, 70.0, 90.0]]))[0]
    on = make_filter(method_config("epmcmc-elpda", n_parts=1, n_particles=10), init, ev, 0)
    off = make_filter(method_config("epmcmc-elpda", n_parts=1, n_particles=10, reference_min_visible=None), init, ev, 0)
    assert bhattacharyya(on.targets.references[0, 0], blue) < 0.05
    assert bhattacharyya(off.targets.references[0, 0], blue) > 0.3
