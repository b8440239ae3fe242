"""Augmented MCL (Thrun et al. Tab. 8.3, [A] §2.1.3): kidnapped-robot recovery against plain MCL,
the w_slow/w_fast averages and injection in the log domain, validation, tracing, no NaN."""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.demo import demo_setting
from jaxnav.localization import augmented_mcl as am
from jaxnav.localization import mcl
from jaxnav.models import landmarks as lm
from jaxnav.sim import landmark_world as world
from jaxnav.sim import trajectories

START = jnp.asarray([5.0, 1.5, 0.0])
BOUNDS = jnp.asarray([0.0, 10.0, 0.0, 10.0])
T_KIDNAP = 120  # steps before the kidnap (w_slow has reached 1 - 0.98^120 = 91% of its level)
HORIZON = 30  # augmented MCL must have recovered this many steps after it
T_AFTER = 50  # steps simulated after the kidnap (170 in all)
SHIFT = jnp.asarray([0.0, 3.5, 0.0])  # the kidnap: 3.5 m north, no motion update reports it
# The filter's range-bearing noise is 3x the simulator's (0.1 m, 0.05 rad). With a
# correctly specified sensor, log w_avg = const − ½χ²₁₆ fluctuates with sd 2.8 from step
# to step, so w_fast/w_slow falls far below 1 in ordinary tracking and particles are
# injected all the time (Thrun et al. §8.3.5 discuss this); inflating σ by 3 divides
# that sd by 9. Both filters below get the same inflated model.
FILTER_SENSOR = lm.RangeBearingNoise(jnp.asarray([0.3, 0.15]))


def _params(n=1000, **config_kw):
    _, p = demo_setting(n)
    config = am.AugmentedMCLConfig(num_particles=n, **config_kw)
    params = am.AugmentedMCLParams(p.motion, FILTER_SENSOR, p.landmarks, BOUNDS)
    return config, params, p


def _kidnap_run(seed):
    """True path: T_KIDNAP steps of the demo circle, then a teleport by SHIFT, then T_AFTER steps.

    Both segments are simulated with the full control sequence (one compiled
    simulator) and cut to length.
    """
    _, p = demo_setting(10)
    k1, k2 = jax.random.split(jax.random.PRNGKey(seed))
    controls = trajectories.loop_controls(T_KIDNAP + T_AFTER, 0.5, 0.21, 0.25)
    before = world.simulate(k1, p.landmarks, START, controls, p.motion, p.sensor)
    kidnapped = before.true_poses[T_KIDNAP - 1] + SHIFT
    after = world.simulate(k2, p.landmarks, kidnapped, controls, p.motion, p.sensor)

    def splice(a, b):
        return jnp.concatenate([a[:T_KIDNAP], b[:T_AFTER]])

    truth = splice(before.true_poses, after.true_poses)
    obs = jax.tree_util.tree_map(splice, before.observations, after.observations)
    return controls, obs, truth


@functools.cache
def _runs(seed):
    """Augmented MCL and plain MCL (same seed, N = 1,000, same models) on the kidnap run."""
    config, params, p = _params(1000)
    controls, obs, truth = _kidnap_run(seed)
    k_init, k_run = jax.random.split(jax.random.PRNGKey(100 + seed))
    sd = jnp.asarray([0.3, 0.3, 0.1])
    state = am.init(k_init, config, params, START, sd)
    final, trace = am.run(k_run, state, config, params, controls, obs)
    mcl_config = mcl.MCLConfig(num_particles=1000)
    mcl_params = mcl.MCLParams(p.motion, FILTER_SENSOR, p.landmarks)
    mcl_state = mcl.init(k_init, mcl_config, mcl_params, START, sd)
    _, mtrace = mcl.run(k_run, mcl_state, mcl_config, mcl_params, controls, obs)
    return dict(
        config=config,
        params=params,
        controls=controls,
        obs=obs,
        truth=truth,
        key=k_run,
        state=state,
        final=final,
        trace=trace,
        mtrace=mtrace,
    )


