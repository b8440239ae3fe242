"""The filter skeleton (jaxnav.core.filter): one argument order, validation once per value,
compiled once per shapes, donation, keys, and the pure kernel and scan."""

from __future__ import annotations

import inspect
from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.core import filter as filter_api
from jaxnav.core.validation import is_concrete
from jaxnav.localization import ekf, grid, mcl, rfid_tag, ukf
from jaxnav.slam import ekf_slam, fastslam, pf_slam, ps_slam


@dataclass(frozen=True)
class WalkConfig:
    num_particles: int = 8


class WalkParams(NamedTuple):
    sd: jax.Array


class WalkState(NamedTuple):
    particles: jax.Array


def walk_kernel(key, state, config, params, control, observation):
    """A random walk pulled toward the observation: enough to exercise the skeleton."""
    noise = jax.random.normal(key, state.particles.shape) * params.sd
    particles = state.particles + control + noise + 0.5 * (observation - state.particles)
    return WalkState(particles), jnp.mean(particles)


def _walk(deterministic=False, donate_step=False):
    calls = []

    def check_params(config, params):
        calls.append(params)
        if is_concrete(params.sd) and np.any(np.asarray(params.sd) < 0):
            raise ValueError("params.sd must be ≥ 0")

    def kernel(key, state, config, params, control, observation):
        if deterministic:
            key = jax.random.PRNGKey(0)  # ignores the key it is given
        return walk_kernel(key, state, config, params, control, observation)

    spec = filter_api.FilterSpec(
        name="walk",
        kernel=kernel,
        config_type=WalkConfig,
        check_params=check_params,
        deterministic=deterministic,
        donate_step=donate_step,
    )
    step, run = filter_api.build(spec, __name__)
    return step, run, calls


CONFIG = WalkConfig()
STATE = WalkState(jnp.zeros(8))
CONTROLS = jnp.linspace(0.0, 1.0, 5)
OBS = jnp.linspace(1.0, 2.0, 5)


def test_run_equals_a_loop_of_steps_with_fold_in_keys_and_the_pure_scan():
    step, run, _ = _walk()
    key = jax.random.PRNGKey(3)
    params = WalkParams(jnp.asarray(0.1))
    final, trace = run(key, STATE, CONFIG, params, CONTROLS, OBS)
    state = STATE
    for t in range(5):
        state, info = step(jax.random.fold_in(key, t), state, CONFIG, params, CONTROLS[t], OBS[t])
        assert float(info) == float(trace[t])
    np.testing.assert_array_equal(state.particles, final.particles)
    pure_final, pure_trace = jax.jit(lambda k: filter_api.scan(walk_kernel, k, STATE, CONFIG, params, CONTROLS, OBS))(
        key
    )
    np.testing.assert_array_equal(pure_final.particles, final.particles)
    np.testing.assert_array_equal(pure_trace, trace)


def test_params_are_checked_once_per_value_not_per_object():
    step, _, calls = _walk()
    key = jax.random.PRNGKey(0)
    for _ in range(3):  # an online loop: new objects, same values
        step(key, STATE, CONFIG, WalkParams(jnp.asarray(0.1)), 0.0, 1.0)
    assert len(calls) == 1
    step(key, STATE, CONFIG, WalkParams(jnp.asarray(0.2)), 0.0, 1.0)  # new values: checked
    assert len(calls) == 2
    with pytest.raises(ValueError, match="params.sd has dtype float16"):  # new dtype: checked (and refused)
        step(key, STATE, CONFIG, WalkParams(jnp.asarray(0.2, jnp.float16)), 0.0, 1.0)
    assert len(calls) == 3
    with pytest.raises(ValueError, match="params.sd"):
        step(key, STATE, CONFIG, WalkParams(jnp.asarray(-1.0)), 0.0, 1.0)


