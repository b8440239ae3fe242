"""Monte Carlo localization ([A] Alg. 3): convergence, jit/vmap, tracing, determinism, bad input."""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.core import weights
from jaxnav.demo import demo_setting, run_demo
from jaxnav.localization import mcl
from jaxnav.models import landmarks as lm
from jaxnav.models import motion
from jaxnav.sim import landmark_world as world
from jaxnav.sim import trajectories

START = jnp.asarray([5.0, 1.5, 0.0])
# Short runs of the default config share one length: one simulation and one compiled ``run``.
SHORT = 8


@functools.cache  # equal settings share the simulation (its arrays are immutable)
def _setting(n=300, steps=30, **config_kw):
    config, params = demo_setting(n)
    if config_kw:
        config = mcl.MCLConfig(num_particles=n, **config_kw)
    controls = trajectories.loop_controls(steps, 0.5, 0.21, 0.25)
    sim = world.simulate(jax.random.PRNGKey(10), params.landmarks, START, controls, params.motion, params.sensor)
    state = mcl.init(jax.random.PRNGKey(11), config, params, START, jnp.asarray([0.3, 0.3, 0.1]))
    return config, params, sim, state


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_demo_converges_below_20_cm_after_50_steps(seed):
    """The convergence bound of landmark MCL: position error < 0.2 m from step 50 on, in the demo world."""
    result = run_demo(seed=seed, num_steps=80)
    assert np.all(np.isfinite(result.estimates))
    assert result.position_error[49:].max() < 0.2, result.position_error[49:].max()


def test_init_takes_a_list_pose_like_an_array():
    config, params, _, _ = _setting(steps=SHORT)
    a = mcl.init(jax.random.PRNGKey(0), config, params, [5.0, 1.5, 0.0], [0.1, 0.1, 0.05])
    b = mcl.init(jax.random.PRNGKey(0), config, params, jnp.asarray([5.0, 1.5, 0.0]), jnp.asarray([0.1, 0.1, 0.05]))
    np.testing.assert_array_equal(a.particles, b.particles)


def test_run_equals_a_loop_of_steps_with_fold_in_keys():
    config, params, sim, state = _setting(steps=SHORT)
    key = jax.random.PRNGKey(3)
    final, trace = mcl.run(key, state, config, params, sim.controls, sim.observations)
    s = state
    for t in range(SHORT):
        obs_t = jax.tree_util.tree_map(lambda x: x[t], sim.observations)
        s, info = mcl.step(jax.random.fold_in(key, t), s, config, params, sim.controls[t], obs_t)
        np.testing.assert_allclose(info.estimate, trace.estimate[t], atol=1e-5)
    np.testing.assert_allclose(s.particles, final.particles, atol=1e-5)


def test_same_key_is_bitwise_identical_and_different_keys_differ():
    config, params, sim, state = _setting()
    a = mcl.run(jax.random.PRNGKey(5), state, config, params, sim.controls, sim.observations)
    b = mcl.run(jax.random.PRNGKey(5), state, config, params, sim.controls, sim.observations)
    c = mcl.run(jax.random.PRNGKey(6), state, config, params, sim.controls, sim.observations)
    for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)):
        np.testing.assert_array_equal(x, y)
    assert not np.array_equal(a[0].particles, c[0].particles)


def test_runs_under_jit_and_vmap_over_runs():
    config, params, sim, state = _setting(n=200, steps=20)

    def one_run(key):
        k_init, k_run = jax.random.split(key)
        s0 = mcl.init(k_init, config, params, START, jnp.asarray([0.3, 0.3, 0.1]))
        _, trace = mcl.run(k_run, s0, config, params, sim.controls, sim.observations)
        return trace.estimate

    keys = jax.random.split(jax.random.PRNGKey(0), 4)
    batched = jax.jit(jax.vmap(one_run))(keys)
    assert batched.shape == (4, 20, 3)
    for r in range(4):
        np.testing.assert_allclose(batched[r], one_run(keys[r]), atol=1e-4)
    err = np.linalg.norm(np.asarray(batched[:, -1, :2]) - np.asarray(sim.true_poses[-1, :2]), axis=-1)
    assert np.all(err < 0.2)


