"""The synthetic scene's hardest event, end to end: a car emerging from 1.5 s of full smoke.

On seed 5 (also 6 and 11 of seeds 0-12) Pang's RBPF committed to the secondary peak half a car
length ahead of the emerging car (its visible front half matches the template shifted) on the
machine the seeds were chosen on; the jump component of
``RECOVERY_PROPOSAL`` brings the track back within 10 frames of re-emergence (``polartrack
study`` measures this over 20 seeds)."""

from __future__ import annotations

import numpy as np
import pytest

from common.evaluation import recovered, reemergence_frame
from common.single_target.runner import Tracker
from common.settings import RECOVERY_PROPOSAL, profile_for
from common.sources import SyntheticSource


def _errors(seed: int, extra: dict, frames: int) -> tuple[np.ndarray, int]:
    src = SyntheticSource(seed=seed)
    st = profile_for(src, filter="rbpf", seed=seed, particles=200)
    if extra:
        st = st.model_copy(update={"rbpf": st.rbpf.model_copy(update=extra)})
    f0 = src.frame(0)
    tracker = Tracker.start(f0, f0.truth.box, st)
    err, vf = [], []
    for i in range(frames):
        f = src.frame(i)
        s = tracker.step(f)
        tx, ty = src.true_centre(i)
        err.append(np.hypot(s.map_estimate.image_x - tx, s.map_estimate.image_y - ty))
        vf.append(f.truth.visible_fraction or 0.0)
    return np.array(err), reemergence_frame(np.array(vf), src.scene.events["smoke"])


@pytest.mark.parametrize("seed", [5])
def test_jump_component_recovers_where_pangs_filter_locks_on_an_offset_peak(seed):
    # Whether Pang's plain filter locks on the offset peak here is chaotic: it did on the machine the
    # seed was chosen on and recovers on others (BLAS kernels differ in the last bits), so it is no
    # negative control; the jump component must recover either way.
    jumps, re = _errors(seed, RECOVERY_PROPOSAL, 165)
    assert re is not None and re + 20 <= 165
    assert recovered(jumps, re)
    assert np.median(jumps[re:re + 20]) < 3