def test_numpy_params_changed_in_place_are_checked_again():
    step, _, calls = _walk()
    sd = np.asarray(0.1, np.float32)
    params = WalkParams(sd)
    step(jax.random.PRNGKey(0), STATE, CONFIG, params, 0.0, 1.0)
    step(jax.random.PRNGKey(0), STATE, CONFIG, params, 0.0, 1.0)
    assert len(calls) == 1
    sd[...] = -1.0  # the same object, now invalid
    with pytest.raises(ValueError, match="params.sd"):
        step(jax.random.PRNGKey(0), STATE, CONFIG, params, 0.0, 1.0)


def test_params_under_a_callers_jit_are_checked_at_every_trace_with_unknown_values():
    step, _, calls = _walk()

    @jax.jit
    def f(sd):
        return step(jax.random.PRNGKey(0), STATE, CONFIG, WalkParams(sd), 0.0, 1.0)[1]

    f(jnp.asarray(0.1))
    f(jnp.asarray(0.3))  # same shapes: no retrace, no check
    assert len(calls) == 1
    assert isinstance(calls[0].sd, jax.core.Tracer)


def test_compiled_once_per_config_and_shapes():
    step, run, _ = _walk()
    params = WalkParams(jnp.asarray(0.1))
    run(jax.random.PRNGKey(0), STATE, CONFIG, params, CONTROLS, OBS)
    assert run.trace_count() == 1
    run(jax.random.PRNGKey(1), WalkState(jnp.ones(8)), CONFIG, WalkParams(jnp.asarray(0.5)), CONTROLS + 1, OBS)
    assert run.trace_count() == 1
    run(jax.random.PRNGKey(1), STATE, WalkConfig(num_particles=9), params, CONTROLS, OBS)  # a new config
    assert run.trace_count() == 2
    step(jax.random.PRNGKey(0), STATE, CONFIG, params, 0.0, 1.0)
    step(jax.random.PRNGKey(5), STATE, CONFIG, WalkParams(jnp.asarray(0.7)), 1.0, 2.0)
    assert step.trace_count() == 1


def test_keys_are_checked_and_deterministic_filters_accept_none():
    step, run, _ = _walk()
    params = WalkParams(jnp.asarray(0.1))
    with pytest.raises(ValueError, match="key must be a PRNG key"):
        step(None, STATE, CONFIG, params, 0.0, 1.0)
    for bad in (jnp.zeros(2, jnp.int32), jnp.zeros(3, jnp.uint32), 7, jax.random.split(jax.random.PRNGKey(0), 2)):
        with pytest.raises(ValueError, match="key must be one PRNG key"):
            run(bad, STATE, CONFIG, params, CONTROLS, OBS)
    step(jax.random.key(1), STATE, CONFIG, params, 0.0, 1.0)  # a typed key is a key
    det_step, det_run, _ = _walk(deterministic=True)
    a = det_run(None, STATE, CONFIG, params, CONTROLS, OBS)
    b = det_run(jax.random.PRNGKey(9), STATE, CONFIG, params, CONTROLS, OBS)
    np.testing.assert_array_equal(a[1], b[1])


def test_config_of_the_wrong_type_is_refused_by_name():
    step, _, _ = _walk()
    with pytest.raises(ValueError, match="config must be a WalkConfig, got MCLConfig"):
        step(jax.random.PRNGKey(0), STATE, mcl.MCLConfig(), WalkParams(jnp.asarray(0.1)), 0.0, 1.0)


def test_donated_step_and_run_reuse_the_state_buffers():
    step, run, _ = _walk(donate_step=True)
    params = WalkParams(jnp.asarray(0.1))
    state = WalkState(jnp.zeros(8))
    step(jax.random.PRNGKey(0), state, CONFIG, params, 0.0, 1.0)
    assert state.particles.is_deleted()
    state = WalkState(jnp.zeros(8))
    run(jax.random.PRNGKey(0), state, CONFIG, params, CONTROLS, OBS)
    assert not state.particles.is_deleted()  # run copies unless told
    run(jax.random.PRNGKey(0), state, CONFIG, params, CONTROLS, OBS, donate_state=True)
    assert state.particles.is_deleted()


