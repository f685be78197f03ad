"""Polar matching accuracy: the numbers of section 6 of the polar-matching spec, and controls."""

import numpy as np
import pytest

import common.detector.frame as frame_mod
from common.detector import PolarMatcher, Template, prepare_frame
from common.detector.layout import column_harmonics
from common.detector.sampler import sample_pmatrices
from common.sources.imageio import read_rgb
from imagegen import DATA, angle_error, blob_image, rotate_about

SWEEP = np.arange(0, 91, 5)


def sweep(images, centre, matcher):
    errors, peaks = [], []
    for angle, img in zip(SWEEP, images):
        prep = prepare_frame(img)
        best, score, _ = matcher.refine_peak(prep, *centre)
        errors.append(angle_error(best, angle))
        peaks.append(score)
    errors = np.asarray(errors)
    return float(np.sqrt(np.mean(errors**2))), float(np.max(np.abs(errors))), float(np.min(peaks))


@pytest.fixture(scope="module")
def blob_sweep():
    return [blob_image(a) for a in SWEEP]


def test_synthetic_sweep(blob_sweep):
    centre = (128.0, 128.0)
    matcher = PolarMatcher(Template.from_image(blob_sweep[0], centre))
    rms, worst, peak = sweep(blob_sweep, centre, matcher)
    assert rms <= 1.0
    assert worst <= 2.0
    assert peak >= 0.85


def test_unrelated_image_scores_low(blob_sweep):
    centre = (128.0, 128.0)
    matcher = PolarMatcher(Template.from_image(blob_sweep[0], centre))
    other = prepare_frame(blob_image(0, seed=99))
    _, score, _ = matcher.refine_peak(other, *centre)
    assert score < 0.6


def test_negative_control_zero_kc(blob_sweep):
    centre = (128.0, 128.0)
    template = Template.from_image(blob_sweep[0], centre)
    rms, _, _ = sweep(blob_sweep, centre, PolarMatcher(template, kc=np.zeros(34, np.int64)))
    assert rms > 2.0  # about 3 degrees: the column-specific centring matters


def test_negative_control_flipped_kc(blob_sweep):
    centre = (128.0, 128.0)
    template = Template.from_image(blob_sweep[0], centre)
    rms, _, _ = sweep(blob_sweep, centre, PolarMatcher(template, kc=-column_harmonics()))
    assert rms > 5.0  # about 11 degrees


def test_negative_control_no_fix(blob_sweep, monkeypatch):
    monkeypatch.setattr(frame_mod, "FIX", np.ones(6, np.complex128))
    frame_mod._demodulator_grid.cache_clear()
    try:
        centre = (128.0, 128.0)
        matcher = PolarMatcher(Template.from_image(blob_sweep[0], centre))
        rms, _, _ = sweep(blob_sweep, centre, matcher)
    finally:
        monkeypatch.undo()
        frame_mod._demodulator_grid.cache_clear()
    assert rms > 15.0  # about 40 degrees: the matcher is useless without the phase fix


def test_rot90_is_an_exact_row_roll():
    img = blob_image(0, channels=3, seed=4)
    centre = (127.5, 127.5)  # rot90 maps the centre of a 256x256 image onto itself
    p0 = sample_pmatrices(prepare_frame(img), np.array([centre[0]]), np.array([centre[1]]), np.array([True]))[0]
    p1 = sample_pmatrices(prepare_frame(np.rot90(img).copy()), np.array([centre[0]]), np.array([centre[1]]),
                          np.array([True]))[0]
    rolled = np.roll(p0, 3, axis=0)  # 90 degrees anticlockwise = 3 rows down
    corr = np.abs(np.vdot(rolled, p1)) / (np.linalg.norm(rolled) * np.linalg.norm(p1))
    assert corr > 0.9999
    # and not merely "correlated": the unrolled matrix is far off
    corr0 = np.abs(np.vdot(p0, p1)) / (np.linalg.norm(p0) * np.linalg.norm(p1))
    assert corr0 < 0.9
    matcher = PolarMatcher(Template(pmatrix=p0, centre=centre))
    best, score, _ = matcher.refine_peak(prepare_frame(np.rot90(img).copy()), *centre)
    assert abs(angle_error(best, 90.0)) < 0.05 and score > 0.9999


AERO = DATA / "opencv-aerial" / "aero1.jpg"


@pytest.mark.skipif(not AERO.exists(), reason=f"{AERO} not present")
def test_real_photograph_rotated():
    img = read_rgb(AERO).astype(np.float64)
    centre = (320.0, 240.0)
    images = [rotate_about(img, centre, a) for a in SWEEP]
    matcher = PolarMatcher(Template.from_image(images[0], centre))
    rms, worst, peak = sweep(images, centre, matcher)
    assert rms <= 1.5
    assert worst <= 4.0
    assert peak >= 0.8


@pytest.mark.skipif(not AERO.exists(), reason=f"{AERO} not present")
def test_real_photograph_with_noise_still_matches():
    img = read_rgb(AERO).astype(np.float64)
    centre = (320.0, 240.0)
    matcher = PolarMatcher(Template.from_image(img, centre))
    rng = np.random.default_rng(5)
    rotated = rotate_about(img, centre, 40.0) + rng.normal(0, 0.05 * 255, img.shape)
    best, score, _ = matcher.refine_peak(prepare_frame(rotated), *centre)
    assert abs(angle_error(best, 40.0)) < 3.0
    assert score > 0.75