@pytest.mark.parametrize("seed", [0, 1])
def test_kidnapped_robot_recovers_with_injection_and_plain_mcl_does_not(seed):
    """The kidnapped-robot problem ([A] §2.1.3): 1,000 particles, 8 landmarks all in view,
    default alphas (0.02, 0.2).

    Bound 0.2 m: the convergence bound of landmark MCL in this world
    (tests/localization/test_mcl.py, the demo); before the kidnap both filters track at
    < 0.13 m, and a lost filter is off by about the kidnap distance, 3.5 m.
    Horizon 30 steps (7.5 s): over seeds 0–7 recovery took 2–23 steps and the
    error in the window stayed below 0.18 m. Plain MCL can only creep back by
    hill-climbing on its motion noise (~5 cm/step); over the same seeds its
    error in the window stayed above 0.89 m. It is the negative control: same
    seed, same particle count, same models, no injection. Injected particles
    are not asserted to vanish after recovery: w_slow still remembers the
    better-tracked steps before the kidnap for ~1/α_slow steps.
    """
    r = _runs(seed)
    truth, trace, final = r["truth"], r["trace"], r["final"]
    err = np.linalg.norm(np.asarray(trace.estimate[:, :2] - truth[:, :2]), axis=1)
    merr = np.linalg.norm(np.asarray(r["mtrace"].estimate[:, :2] - truth[:, :2]), axis=1)
    for leaf in jax.tree_util.tree_leaves((final, trace.estimate, trace.ess, trace.injection_probability)):
        assert np.all(~np.isnan(np.asarray(leaf)))
    assert np.all(np.isfinite(np.asarray(final.particles))) and np.all(np.isfinite(np.asarray(trace.estimate)))
    # both track before the kidnap
    assert err[10:T_KIDNAP].max() < 0.2 and merr[10:T_KIDNAP].max() < 0.2
    # both are lost right after it (the kidnapped path stays inside the injection bounds)
    assert err[T_KIDNAP] > 1.0 and merr[T_KIDNAP] > 1.0
    assert np.all((np.asarray(truth[:, :2]) > 0.0) & (np.asarray(truth[:, :2]) < 10.0))
    window = slice(T_KIDNAP + HORIZON, T_KIDNAP + T_AFTER)
    assert err[window].max() < 0.2, err[window]
    assert merr[window].min() > 0.5, merr[window]
    # the kidnap triggered injection (measured: >= 4,000 particles in 10 steps, p ~ 0.5 at +3)
    assert int(np.asarray(trace.num_injected)[T_KIDNAP : T_KIDNAP + 10].sum()) > 1000
    assert float(trace.injection_probability[T_KIDNAP + 3]) > 0.3


def test_injection_probability_follows_thrun_averages_from_zero():
    """Tab. 8.3 lines 8–11 from w_slow = w_fast = 0: the reported p_inject equals the same
    recursion run in the linear domain (float64 NumPy) on the reported w_avg, over all
    170 steps of the kidnap run, where w_avg ranges over e^10 … e^-330."""
    r = _runs(0)
    config, trace = r["config"], r["trace"]
    assert r["state"].log_w_slow == -np.inf and r["state"].log_w_fast == -np.inf
    w_avg = np.exp(np.asarray(trace.log_likelihood, np.float64))
    assert w_avg.max() > 1e3 and 0.0 < w_avg.min() < 1e-100  # the range that needs the log domain
    slow = fast = 0.0
    expected = []
    for w in w_avg:
        slow += config.alpha_slow * (w - slow)
        fast += config.alpha_fast * (w - fast)
        expected.append(max(0.0, 1.0 - fast / slow))
    # float32 log-averages of size ~10 carry ~1e-6 relative error, so p to ~1e-5
    np.testing.assert_allclose(trace.injection_probability, expected, atol=1e-4)


def test_run_equals_a_loop_of_steps_with_fold_in_keys():
    """The first 10 steps of ``run`` and of a loop of ``step`` with ``fold_in(key, t)`` agree
    (to float32 round-off: the scan and the single step are compiled separately, so over
    many steps a resampling index may eventually flip)."""
    r = _runs(0)
    config, params, controls, obs = r["config"], r["params"], r["controls"], r["obs"]
    s = r["state"]
    for t in range(10):
        obs_t = jax.tree_util.tree_map(lambda x: x[t], obs)
        s, info = am.step(jax.random.fold_in(r["key"], t), s, config, params, controls[t], obs_t)
        assert int(info.num_injected) == int(r["trace"].num_injected[t])
        np.testing.assert_allclose(info.estimate, r["trace"].estimate[t], atol=1e-4)
        np.testing.assert_allclose(info.injection_probability, r["trace"].injection_probability[t], atol=1e-5)
        np.testing.assert_allclose(info.log_likelihood, r["trace"].log_likelihood[t], rtol=1e-4)


def _one_step_inputs():
    r = _runs(0)
    return r["config"], r["params"], r["controls"][0], jax.tree_util.tree_map(lambda x: x[0], r["obs"])