def test_no_retrace_between_calls_with_the_same_shapes():
    """``run`` traces the step exactly once per (config, shapes); new data or keys reuse it."""
    before = mcl.run.trace_count()
    config, params, sim, state = _setting(n=37, steps=6)  # a config no other test compiled
    mcl.run(jax.random.PRNGKey(0), state, config, params, sim.controls, sim.observations)
    assert mcl.run.trace_count() == before + 1  # scan traces its body once
    other = world.simulate(jax.random.PRNGKey(99), params.landmarks, START, sim.controls, params.motion, params.sensor)
    params2 = params._replace(sensor=lm.RangeBearingNoise(jnp.asarray([0.2, 0.1])))
    mcl.run(jax.random.PRNGKey(1), state, config, params2, other.controls, other.observations)
    assert mcl.run.trace_count() == before + 1


def test_masked_and_out_of_map_observations_are_ignored_and_counted():
    config, params, sim, state = _setting(steps=SHORT)  # its unpadded run is test_run_equals_a_loop's program
    obs = sim.observations
    m = params.landmarks.shape[0]
    # Append two extra slots per step: one masked with NaN data, one with an id beyond the map.
    extra_ids = jnp.tile(jnp.asarray([[0, m + 3]], jnp.int32), (SHORT, 1))
    extra_z = jnp.tile(jnp.asarray([[[jnp.nan, jnp.nan], [1.0, 0.0]]]), (SHORT, 1, 1))
    extra_mask = jnp.tile(jnp.asarray([[False, True]]), (SHORT, 1))
    padded = lm.RangeBearingObs(
        jnp.concatenate([obs.ids, extra_ids], 1),
        jnp.concatenate([obs.z, extra_z], 1),
        jnp.concatenate([obs.mask, extra_mask], 1),
    )
    key = jax.random.PRNGKey(2)
    _, ref = mcl.run(key, state, config, params, sim.controls, obs)
    _, got = mcl.run(key, state, config, params, sim.controls, padded)
    np.testing.assert_allclose(got.estimate, ref.estimate, atol=1e-5)
    np.testing.assert_array_equal(got.num_ignored, np.ones(SHORT))
    np.testing.assert_array_equal(ref.num_ignored, np.zeros(SHORT))


def test_no_observations_leaves_weights_alone_and_filter_keeps_running():
    config, params, sim, state = _setting(steps=5, motion_model="velocity", ess_threshold=0.5)
    empty = sim.observations._replace(mask=jnp.zeros_like(sim.observations.mask))
    final, trace = mcl.run(jax.random.PRNGKey(0), state, config, params, sim.controls, empty)
    np.testing.assert_allclose(trace.log_likelihood, 0.0, atol=1e-5)
    assert not np.any(trace.resampled)
    assert np.all(np.isfinite(final.particles))


def test_degenerate_weights_are_reset_and_flagged_never_nan():
    config, params, sim, state = _setting(steps=3)
    # a NaN control at step 1 moves every particle to NaN, so every particle has zero weight. The
    # host refuses it (tests/test_bad_input.py); inside a caller's jit it reaches the filter.
    bad = sim.controls.at[1, 0].set(jnp.nan)
    final, trace = jax.jit(lambda u: mcl.run(jax.random.PRNGKey(0), state, config, params, u, sim.observations))(bad)
    np.testing.assert_array_equal(trace.degenerate, [False, True, False])
    assert trace.log_likelihood[1] == -np.inf
    # ESS of a degenerate step is 0 (weights.step_ess), as weights.ess says of all −inf log-weights
    assert float(trace.ess[1]) == 0.0 == float(weights.ess(jnp.full(4, -jnp.inf)))
    assert np.all(np.asarray(trace.ess)[[0, 2]] >= 1.0)
    assert np.all(np.isfinite(final.particles)) and np.all(np.isfinite(trace.estimate))


def test_ess_conditional_resampling_and_gaussian_refresh_options():
    config, params, sim, state = _setting(steps=20, ess_threshold=0.5, resampling="stratified", gaussian_refresh=True)
    final, trace = mcl.run(jax.random.PRNGKey(0), state, config, params, sim.controls, sim.observations)
    assert np.all(np.isfinite(final.particles))
    assert 0 < int(trace.resampled.sum()) <= 20
    err = np.linalg.norm(np.asarray(trace.estimate[-1, :2] - sim.true_poses[-1, :2]))
    assert err < 0.2