def test_score_at_equals_grid_on_grid_angles_and_interpolates_between():
    img = blob_image(0, channels=3, seed=2)
    centre = (128.0, 128.0)
    matcher = PolarMatcher(Template.from_image(img, centre))
    rotated = prepare_frame(blob_image(20, channels=3, seed=2))
    rng = np.random.default_rng(0)
    xy = np.c_[rng.uniform(100, 156, 20), rng.uniform(100, 156, 20)]
    grid, valid = matcher.score_grid(rotated, xy)
    assert valid.all()
    for k in (0, 3, 17, 47):
        at, _ = matcher.score_at(rotated, np.c_[xy, np.full(20, 7.5 * k)])
        np.testing.assert_allclose(at, grid[:, k], atol=1e-5)
    # between grid bins, score_at follows the band-limited curve: a dense sweep of it peaks
    # where refine_peak says, near the true 20 degrees, above the best grid value
    best, best_score, g = matcher.refine_peak(rotated, 128.0, 128.0)
    dense = np.arange(0.0, 45.0, 0.05)
    curve, _ = matcher.score_at(rotated, np.c_[np.full_like(dense, 128.0), np.full_like(dense, 128.0), dense])
    assert abs(dense[np.argmax(curve)] - best) <= 0.05
    assert curve.max() == pytest.approx(best_score, abs=1e-4)
    assert best_score >= g.max() and abs(angle_error(best, 20.0)) < 2.0
    s = curve[np.argmin(np.abs(dense - 20.0))]
    # angles wrap: -340 is +20
    s2, _ = matcher.score_at(rotated, np.array([[128.0, 128.0, -340.0]]))
    assert s2[0] == pytest.approx(s, abs=1e-5)


def test_shift_robustness():
    img = blob_image(0, channels=3, seed=6)
    centre = (128.0, 128.0)
    matcher = PolarMatcher(Template.from_image(img, centre))
    prep = prepare_frame(img)
    offsets = np.array([[0, 0], [0.25, 0], [0, 0.5], [0.5, 0.5], [-0.5, 0.25], [1.0, 0], [0, -1.0]])
    s, _ = matcher.score_at(prep, np.c_[centre[0] + offsets[:, 0], centre[1] + offsets[:, 1], np.zeros(len(offsets))])
    assert s[0] == pytest.approx(1.0, abs=1e-5)
    assert np.all(s[1:5] > 0.95)  # sub-pixel offsets
    assert np.all(s[5:] > 0.85)  # one whole pixel
    far, _ = matcher.score_at(prep, np.array([[centre[0] + 12, centre[1], 0.0]]))
    assert far[0] < s[-1] - 0.2  # but the score does fall off with distance


@pytest.mark.skipif(not AERO.exists(), reason=f"{AERO} not present")
def test_discrimination_against_background():
    img = read_rgb(AERO).astype(np.float64)
    centre = (300.0, 200.0)
    matcher = PolarMatcher(Template.from_image(img, centre))
    rng = np.random.default_rng(8)
    scene = rotate_about(img, centre, 30.0) + rng.normal(0, 6, img.shape)
    prep = prepare_frame(scene)
    target, _ = matcher.score_grid(prep, np.array([centre]))
    bg_xy = np.c_[rng.uniform(64, 575, 400), rng.uniform(64, 415, 400)]
    bg_xy = bg_xy[np.hypot(bg_xy[:, 0] - centre[0], bg_xy[:, 1] - centre[1]) > 20]
    bg, valid = matcher.score_grid(prep, bg_xy)
    assert valid.all()
    bg_best = bg.max(axis=1)
    t = target.max()
    assert t > 0.85
    assert t > np.quantile(bg_best, 0.99) + 0.15
    assert (t - bg_best.mean()) / bg_best.std() > 4.0


def test_rgb_fusion_uses_colour():
    # Two targets with the same luminance pattern but different colours: RGB matching tells
    # them apart, grey matching cannot.
    base = blob_image(0, seed=9)
    rgb_a = np.stack([base, 0.2 * base, 0.1 * base], axis=2)
    lum = np.array([0.299, 0.587, 0.114])
    # a colour with the same luminance weights: solve for a blue-ish version
    w_b = np.array([0.1, 0.2, 0.0])
    w_b[2] = (lum @ np.array([1.0, 0.2, 0.1]) - lum[:2] @ w_b[:2]) / lum[2]
    rgb_b = base[:, :, None] * w_b
    centre = (128.0, 128.0)
    rgb_matcher = PolarMatcher(Template.from_image(rgb_a, centre))
    s_same, _ = rgb_matcher.score_at(prepare_frame(rgb_a), np.array([[128.0, 128.0, 0.0]]))
    s_other, _ = rgb_matcher.score_at(prepare_frame(rgb_b), np.array([[128.0, 128.0, 0.0]]))
    grey_a, grey_b = rgb_a @ lum, rgb_b @ lum
    grey_matcher = PolarMatcher(Template.from_image(grey_a, centre))
    g_other, _ = grey_matcher.score_at(prepare_frame(grey_b), np.array([[128.0, 128.0, 0.0]]))
    assert s_same[0] == pytest.approx(1.0, abs=1e-5)
    assert g_other[0] > 0.999  # grey can't tell
    assert s_other[0] < 0.8  # joint RGB norm can
    with pytest.raises(ValueError, match="channel"):
        rgb_matcher.score_at(prepare_frame(grey_a), np.array([[128.0, 128.0, 0.0]]))
