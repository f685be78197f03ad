"""A detector that does not answer is 'no observation': identical to step(t, None), never a crash."""

import pytest

from common.tracking import RBPF, SIR, InitialState, RBPFConfig, SIRConfig, WindowedML, WindowedMLConfig
from common.tracking.observation import ObservationUnavailable
from common.tracking.testing import GaussianBumpObservation


class Silent:
    """Like a remote detector that timed out."""

    def __init__(self, inner):
        self.inner = inner
        self.time, self.homography, self.image_size = inner.time, inner.homography, inner.image_size

    def score_at(self, hyps):
        raise ObservationUnavailable("no reply")

    def score_grid(self, xy):
        raise ObservationUnavailable("no reply")


@pytest.mark.parametrize("make", [
    lambda: RBPF(RBPFConfig(n_particles=50), InitialState(x=100.0, y=100.0, vx=3.0, time=0.0, pos_std=2.0), seed=4),
    lambda: SIR(SIRConfig(n_particles=50), InitialState(x=100.0, y=100.0, vx=3.0, time=0.0, pos_std=2.0), seed=4),
    lambda: WindowedML(WindowedMLConfig(), InitialState(x=100.0, y=100.0, time=0.0)),
])
def test_unavailable_equals_none(make):
    a, b = make(), make()
    for k in range(1, 8):
        t = k / 30.0
        obs = GaussianBumpObservation(time=t, target_xy=(100.0 + 3 * t, 100.0))
        if k in (3, 4):
            sa, sb = a.step(t, Silent(obs)), b.step(t, None)
            assert not sa.observed and not sb.observed
        else:
            sa, sb = a.step(t, obs), b.step(t, obs)
            assert sa.observed
        assert sa.identical(sb)