def test_arguments_by_keyword_and_a_readable_signature():
    step, run, _ = _walk()
    params = WalkParams(jnp.asarray(0.1))
    a = run(jax.random.PRNGKey(0), STATE, CONFIG, params, CONTROLS, OBS)
    b = run(key=jax.random.PRNGKey(0), state=STATE, config=CONFIG, params=params, control=CONTROLS, observation=OBS)
    np.testing.assert_array_equal(a[1], b[1])
    with pytest.raises(TypeError):
        run(jax.random.PRNGKey(0), CONFIG, params, CONTROLS, OBS)  # the state is missing
    assert list(inspect.signature(run).parameters)[:4] == ["key", "state", "config", "params"]


@pytest.mark.parametrize(
    "module", [mcl, ekf, ukf, grid, rfid_tag, ekf_slam, fastslam, pf_slam, ps_slam], ids=lambda m: m.__name__
)
def test_every_filter_has_one_argument_order_and_a_public_kernel(module):
    for fn in (module.step, module.run, module.kernel):
        names = list(inspect.signature(fn).parameters)
        assert names[:4] == ["key", "state", "config", "params"], (fn, names)
    assert "donate_state" in inspect.signature(module.run).parameters
    assert module.step.__doc__ and module.run.__doc__ and module.kernel.__doc__


@pytest.mark.parametrize("size", [1000, (1 << 20) + 1000])  # checked with NumPy, and on the device
def test_state_values_are_checked_with_the_field_and_the_first_bad_index(size):
    class State(NamedTuple):
        particles: jax.Array
        log_weights: jax.Array

    n = size // 2
    good = State(jnp.zeros((n, 2)), jnp.full((n,), -jnp.inf).at[0].set(0.0))
    filter_api.check_state_arrays(good)  # -inf is a weight of zero in a log-domain field
    for value, what in ((jnp.nan, "NaN or infinite"), (jnp.inf, "NaN or infinite"), (2e6, "exceed 1e\\+06")):
        bad = good._replace(particles=good.particles.at[n - 1, 1].set(value))
        with pytest.raises(ValueError, match=rf"state.particles .*{what}.* index \({n - 1}, 1\)"):
            filter_api.check_state_arrays(bad)
    with pytest.raises(ValueError, match=r"state.log_weights holds 1 NaN or infinite value\(s\), the first \(inf\)"):
        filter_api.check_state_arrays(good._replace(log_weights=good.log_weights.at[3].set(jnp.inf)))


def test_is_concrete_tells_values_from_tracers_and_check_real_refuses_complex_dtypes():
    """The host checks' two shared tests, whose fast paths read the exact type and the dtype's kind."""
    from jaxnav.core.validation import check_real

    seen = []
    for x in (np.ones(3), jnp.ones(3), (jnp.ones(2), np.zeros(1)), 1.5, np.float32(2.0)):
        assert is_concrete(x)
    jax.jit(lambda x: seen.append((is_concrete(x), is_concrete((jnp.ones(2), x)))) or x)(jnp.ones(3))
    jax.vmap(lambda x: seen.append((is_concrete(x), is_concrete({"a": x}))) or x)(jnp.ones((2, 3)))
    assert seen == [(False, False), (False, False)]
    for dtype in (np.complex64, np.complex128, jnp.complex64):
        with pytest.raises(ValueError, match="must hold real numbers, got dtype complex"):
            check_real("x", np.zeros(2, dtype))
    with jax.enable_x64(True), pytest.raises(ValueError, match="complex128"):
        check_real("x", jnp.zeros(2, jnp.complex128))
    for dtype in (jnp.bfloat16, np.float16, np.float32, np.int8, np.bool_):
        check_real("x", np.zeros(2, dtype))
    check_real("key", jax.random.key(0))  # a key dtype, which NumPy cannot read, is not complex
