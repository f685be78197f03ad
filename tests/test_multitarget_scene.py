"""The synthetic people scene: deterministic, ground truth consistent with the rendering."""

import numpy as np
import pytest

from common.scene.people import PART_NAMES, PeopleScene, PeopleSceneConfig
from common.scene.people.render import apply_light, label_of


def test_same_seed_same_frames_in_any_order():
    cfg = PeopleSceneConfig(n_people=3, n_frames=30)
    a, b = PeopleScene(cfg, seed=4), PeopleScene(cfg, seed=4)
    for i in (17, 0, 29, 5):
        fa, fb = a.frame(i), b.frame(i)
        assert np.array_equal(fa.image, fb.image) and np.array_equal(fa.labels, fb.labels)
        assert np.array_equal(fa.truth.parts, fb.truth.parts) and np.array_equal(fa.truth.visible, fb.truth.visible)
    assert not np.array_equal(PeopleScene(cfg, seed=5).frame(3).image, a.frame(3).image)


@pytest.mark.parametrize("seed", [0, 3])
def test_pixel_at_each_visible_part_is_its_clothing_colour(seed):
    cfg = PeopleSceneConfig(n_people=4, n_frames=60, noise_sigma=0.0)
    scene = PeopleScene(cfg, seed=seed)
    hidden = checked = 0
    for i in range(0, 60, 3):
        f = scene.frame(i)
        for k, walker in enumerate(scene.walkers):
            want = apply_light(walker.colours, f.light)
            for p in range(10):
                x, y = np.round(f.truth.parts[k, p]).astype(int)
                if not f.truth.visible[k, p]:
                    hidden += 1
                    continue
                checked += 1
                assert f.labels[y, x] == label_of(k, p), (i, k, PART_NAMES[p])
                assert np.array_equal(f.image[y, x], want[p]), (i, k, PART_NAMES[p], f.image[y, x], want[p])
    assert checked > 400 and hidden > 10  # people do hide each other's parts


def test_people_cross_occlude_and_the_light_changes():
    cfg = PeopleSceneConfig(n_people=3)
    scene = PeopleScene(cfg, seed=1)
    assert scene.crossings, "people walking opposite ways must pass each other"
    frac = np.array([scene.frame(i).truth.visible_fraction for i in range(0, len(scene), 2)])
    assert frac.min() < 0.2  # a part is (almost) completely hidden at some time
    assert scene.light(0) == 1.0 and scene.light(len(scene) - 1) == pytest.approx(cfg.illumination_low)
    # distinct clothing colours per person
    shirts = {tuple(w.colours[1]) for w in scene.walkers}
    assert len(shirts) == 3


@pytest.mark.parametrize("n", [1, 5])
def test_number_of_people_is_configurable(n):
    scene = PeopleScene(PeopleSceneConfig(n_people=n, n_frames=12), seed=2)
    f = scene.frame(11)
    assert f.truth.parts.shape == (n, 10, 2) and f.truth.boxes.shape == (n, 4)
    assert f.image.shape == (288, 384, 3) and f.image.dtype == np.uint8
    with pytest.raises(IndexError):
        scene.frame(12)
    with pytest.raises(ValueError):
        PeopleSceneConfig(n_people=6)