def test_update_average_and_injection_probability_edge_cases():
    ninf = -jnp.inf
    # alpha = 1 forgets the past entirely, even a zero (-inf) past
    assert float(am.update_average(jnp.asarray(3.0), jnp.asarray(-2.0), 1.0)) == -2.0
    assert float(am.update_average(jnp.asarray(ninf), jnp.asarray(-2.0), 1.0)) == -2.0
    # a zero-likelihood step (degenerate) only decays the average, no NaN
    np.testing.assert_allclose(
        am.update_average(jnp.asarray(5.0), jnp.asarray(ninf), 0.5), 5.0 + math.log(0.5), rtol=1e-6
    )
    assert float(am.update_average(jnp.asarray(ninf), jnp.asarray(ninf), 0.5)) == -np.inf
    p = am.injection_probability
    assert float(p(jnp.asarray(ninf), jnp.asarray(ninf))) == 0.0  # w_slow = 0: nothing yet
    assert float(p(jnp.asarray(ninf), jnp.asarray(7.0))) == 0.0
    assert float(p(jnp.asarray(1.0), jnp.asarray(2.0))) == 0.0  # w_fast > w_slow
    np.testing.assert_allclose(p(jnp.asarray(1.0), jnp.asarray(1.0 - math.log(2.0))), 0.5, rtol=1e-6)
    assert float(p(jnp.asarray(1.0), jnp.asarray(ninf))) == 1.0
    assert float(p(jnp.asarray(20.0), jnp.asarray(-3000.0))) == 1.0  # after a kidnap, no overflow


def test_injected_particles_are_uniform_in_the_bounds():
    """With w_slow = e^100 far above this step's w_avg ≈ e^9 (and w_fast = 0), p_inject
    rounds to 1 and every particle is replaced: the set must lie in the bounds and be
    uniform there: means of x, y, θ within 4 standard errors of the centre."""
    config, params, control, obs = _one_step_inputs()
    n = config.num_particles
    params = params._replace(bounds=jnp.asarray([-2.0, 6.0, 1.0, 3.0]))
    state = am.init(jax.random.PRNGKey(0), config, params, START, jnp.full((3,), 0.1))
    state = state._replace(log_w_slow=jnp.float32(100.0), log_w_fast=jnp.float32(-jnp.inf))
    new, info = am.step(jax.random.PRNGKey(1), state, config, params, control, obs)
    assert float(info.injection_probability) == 1.0 and int(info.num_injected) == n
    x, y, th = (np.asarray(new.particles[:, i]) for i in range(3))
    assert x.min() >= -2.0 and x.max() <= 6.0 and y.min() >= 1.0 and y.max() <= 3.0
    assert th.min() >= -np.pi and th.max() < np.pi
    for v, lo, hi in ((x, -2.0, 6.0), (y, 1.0, 3.0), (th, -np.pi, np.pi)):
        se = (hi - lo) / math.sqrt(12.0 * n)
        assert abs(v.mean() - 0.5 * (lo + hi)) < 4 * se
    np.testing.assert_allclose(np.exp(np.asarray(new.log_weights)), 1.0 / n, rtol=1e-5)
    # negative control: w_fast >= w_slow injects nothing
    state = state._replace(log_w_slow=jnp.float32(1.0), log_w_fast=jnp.float32(50.0))
    _, info = am.step(jax.random.PRNGKey(1), state, config, params, control, obs)
    assert float(info.injection_probability) == 0.0 and int(info.num_injected) == 0


def test_degenerate_step_is_flagged_raises_injection_and_never_nan():
    """A step with zero likelihood everywhere (w_avg = 0) only decays both averages, so from
    w_slow = w_fast it gives p_inject = 1 − (1 − α_fast)/(1 − α_slow) exactly (0.18 here)."""
    config, params, control, obs = _one_step_inputs()
    # a NaN control moves every particle to NaN: zero weight everywhere (refused on the host, so
    # passed inside a caller's jit)
    bad = control.at[0].set(jnp.nan)
    state = am.init(jax.random.PRNGKey(0), config, params, START, jnp.full((3,), 0.1))
    state = state._replace(log_w_slow=jnp.float32(8.0), log_w_fast=jnp.float32(8.0))
    new, info = jax.jit(lambda u: am.step(jax.random.PRNGKey(1), state, config, params, u, obs))(bad)
    assert bool(info.degenerate) and info.log_likelihood == -np.inf
    expected = 1.0 - (1.0 - config.alpha_fast) / (1.0 - config.alpha_slow)
    np.testing.assert_allclose(info.injection_probability, expected, rtol=1e-5)
    # Binomial(1000, 0.184): mean 184, sd 12
    assert 184 - 5 * 12 < int(info.num_injected) < 184 + 5 * 12
    for leaf in jax.tree_util.tree_leaves((new, info.estimate, info.ess)):
        assert np.all(np.isfinite(np.asarray(leaf)))


