"""Beta calibration: the ML fit recovers known parameters; the sampler separates target from background."""

import numpy as np
import pytest

from common.evaluation.calibration import calibrate, fit_beta
from common.sources import open_source


def test_fit_beta_recovers_known_parameters():
    rng = np.random.default_rng(0)
    for a, b in ((5.0, 7.0), (1.0, 7.0), (6.0, 2.5)):
        z = rng.beta(a, b, 20000)
        fa, fb = fit_beta(z)
        assert fa == pytest.approx(a, rel=0.05) and fb == pytest.approx(b, rel=0.05)


def test_calibration_on_synthetic_scene(tmp_path):
    cal = calibrate(open_source("synthetic:5", n_frames=6), frames=6, per_frame=10)
    assert cal.frames == 6
    assert cal.visible.size == 60
    assert cal.visible.mean() > 0.5 > cal.background.mean() + 0.3
    (a1, b1), (a0, b0) = cal.visible_ab, cal.background_ab
    assert a1 / (a1 + b1) > 0.5 > a0 / (a0 + b0)  # fitted means on the right sides
    from common.evaluation.calibration import plot_calibration

    plot_calibration(cal, str(tmp_path / "cal.png"))
    assert (tmp_path / "cal.png").stat().st_size > 10_000


def test_beta_by_moments_recovers_a_known_beta_and_refuses_what_none_fits():
    """The moments fit the re-acquisition's threshold and tools/background_scores.py share."""
    import numpy as np
    import pytest

    from common.tracking.likelihood import beta_by_moments

    z = np.random.default_rng(4).beta(0.4, 6.0, size=200_000)
    a, b = beta_by_moments(z)
    assert a == pytest.approx(0.4, rel=0.03) and b == pytest.approx(6.0, rel=0.03)
    assert beta_by_moments(np.full(10, 0.2)) is None  # no spread
    assert beta_by_moments(np.array([0.3])) is None
    assert beta_by_moments(np.array([0.1, np.nan, 0.2])) is None
    assert beta_by_moments(np.array([0.0, 1.0, 0.0, 1.0])) is None  # variance m(1 - m): no Beta
