"""KLD-sampling MCL (Fox 2001; Thrun et al. Tab. 8.4) in fixed shapes: the adaptive count on a
global-localization run, inactive slots never used, Fox's stopping rule, the χ² bound, tracing."""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from jaxnav.demo import demo_setting
from jaxnav.localization import kld_mcl as kld
from jaxnav.localization import mcl
from jaxnav.models import landmarks as lm
from jaxnav.sim import landmark_world as world
from jaxnav.sim import trajectories

START = jnp.asarray([5.0, 1.5, 0.0])
N_MAX = 3000
N_MIN = 100
DARK = 5  # the sensor reports nothing during the first DARK steps
STEPS = 60
# A sensor 3x noisier than the demo's, in the simulator and the filter alike: with the
# demo's (0.1 m, 0.05 rad) the first posterior is ~1/10,000 of the room's pose volume and
# global localization needs ~20,000 particles (tests/localization/test_mcl.py), not a few thousand.
SENSOR = lm.RangeBearingNoise(jnp.asarray([0.3, 0.15]))


def _setting(n_max=N_MAX, **kw):
    _, p = demo_setting(10)
    config = kld.KLDMCLConfig(max_particles=n_max, min_particles=kw.pop("min_particles", N_MIN), **kw)
    params = kld.KLDMCLParams(p.motion, SENSOR, p.landmarks)
    return config, params


@functools.cache
def _global_run(seed):
    """Global localization in the demo's 10 m room (8 landmarks), uniform start, dark first steps."""
    config, params = _setting()
    k_sim, k_init, k_run = jax.random.split(jax.random.PRNGKey(seed), 3)
    controls = trajectories.loop_controls(STEPS, 0.5, 0.21, 0.25)
    sim = world.simulate(k_sim, params.landmarks, START, controls, params.motion, SENSOR)
    obs = sim.observations._replace(mask=sim.observations.mask.at[:DARK].set(False))
    state = kld.init_uniform(k_init, config, params, (0.0, 10.0, 0.0, 10.0))
    final, trace = kld.run(k_run, state, config, params, controls, obs)
    return dict(
        config=config,
        params=params,
        controls=controls,
        obs=obs,
        truth=sim.true_poses,
        state=state,
        final=final,
        trace=trace,
        key=k_run,
    )


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_global_localization_count_adapts_and_estimate_converges(seed):
    """Uniform start with N_max = 3,000: while the belief is uniform (no detections) the bound
    asks for more than N_max (the candidates fill ~1,850 of the 57,600 bins), so n_t = N_max;
    once converged the posterior spans a few 0.25 m × 0.25 m × 10° bins (k ≤ ~10, so
    n_χ ≤ ~220) and n_t ≤ 0.1·N_max. Error bound 0.2 m over the last 20 steps: the
    convergence bound of landmark MCL in this world (tests/localization/test_mcl.py); over
    seeds 0–4 the measured maximum was 0.15 m and the largest converged count 186."""
    r = _global_run(seed)
    trace, truth = r["trace"], r["truth"]
    n = np.asarray(trace.num_active)
    assert int(r["state"].num_active) == N_MAX
    assert np.all(n[:DARK] == N_MAX)
    assert np.all(np.asarray(trace.num_bins[:DARK]) > 1000)
    assert n[-20:].max() <= 0.1 * N_MAX, n[-20:]
    assert np.all((n >= N_MIN) & (n <= N_MAX))
    err = np.linalg.norm(np.asarray(trace.estimate[:, :2] - truth[:, :2]), axis=1)
    assert err[:DARK].min() > 1.0  # the uniform belief's mean is nowhere near the robot
    assert err[-20:].max() < 0.2, err[-20:]
    # every count meets the bound it was chosen by (or is capped at N_max)
    bound = np.asarray(kld.kld_bound(trace.num_bins, r["config"].epsilon, r["config"].delta))
    assert np.all((n >= np.ceil(bound - 1e-3)) | (n == N_MAX))
    # ESS counts only active particles: never above the previous step's count
    prev = np.concatenate([[N_MAX], n[:-1]])
    assert np.all(np.asarray(trace.ess) <= prev * (1 + 1e-5))
    assert np.all(np.isfinite(np.asarray(trace.estimate)))