def test_no_retrace_between_calls_with_the_same_shapes():
    """``run`` traces the step exactly once per (config, shapes); new data, keys and params reuse it."""
    before = am.run.trace_count()
    r0, r1 = _runs(0), _runs(1)
    config, params = _params(41)[:2]  # a config no other test compiled
    cut = lambda x: x[:5]  # noqa: E731
    state = am.init(jax.random.PRNGKey(0), config, params, START, jnp.full((3,), 0.1))
    am.run(jax.random.PRNGKey(0), state, config, params, r0["controls"][:5], jax.tree_util.tree_map(cut, r0["obs"]))
    assert am.run.trace_count() == before + 1  # scan traces its body once
    params2 = params._replace(
        bounds=jnp.asarray([1.0, 9.0, 1.0, 9.0]), sensor=lm.RangeBearingNoise(jnp.asarray([0.2, 0.1]))
    )
    state2 = state._replace(log_w_slow=jnp.float32(3.0), log_w_fast=jnp.float32(2.0))  # strong float32, as init gives
    obs2 = jax.tree_util.tree_map(lambda x: x[5:10], r1["obs"])
    am.run(jax.random.PRNGKey(1), state2, config, params2, r1["controls"][5:10], obs2)
    assert am.run.trace_count() == before + 1


def test_init_uniform_uses_params_bounds_by_default():
    config, params, _ = _params(500)
    params = params._replace(bounds=jnp.asarray([2.0, 3.0, -1.0, 0.0]))
    s = am.init_uniform(jax.random.PRNGKey(0), config, params)
    p = np.asarray(s.particles)
    assert p[:, 0].min() >= 2.0 and p[:, 0].max() <= 3.0 and p[:, 1].min() >= -1.0 and p[:, 1].max() <= 0.0
    assert s.log_w_slow == -np.inf and s.log_w_fast == -np.inf
    s2 = am.init_uniform(jax.random.PRNGKey(0), config, params, (0.0, 1.0, 0.0, 1.0))
    assert np.asarray(s2.particles)[:, 0].max() <= 1.0


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"alpha_slow": 0.5, "alpha_fast": 0.1}, "0 < alpha_slow < alpha_fast <= 1"),
        ({"alpha_slow": 0.2, "alpha_fast": 0.2}, "0 < alpha_slow < alpha_fast <= 1"),
        ({"alpha_slow": 0.0, "alpha_fast": 0.1}, "0 < alpha_slow < alpha_fast <= 1"),
        ({"alpha_slow": -0.1, "alpha_fast": 0.1}, "0 < alpha_slow < alpha_fast <= 1"),
        ({"alpha_slow": 0.1, "alpha_fast": 1.5}, "0 < alpha_slow < alpha_fast <= 1"),
        ({"alpha_slow": float("nan"), "alpha_fast": 0.5}, "0 < alpha_slow < alpha_fast <= 1"),
        ({"alpha_slow": "0.1"}, "alpha_slow must be a real number"),
        ({"num_particles": 0}, "num_particles must be a positive integer"),
        ({"resampling": "bogus"}, "resampling must be one of"),
        ({"motion_model": "warp"}, "motion_model must be one of"),
    ],
)
def test_bad_config_is_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        am.AugmentedMCLConfig(**kwargs)


def test_alpha_fast_equal_one_is_allowed():
    assert am.AugmentedMCLConfig(alpha_slow=0.01, alpha_fast=1.0).alpha_fast == 1.0


def test_bad_params_and_state_are_refused_with_the_argument_named():
    config, params, _ = _params(50)
    controls, obs = _runs(0)["controls"][:3], jax.tree_util.tree_map(lambda x: x[:3], _runs(0)["obs"])
    key = jax.random.PRNGKey(0)
    state = am.init(key, config, params, START)
    with pytest.raises(ValueError, match="x_min < x_max"):
        am.run(key, state, config, params._replace(bounds=jnp.asarray([1.0, 0.0, 0.0, 1.0])), controls, obs)
    with pytest.raises(ValueError, match=r"params.bounds must have shape \(4\)"):
        am.run(key, state, config, params._replace(bounds=jnp.zeros(3)), controls, obs)
    with pytest.raises(ValueError, match="params.bounds contains NaN"):
        am.init_uniform(key, config, params._replace(bounds=jnp.asarray([0.0, jnp.nan, 0.0, 1.0])))
    with pytest.raises(ValueError, match="params must be an AugmentedMCLParams"):
        am.run(key, state, config, mcl.MCLParams(params.motion, params.sensor, params.landmarks), controls, obs)
    with pytest.raises(ValueError, match=r"state.log_w_slow must have shape \(\)"):
        am.run(key, state._replace(log_w_slow=jnp.zeros(2)), config, params, controls, obs)
    with pytest.raises(ValueError, match=r"state.particles must have shape \(50, 3\)"):
        am.run(key, state._replace(particles=state.particles[:3]), config, params, controls, obs)
    with pytest.raises(ValueError, match="params.sensor.sd must be finite and strictly positive"):
        am.run(
            key, state, config, params._replace(sensor=lm.RangeBearingNoise(jnp.asarray([0.1, -1.0]))), controls, obs
        )
    with pytest.raises(ValueError, match="same number of steps"):
        am.run(key, state, config, params, controls[:2], obs)
