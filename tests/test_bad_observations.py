"""Bad observation slots never become a silent wrong answer, in any landmark filter.

A NaN or an infinity in a valid slot is refused on the host with the argument and the slot
named; inside a caller's ``jit`` (values unknown on the host) the slot is dropped and counted
in ``info.num_ignored``, and every estimate stays finite. An integer mask of 0/1 filters exactly like
the boolean one; other integers (a 0/2 mask, which a bitwise ``&`` would turn into "drop every
slot") are refused on the host and read as nonzero = set inside a caller's ``jit``; a float mask or
float ids are refused.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.demo import demo_setting
from jaxnav.localization import ekf, grid, mcl, ukf
from jaxnav.models import hf_rfid
from jaxnav.models.motion import OmniNoise
from jaxnav.sim import landmark_world as world
from jaxnav.sim import trajectories
from jaxnav.slam import ekf_slam, fastslam, pf_slam

START = jnp.asarray([5.0, 1.5, 0.0])
STEPS = 12


def _world():
    _, p = demo_setting(10)
    controls = trajectories.loop_controls(STEPS, 0.5, 0.21, 0.25)
    sim = world.simulate(jax.random.PRNGKey(1), p.landmarks, START, controls, p.motion, p.sensor)
    assert bool(sim.observations.mask[3, 0])  # the slot the tests poison is a real observation
    return p, controls, sim.observations


def _filters(p):
    """``name -> run(observations)`` for every landmark filter, on the demo room."""
    kp = ekf.KalmanParams(p.motion, p.sensor, p.landmarks)
    cov = jnp.diag(jnp.asarray([1e-3, 1e-3, 1e-4]))
    mcl_config = mcl.MCLConfig(num_particles=64)
    grid_config = grid.GridConfig((0.0, 10.0, 0.0, 10.0), 20, 20, 8, "velocity")
    slam_config = ekf_slam.EKFSLAMConfig(num_landmarks=p.landmarks.shape[0])
    slam_params = ekf_slam.EKFSLAMParams(p.motion, p.sensor)

    def fs(version):
        config = fastslam.FastSLAMConfig(num_particles=16, num_landmarks=p.landmarks.shape[0], version=version)
        params = fastslam.FastSLAMParams(p.motion, p.sensor)
        state = fastslam.init(jax.random.PRNGKey(0), config, params, START)
        return lambda u, o: fastslam.run(jax.random.PRNGKey(2), state, config, params, u, o)

    return {
        "ekf": lambda u, o: ekf.run(None, ekf.init(None, ekf.EKFConfig(), kp, START, cov), ekf.EKFConfig(), kp, u, o),
        "ukf": lambda u, o: ukf.run(None, ukf.init(None, ukf.UKFConfig(), kp, START, cov), ukf.UKFConfig(), kp, u, o),
        "mcl": lambda u, o: mcl.run(
            jax.random.PRNGKey(2), mcl.init(jax.random.PRNGKey(0), mcl_config, p, START), mcl_config, p, u, o
        ),
        "grid": lambda u, o: grid.run(None, grid.init(None, grid_config, p, START), grid_config, p, u, o),
        "ekf_slam": lambda u, o: ekf_slam.run(
            None, ekf_slam.init(None, slam_config, slam_params, START, cov), slam_config, slam_params, u, o
        ),
        "fastslam1": fs(1),
        "fastslam2": fs(2),
    }


NAMES = ["ekf", "ukf", "mcl", "grid", "ekf_slam", "fastslam1", "fastslam2"]


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("value", [np.nan, np.inf])
def test_a_non_finite_valid_slot_is_refused_on_the_host(name, value):
    p, u, obs = _world()
    bad = obs._replace(z=obs.z.at[3, 0, 0].set(value))
    with pytest.raises(ValueError, match=r"observations.z holds NaN or infinite values .* index \(3, 0\)"):
        _filters(p)[name](u, bad)


@pytest.mark.parametrize("name", NAMES)
def test_a_non_finite_valid_slot_under_jit_is_dropped_and_counted(name):
    p, u, obs = _world()
    run = _filters(p)[name]
    bad = obs._replace(z=obs.z.at[3, 0, 1].set(jnp.inf))
    final, trace = jax.jit(lambda o: run(u, o))(bad)
    for leaf in jax.tree_util.tree_leaves((final, trace.estimate)):
        if jnp.issubdtype(leaf.dtype, jnp.floating):
            assert np.all(np.isfinite(np.asarray(leaf)) | np.isneginf(np.asarray(leaf))), name
    _, clean = run(u, obs)
    np.testing.assert_array_equal(
        np.asarray(trace.num_ignored), np.asarray(clean.num_ignored) + (np.arange(STEPS) == 3)
    )
    # the same as masking the slot out
    _, masked = run(u, obs._replace(mask=obs.mask.at[3, 0].set(False)))
    np.testing.assert_allclose(np.asarray(trace.estimate), np.asarray(masked.estimate), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("name", NAMES)
def test_an_integer_mask_of_zeros_and_ones_is_the_boolean_mask_and_others_are_refused(name):
    p, u, obs = _world()
    run = _filters(p)[name]
    _, expected = run(u, obs)
    _, ones = run(u, obs._replace(mask=obs.mask.astype(jnp.int32)))
    np.testing.assert_array_equal(np.asarray(ones.estimate), np.asarray(expected.estimate))
    twos = obs._replace(mask=obs.mask.astype(jnp.int32) * 2)
    with pytest.raises(ValueError, match=r"observations.mask must be boolean or integers 0 and 1, got 2 at index"):
        run(u, twos)
    # inside a caller's jit: nonzero = set. The caller's jit is another XLA program than the
    # filter's own, which may round differently (measured: up to 2.4e-6 m): equal to float32 rounding
    _, traced = jax.jit(lambda o: run(u, o))(twos)
    np.testing.assert_allclose(np.asarray(traced.estimate), np.asarray(expected.estimate), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("name", NAMES)
def test_float_masks_and_float_ids_are_refused_by_name(name):
    p, u, obs = _world()
    run = _filters(p)[name]
    with pytest.raises(ValueError, match="observations.mask must be a boolean array"):
        run(u, obs._replace(mask=obs.mask.astype(jnp.float32)))
    with pytest.raises(ValueError, match="observations.ids must be an integer array"):
        run(u, obs._replace(ids=obs.ids.astype(jnp.float32)))


def test_tag_detections_with_an_integer_mask_update_the_tags():
    """PF-SLAM: an integer 0/1 mask detects like the boolean one (a bitwise & with a 0/2 mask
    would drop every slot; such a mask is refused on the host)."""
    config = pf_slam.PFSLAMConfig(num_particles=8, num_tag_particles=4, max_tags=8)
    params = pf_slam.PFSLAMParams(OmniNoise(jnp.zeros(3)), hf_rfid.reader_params(0.06))
    control = jnp.asarray([0.0, 0.0, 0.0, 0.1])
    masks = {"bool": jnp.asarray([True, False]), "int": jnp.asarray([1, 0], jnp.int32)}
    out = {}
    for kind, mask in masks.items():
        det = hf_rfid.TagDetections(jnp.asarray([3, 0], jnp.int32), jnp.asarray([0, 0], jnp.int32), mask)
        state = pf_slam.init(jax.random.PRNGKey(0), config, params, jnp.zeros(3))
        _, info = pf_slam.step(jax.random.PRNGKey(1), state, config, params, control, det)
        out[kind] = info
    assert int(out["int"].num_new) == int(out["bool"].num_new) == 1
    np.testing.assert_array_equal(out["int"].slot_estimates, out["bool"].slot_estimates)
    state = pf_slam.init(jax.random.PRNGKey(0), config, params, jnp.zeros(3))
    det = hf_rfid.TagDetections(jnp.asarray([3], jnp.int32), jnp.asarray([0], jnp.int32), jnp.ones(1))
    with pytest.raises(ValueError, match="detections.mask must be a boolean array"):
        pf_slam.step(jax.random.PRNGKey(1), state, config, params, control, det)
    det = hf_rfid.TagDetections(jnp.asarray([3], jnp.int32), jnp.asarray([0], jnp.int32), jnp.asarray([2]))
    with pytest.raises(ValueError, match="detections.mask must be boolean or integers 0 and 1, got 2"):
        pf_slam.step(jax.random.PRNGKey(1), state, config, params, control, det)