def test_inactive_slots_never_affect_anything():
    """Garbage in the inactive slots — NaN and huge poses, finite and +inf log-weights —
    gives bit-for-bit the same step as clean inactive slots (same key)."""
    r = _global_run(0)
    config, params, state = r["config"], r["params"], r["final"]
    n = int(state.num_active)
    assert n < N_MAX // 2
    inactive = ~np.asarray(state.active)
    garbage_p = np.asarray(state.particles).copy()
    garbage_p[inactive] = np.nan
    garbage_p[np.flatnonzero(inactive)[::2]] = 1e30
    garbage_w = np.asarray(state.log_weights).copy()
    garbage_w[inactive] = 0.0
    garbage_w[np.flatnonzero(inactive)[::3]] = np.inf
    dirty = state._replace(particles=jnp.asarray(garbage_p), log_weights=jnp.asarray(garbage_w))
    t = STEPS - 1
    control, obs = r["controls"][t], jax.tree_util.tree_map(lambda x: x[t], r["obs"])
    key = jax.random.PRNGKey(42)
    clean_state, clean_info = kld.step(key, state, config, params, control, obs)
    dirty_state, dirty_info = kld.step(key, dirty, config, params, control, obs)
    for a, b in zip(
        jax.tree_util.tree_leaves((clean_state, clean_info)), jax.tree_util.tree_leaves((dirty_state, dirty_info))
    ):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert np.all(np.isfinite(np.asarray(clean_info.estimate)))
    assert float(clean_info.ess) <= n
    # negative control: the same garbage inside an *active* slot does change the estimate
    poisoned = state._replace(particles=state.particles.at[0].set(jnp.asarray([1e3, 1e3, 0.0])))
    _, bad_info = kld.step(key, poisoned, config, params, control, obs)
    assert not np.array_equal(np.asarray(bad_info.estimate), np.asarray(clean_info.estimate))


def _fox_sequential_count(bins, epsilon, delta, n_min):
    """Thrun et al. Tab. 8.4's loop, sample by sample: k counts new bins, M_χ is updated when
    k > 1 (Wilson–Hilferty form, as Tab. 8.4 line 13), stop when M ≥ M_χ and M ≥ M_χmin."""
    z = stats.norm.ppf(1.0 - delta)
    seen, m_chi = set(), 0.0
    for m, b in enumerate(bins, start=1):
        if b not in seen:
            seen.add(b)
            k = len(seen)
            if k > 1:
                a = 2.0 / (9.0 * (k - 1))
                m_chi = (k - 1) / (2.0 * epsilon) * (1.0 - a + math.sqrt(a) * z) ** 3
        if m >= m_chi and m >= n_min:
            return m, len(seen)
    return len(bins), len(seen)


@pytest.mark.parametrize("spread", [0.001, 0.1, 0.5, 20.0])
def test_count_is_foxs_stopping_rule_on_the_candidate_sequence(spread):
    """The fixed-shape prefix count equals Fox's sequential loop on the same candidate order,
    from a tight cluster (k small, n = n_min) to a spread-out set (capped at N_max)."""
    config = kld.KLDMCLConfig(max_particles=2000, min_particles=50)
    rng = np.random.default_rng(int(spread * 1000))
    poses = np.column_stack(
        [
            3.1 + spread * rng.standard_normal(2000),
            -0.9 + spread * rng.standard_normal(2000),
            np.pi - 0.2 + spread * rng.standard_normal(2000),  # straddles ±π
        ]
    ).astype(np.float32)
    k_prefix = jax.jit(kld.occupied_bins_per_prefix, static_argnums=1)(jnp.asarray(poses), config.bin_size)
    n = int(kld.choose_count(k_prefix, config, jnp.float32))
    th = (poses[:, 2] + np.pi) % (2 * np.pi)  # bins on [-π, π) anchored at -π, as the filter
    cells = np.floor(np.column_stack([poses[:, 0] / 0.25, poses[:, 1] / 0.25, th / config.bin_size[2]]))
    bins = [tuple(b) for b in cells.astype(int)]
    want_k = np.cumsum([b not in set(bins[:i]) for i, b in enumerate(bins)])
    np.testing.assert_array_equal(np.asarray(k_prefix), want_k)
    want_n, _ = _fox_sequential_count(bins, config.epsilon, config.delta, config.min_particles)
    assert n == want_n
    if spread == 20.0:
        assert n == 2000
    if spread == 0.001:  # one bin: n_χ(1) = 0, so the minimum decides
        assert n == 50 and int(k_prefix[-1]) == 1