def test_global_localization_from_uniform_prior():
    config, params = demo_setting(20000)
    controls = trajectories.loop_controls(30, 0.5, 0.21, 0.25)
    sim = world.simulate(jax.random.PRNGKey(4), params.landmarks, START, controls, params.motion, params.sensor)
    state = mcl.init_uniform(jax.random.PRNGKey(5), config, params, (0.0, 10.0, 0.0, 10.0))
    _, trace = mcl.run(jax.random.PRNGKey(6), state, config, params, sim.controls, sim.observations)
    err = np.linalg.norm(np.asarray(trace.estimate[-10:, :2] - sim.true_poses[-10:, :2]), axis=-1)
    assert err.max() < 0.2


def test_float64_is_preserved():
    with jax.enable_x64(True):
        config, params = demo_setting(100)
        params = jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float64), params)
        controls = jnp.asarray(trajectories.loop_controls(4), jnp.float64)
        sim = world.simulate(
            jax.random.PRNGKey(0),
            params.landmarks,
            jnp.asarray(START, jnp.float64),
            controls,
            params.motion,
            params.sensor,
        )
        state = mcl.init(jax.random.PRNGKey(1), config, params, jnp.asarray(START, jnp.float64), jnp.full((3,), 0.1))
        final, trace = mcl.run(jax.random.PRNGKey(2), state, config, params, sim.controls, sim.observations)
        assert final.particles.dtype == jnp.float64
        assert trace.estimate.dtype == jnp.float64


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"num_particles": 0}, "num_particles must be a positive integer"),
        ({"num_particles": 2.5}, "num_particles must be a positive integer"),
        ({"ess_threshold": 0.0}, "ess_threshold must be in"),
        ({"ess_threshold": 1.5}, "ess_threshold must be in"),
        ({"resampling": "bogus"}, "resampling must be one of"),
        ({"motion_model": "warp"}, "motion_model must be one of"),
    ],
)
def test_bad_config_is_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        mcl.MCLConfig(**kwargs)


def test_bad_params_and_inputs_are_refused_with_the_argument_named():
    config, params, sim, state = _setting(steps=3)
    key = jax.random.PRNGKey(0)
    run = lambda p=params, c=sim.controls, o=sim.observations, s=state: mcl.run(key, s, config, p, c, o)  # noqa: E731
    with pytest.raises(ValueError, match="params.sensor.sd must be finite and strictly positive"):
        run(p=params._replace(sensor=lm.RangeBearingNoise(jnp.asarray([0.1, 0.0]))))
    with pytest.raises(ValueError, match="motion noise pose_sd must be finite and non-negative"):
        run(p=params._replace(motion=params.motion._replace(pose_sd=jnp.asarray([0.1, -0.1, 0.0]))))
    with pytest.raises(ValueError, match="params.motion must be a VelocityNoise"):
        run(p=params._replace(motion=motion.OmniNoise(jnp.ones(3))))
    with pytest.raises(ValueError, match="controls holds 1 value.* not finite"):
        run(c=sim.controls.at[1, 0].set(jnp.nan))
    with pytest.raises(ValueError, match=r"controls must have shape \(\*, 3\)"):
        run(c=jnp.zeros((3, 2)))
    with pytest.raises(ValueError, match="same number of steps"):
        run(c=sim.controls[:2])
    with pytest.raises(ValueError, match=r"state.particles must have shape \(300, 3\)"):
        run(s=state._replace(particles=state.particles[:10]))
    with pytest.raises(ValueError, match="initial_sd must be finite and non-negative"):
        mcl.init(key, config, params, START, jnp.asarray([0.1, -1.0, 0.1]))
    with pytest.raises(ValueError, match="bounds must satisfy"):
        mcl.init_uniform(key, config, params, (1.0, 0.0, 0.0, 1.0))


def test_masked_observation_inside_jit_keeps_running():
    """Inside the user's own jit the host checks are skipped; masks still work."""
    config, params, sim, state = _setting(steps=SHORT)
    obs = sim.observations._replace(mask=sim.observations.mask.at[:, :4].set(False))
    f = jax.jit(lambda k, o: mcl.run(k, state, config, params, sim.controls, o)[1].estimate)
    est = f(jax.random.PRNGKey(0), obs)
    assert np.all(np.isfinite(est))
    assert math.isfinite(float(np.linalg.norm(np.asarray(est[-1, :2] - sim.true_poses[-1, :2]))))
