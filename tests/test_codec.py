"""Message <-> domain conversions (common.msgs.convert): round trips and refusals."""

from types import SimpleNamespace

import numpy as np
import pytest

from common.msgs import ParticleCloud, pack
from common.msgs.convert import msg_to_cloud, particles_msg


def _state(n: int, rng: np.random.Generator):
    return SimpleNamespace(particles=rng.normal(0, 300, (n, 5)), particles_image=rng.uniform(0, 1280, (n, 2)),
                           weights=rng.dirichlet(np.ones(n)), particle_visibility=rng.uniform(0, 1, n),
                           p_visible=0.5, time=1.25)


def test_particle_cloud_round_trips_in_float32():
    st = _state(400, np.random.default_rng(0))
    msg = ParticleCloud.FromString(particles_msg(7, st).SerializeToString())
    assert msg.frame_index == 7 and msg.count == 400 and len(msg.particles) == 400 * 5 * 4  # float32 on the wire
    cloud = msg_to_cloud(msg)
    for got, want in [(cloud.states, st.particles), (cloud.image_xy, st.particles_image),
                      (cloud.weights, st.weights), (cloud.p_visible, st.particle_visibility)]:
        assert got.dtype == np.float64 and got.shape == want.shape
        assert np.array_equal(got, want.astype(np.float32).astype(np.float64))
        assert np.allclose(got, want, rtol=1e-6, atol=1e-4) and not np.array_equal(got, want)


def test_particle_cloud_of_an_older_recording_reads_as_float64():
    st = _state(3, np.random.default_rng(1))
    old = ParticleCloud(count=3, particles=pack(st.particles), image_xy=pack(st.particles_image), weights=pack(st.weights))
    cloud = msg_to_cloud(old)
    assert np.array_equal(cloud.states, st.particles) and cloud.p_visible is None  # bit for bit


def test_particle_cloud_whose_size_disagrees_with_its_count_is_refused():
    st = _state(3, np.random.default_rng(2))
    good = particles_msg(0, st)
    for bad in [ParticleCloud(count=4, particles=good.particles, image_xy=good.image_xy, weights=good.weights),
                ParticleCloud(count=3, particles=good.particles[:-1], image_xy=good.image_xy, weights=good.weights)]:
        with pytest.raises(ValueError):
            msg_to_cloud(bad)