@pytest.mark.parametrize("delta", [0.001, 0.01, 0.05, 0.1, 0.5])
@pytest.mark.parametrize("epsilon", [0.01, 0.05, 0.25])
def test_bound_matches_the_chi_square_quantile(delta, epsilon):
    """n_χ(k) against scipy's χ²_{k−1}(1−δ)/(2ε) for k = 2…5,000 in float64.

    Tolerance |n/n_ref − 1| ≤ 0.1/(k − 1): the Wilson–Hilferty cube-root approximation's
    relative error falls like 1/(k − 1); measured max (k − 1)·|rel. error| = 0.059 over
    δ ∈ [0.001, 0.5] (worst at k = 2, δ = 0.001: 3%; at k ≥ 101 below 4e-4).
    Negative control: the plain normal approximation (k−1 + z√(2(k−1)))/(2ε) fails it."""
    ks = np.arange(2, 5001)
    ref = stats.chi2.ppf(1.0 - delta, ks - 1) / (2.0 * epsilon)
    tol = 0.1 / (ks - 1)
    with jax.enable_x64(True):
        got = np.asarray(kld.kld_bound(jnp.asarray(ks), epsilon, delta))
        assert got.dtype == np.float64
        np.testing.assert_array_equal(np.asarray(kld.kld_bound(jnp.asarray([-3, 0, 1]), epsilon, delta)), 0.0)
    assert np.all(np.abs(got / ref - 1.0) <= tol)
    got32 = np.asarray(kld.kld_bound(jnp.asarray(ks, jnp.int32), epsilon, delta))
    assert got32.dtype == np.float32
    np.testing.assert_allclose(got32, got, rtol=2e-5)
    z = stats.norm.ppf(1.0 - delta)
    normal = (ks - 1 + z * np.sqrt(2.0 * (ks - 1))) / (2.0 * epsilon)
    if delta < 0.5:  # at δ = 0.5 both are the median and the normal form is close too
        assert np.any(np.abs(normal / ref - 1.0) > tol)


def test_degenerate_step_resets_only_active_weights_and_never_nan():
    r = _global_run(0)
    config, params, state = r["config"], r["params"], r["final"]
    t = STEPS - 1
    obs = jax.tree_util.tree_map(lambda x: x[t], r["obs"])
    # a NaN control moves every particle to NaN: zero weight everywhere (refused on the host, so
    # passed inside a caller's jit)
    bad = r["controls"][t].at[0].set(jnp.nan)
    new, info = jax.jit(lambda u: kld.step(jax.random.PRNGKey(0), state, config, params, u, obs))(bad)
    assert bool(info.degenerate) and info.log_likelihood == -np.inf
    # uniform over the n_{t-1} active particles only; a degenerate step reports ESS 0 (weights.step_ess)
    assert float(info.ess) == 0.0
    n = int(new.num_active)
    lw = np.asarray(new.log_weights)
    np.testing.assert_allclose(lw[:n], -np.log(n), rtol=1e-6)
    assert np.all(lw[n:] == -np.inf)
    assert np.all(np.isfinite(np.asarray(new.particles))) and np.all(np.isfinite(np.asarray(info.estimate)))


def test_run_equals_a_loop_of_steps_with_fold_in_keys():
    """The first 8 steps (dark steps and the first detections) of ``run`` and of ``step``."""
    r = _global_run(0)
    s = r["state"]
    for t in range(8):
        obs_t = jax.tree_util.tree_map(lambda x: x[t], r["obs"])
        s, info = kld.step(jax.random.fold_in(r["key"], t), s, r["config"], r["params"], r["controls"][t], obs_t)
        assert int(info.num_active) == int(r["trace"].num_active[t])
        assert int(info.num_bins) == int(r["trace"].num_bins[t])
        np.testing.assert_allclose(info.estimate, r["trace"].estimate[t], atol=1e-4)


