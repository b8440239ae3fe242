"""Range-bearing model and landmark-world simulator."""

import math

import jax
import jax.numpy as jnp
import numpy as np
from jax.test_util import check_grads

from jaxnav.models import landmarks as lm
from jaxnav.models import motion
from jaxnav.sim import landmark_world as world


def test_predict_and_inverse_are_consistent():
    pose = jnp.asarray([1.0, 2.0, 0.7])
    lmk = jnp.asarray([4.0, -1.0])
    z = lm.predict(pose, lmk)
    np.testing.assert_allclose(z[0], math.hypot(3.0, -3.0), rtol=1e-6)
    np.testing.assert_allclose(z[1], math.atan2(-3.0, 3.0) - 0.7, atol=1e-6)
    np.testing.assert_allclose(lm.inverse(pose, z), lmk, atol=1e-5)


def test_log_likelihood_is_the_gaussian_density_with_wrapped_bearing():
    pose = jnp.asarray([0.0, 0.0, math.pi - 0.01])
    lmk = jnp.asarray([[-1.0, 0.0]])  # straight behind the x-axis: bearing ≈ +0.01
    z = jnp.asarray([[1.05, 0.01 - 2 * math.pi + 0.02]])  # same bearing, one turn off
    sd = jnp.asarray([0.1, 0.05])
    got = lm.log_likelihood(pose[None], lmk, z, jnp.asarray([True]), lm.RangeBearingNoise(sd))
    want = -math.log(2 * math.pi * 0.1 * 0.05) - 0.5 * ((0.05 / 0.1) ** 2 + (0.02 / 0.05) ** 2)
    np.testing.assert_allclose(got, [want], rtol=1e-4)


def test_lookup_drops_ids_outside_the_map():
    lmap = jnp.arange(10.0).reshape(5, 2)
    obs = lm.RangeBearingObs(
        jnp.asarray([0, 4, 5, -1, 2]), jnp.zeros((5, 2)), jnp.asarray([True, True, True, True, False])
    )
    pos, valid, ignored = lm.lookup(lmap, obs)
    np.testing.assert_array_equal(valid, [True, True, False, False, False])
    assert int(ignored) == 2
    np.testing.assert_allclose(pos[1], [8.0, 9.0])


def test_log_likelihood_gradient():
    lmk = jnp.asarray([[3.0, 1.0], [0.0, 4.0]])
    z = jnp.asarray([[3.1, 0.3], [4.0, 1.2]])
    valid = jnp.asarray([True, True])
    f = lambda pose, sd: lm.log_likelihood(pose, lmk, z, valid, lm.RangeBearingNoise(sd))  # noqa: E731
    check_grads(
        f, (jnp.asarray([0.2, 0.1, 0.05]), jnp.asarray([0.2, 0.1])), order=1, modes=["rev"], atol=5e-2, rtol=5e-2
    )


def test_square_room_landmarks_w2_layout():
    got = np.asarray(world.square_room_landmarks(10.0, 8))
    want = [[0, 0], [5, 0], [10, 0], [10, 5], [10, 10], [5, 10], [0, 10], [0, 5]]
    np.testing.assert_allclose(got, want, atol=1e-5)


def test_simulator_noise_statistics_and_visibility():
    lmks = world.square_room_landmarks(10.0, 8)
    noise = lm.RangeBearingNoise(jnp.asarray([0.1, 0.05]))
    still = motion.VelocityNoise(jnp.zeros(6), jnp.zeros(3))
    controls = jnp.tile(jnp.asarray([0.0, 0.0, 0.1]), (4000, 1))  # stand still
    pose = jnp.asarray([5.0, 5.0, 0.0])
    sim = world.simulate(jax.random.PRNGKey(0), lmks, pose, controls, still, noise)
    np.testing.assert_allclose(sim.true_poses, np.tile(pose, (4000, 1)), atol=1e-5)
    resid = np.array(sim.observations.z - lm.predict(pose, lmks))
    resid[..., 1] = (resid[..., 1] + np.pi) % (2 * np.pi) - np.pi
    np.testing.assert_allclose(resid.std(axis=(0, 1)), [0.1, 0.05], rtol=0.03)
    assert bool(sim.observations.mask.all())
    limited = world.simulate(jax.random.PRNGKey(0), lmks, pose, controls[:2], still, noise, max_range=6.0, fov=math.pi)
    # From the centre facing +x: corners are 7.07 m away, (5,0)/(5,10) at ±90° (on the FOV edge), (0,5) behind.
    np.testing.assert_array_equal(limited.observations.mask[0], [False, True, False, True, False, True, False, False])