def test_no_retrace_between_calls_with_the_same_shapes():
    """``run`` traces the step once per (config, shapes); new data, keys, params and a
    different starting count reuse the compiled scan."""
    before = kld.run.trace_count()
    r0, r1 = _global_run(0), _global_run(1)
    config, params = _setting(n_max=211, min_particles=20)  # a config no other test compiled
    cut = lambda x: x[:6]  # noqa: E731
    state = kld.init_uniform(jax.random.PRNGKey(0), config, params, (0.0, 10.0, 0.0, 10.0))
    kld.run(jax.random.PRNGKey(0), state, config, params, r0["controls"][:6], jax.tree_util.tree_map(cut, r0["obs"]))
    assert kld.run.trace_count() == before + 1
    params2 = params._replace(sensor=lm.RangeBearingNoise(jnp.asarray([0.2, 0.1])))
    state2 = kld.init(jax.random.PRNGKey(1), config, params2, START, jnp.full((3,), 0.2))._replace(
        num_active=jnp.int32(50)
    )
    kld.run(jax.random.PRNGKey(1), state2, config, params2, r1["controls"][:6], jax.tree_util.tree_map(cut, r1["obs"]))
    assert kld.run.trace_count() == before + 1


def test_active_mask_property():
    s = kld.KLDMCLState(jnp.zeros((5, 3)), jnp.zeros(5), jnp.int32(2))
    np.testing.assert_array_equal(s.active, [True, True, False, False, False])
    batched = kld.KLDMCLState(jnp.zeros((2, 5, 3)), jnp.zeros((2, 5)), jnp.asarray([1, 4], jnp.int32))
    np.testing.assert_array_equal(batched.active.sum(axis=1), [1, 4])


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"max_particles": 0}, "max_particles must be a positive integer"),
        ({"min_particles": 0}, "min_particles must be a positive integer"),
        ({"max_particles": 100, "min_particles": 200}, "min_particles must be <= max_particles"),
        ({"epsilon": 0.0}, "epsilon must be finite and > 0"),
        ({"epsilon": float("inf")}, "epsilon must be finite and > 0"),
        ({"delta": 0.0}, r"delta must be in \(0, 1\)"),
        ({"delta": 1.0}, r"delta must be in \(0, 1\)"),
        ({"delta": "0.01"}, "delta must be a real number"),
        ({"bin_size": (0.25, 0.25)}, "bin_size must be a tuple"),
        ({"bin_size": [0.25, 0.25, 0.2]}, "bin_size must be a tuple"),
        ({"bin_size": (0.25, 0.0, 0.2)}, "bin_size entries must be finite and > 0"),
        ({"motion_model": "warp"}, "motion_model must be one of"),
    ],
)
def test_bad_config_is_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        kld.KLDMCLConfig(**kwargs)


def test_bad_state_and_params_are_refused_with_the_argument_named():
    config, params = _setting(n_max=64, min_particles=8)
    r = _global_run(0)
    controls, obs = r["controls"][:3], jax.tree_util.tree_map(lambda x: x[:3], r["obs"])
    key = jax.random.PRNGKey(0)
    state = kld.init(key, config, params, START)
    run = lambda s=state, p=params: kld.run(key, s, config, p, controls, obs)  # noqa: E731
    with pytest.raises(ValueError, match=r"state.num_active must be in \[1, 64\]"):
        run(s=state._replace(num_active=jnp.int32(0)))
    with pytest.raises(ValueError, match=r"state.num_active must be in \[1, 64\]"):
        run(s=state._replace(num_active=jnp.int32(65)))
    with pytest.raises(ValueError, match=r"state.num_active must have shape \(\)"):
        run(s=state._replace(num_active=jnp.ones(2, jnp.int32)))
    with pytest.raises(ValueError, match=r"state.particles must have shape \(64, 3\)"):
        run(s=state._replace(particles=state.particles[:3]))
    with pytest.raises(ValueError, match="state must be a KLDMCLState"):
        run(s=mcl.MCLState(state.particles, state.log_weights))
    with pytest.raises(ValueError, match="params.sensor.sd must be finite and strictly positive"):
        run(p=params._replace(sensor=lm.RangeBearingNoise(jnp.asarray([0.0, 0.1]))))
    with pytest.raises(ValueError, match="bounds must satisfy"):
        kld.init_uniform(key, config, params, (0.0, 1.0, 2.0, 1.0))
