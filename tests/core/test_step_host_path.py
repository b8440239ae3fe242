"""The host path of every filter's public ``step`` and ``run`` (jaxnav.core.filter): a donated
state is refused by name, a state in the wrong precision for the x64 setting is refused by name,
and the checks that run at every call (key, inputs, state) still refuse bad values however often
the same state, key and parameters were accepted before."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.core import filter as filter_api
from jaxnav.core.validation import check_magnitude, check_slots
from jaxnav.demo import demo_setting
from jaxnav.localization import mcl
from jaxnav.models import hf_rfid, motion
from jaxnav.models import landmarks as lm
from jaxnav.models.motion import OmniNoise
from jaxnav.sim import landmark_world as world
from jaxnav.sim import trajectories
from jaxnav.slam import fastslam, pf_slam, ps_slam

START = jnp.asarray([5.0, 1.5, 0.0])
DONATED = r"state has been donated to an earlier call \(state\.[a-z_.0-9]+ is deleted"


def _mcl_setting(steps=4, n=64):
    config, params = demo_setting(n)
    controls = trajectories.loop_controls(steps, 0.5, 0.21, 0.25)
    sim = world.simulate(jax.random.PRNGKey(10), params.landmarks, START, controls, params.motion, params.sensor)
    state = mcl.init(jax.random.PRNGKey(11), config, params, START, jnp.asarray([0.3, 0.3, 0.1]))
    return config, params, sim, state


def _at(tree, t):
    return jax.tree_util.tree_map(lambda x: x[t], tree)


# --------------------------------------------------------------------------- donated states


def _tag_slam(module):
    motion_noise = OmniNoise(jnp.asarray([0.01, 0.01, 0.01], jnp.float32))
    sensor = hf_rfid.reader_params(0.06)
    if module is pf_slam:
        config = pf_slam.PFSLAMConfig(num_particles=8, num_tag_particles=4, max_tags=32)
        params = pf_slam.PFSLAMParams(motion_noise, sensor)
    else:
        config = ps_slam.PSSLAMConfig(num_particles=8, num_tag_particles=4, max_tags=32, lag=2)
        params = ps_slam.PSSLAMParams(motion_noise, sensor, ps_slam.default_jitter(sensor))
    state = module.init(jax.random.PRNGKey(0), config, params, jnp.zeros(3))
    detections = hf_rfid.TagDetections(
        jnp.asarray([1, 2, 0, 0], jnp.int32),
        jnp.asarray([0, 3, 0, 0], jnp.int32),
        jnp.asarray([True, True, False, False]),
    )
    odometry = jnp.asarray([0.01, 0.0, 0.0, 0.1])
    return config, params, state, odometry, detections


def _fastslam():
    params = fastslam.FastSLAMParams(
        motion.VelocityNoise(jnp.full(6, 0.01), jnp.full(3, 0.01)), lm.RangeBearingNoise(jnp.asarray([0.1, 0.03]))
    )
    config = fastslam.FastSLAMConfig(num_particles=8, num_landmarks=8)
    state = fastslam.init(jax.random.PRNGKey(0), config, params, START)
    obs = lm.RangeBearingObs(jnp.arange(4, dtype=jnp.int32), jnp.ones((4, 2)), jnp.ones(4, bool))
    return config, params, state, jnp.asarray([0.5, 0.1, 0.1]), obs


DONATING = {
    "pf_slam": (pf_slam, lambda: _tag_slam(pf_slam)),
    "ps_slam": (ps_slam, lambda: _tag_slam(ps_slam)),
    "fastslam": (fastslam, _fastslam),
}


@pytest.mark.parametrize("name", sorted(DONATING))
def test_a_state_donated_to_step_is_refused_by_name(name):
    module, setup = DONATING[name]
    config, params, state, control, observation = setup()
    new_state, _ = module.step(jax.random.PRNGKey(1), state, config, params, control, observation)
    with pytest.raises(ValueError, match=DONATED) as err:
        module.step(jax.random.PRNGKey(2), state, config, params, control, observation)
    assert "pass the state that call returned" in str(err.value)
    assert "copy a state you want to keep" in str(err.value)  # this filter's step donates
    with pytest.raises(ValueError, match=DONATED):  # run refuses it too
        module.run(
            jax.random.PRNGKey(2),
            state,
            config,
            params,
            *jax.tree_util.tree_map(lambda x: x[None], (control, observation)),
        )
    module.step(jax.random.PRNGKey(2), new_state, config, params, control, observation)  # the returned one is fine


def test_a_state_donated_to_run_is_refused_by_name_mcl():
    config, params, sim, state = _mcl_setting()
    final, _ = mcl.run(jax.random.PRNGKey(0), state, config, params, sim.controls, sim.observations, donate_state=True)
    for call in (
        lambda: mcl.run(jax.random.PRNGKey(0), state, config, params, sim.controls, sim.observations),
        lambda: mcl.step(jax.random.PRNGKey(0), state, config, params, sim.controls[0], _at(sim.observations, 0)),
    ):
        with pytest.raises(ValueError, match=DONATED) as err:
            call()
        assert "donate_state=False" in str(err.value)
    mcl.step(jax.random.PRNGKey(0), final, config, params, sim.controls[0], _at(sim.observations, 0))
    # the same state passed with donate_state=False stays usable
    kept, _ = mcl.run(jax.random.PRNGKey(0), final, config, params, sim.controls, sim.observations)
    mcl.run(jax.random.PRNGKey(0), final, config, params, sim.controls, sim.observations)
    assert not any(leaf.is_deleted() for leaf in jax.tree_util.tree_leaves(final))


def test_a_state_donated_to_run_is_refused_by_name_pf_slam():
    config, params, state, odometry, detections = _tag_slam(pf_slam)
    xs = jax.tree_util.tree_map(lambda x: jnp.stack([x, x]), (odometry, detections))
    pf_slam.run(jax.random.PRNGKey(0), state, config, params, *xs, donate_state=True)
    with pytest.raises(ValueError, match=DONATED):
        pf_slam.run(jax.random.PRNGKey(0), state, config, params, *xs, donate_state=True)


# --------------------------------------------------------------------------- precision


def test_a_float64_state_is_refused_with_x64_off_by_name():
    config, params, sim, _ = _mcl_setting()
    with jax.enable_x64(True):
        _, params64 = demo_setting(64)
        state64 = mcl.init(
            jax.random.PRNGKey(11), config, params64, START.astype(jnp.float64), jnp.asarray([0.3, 0.3, 0.1])
        )
        assert state64.particles.dtype == jnp.float64
        # known under x64: the next call with x64 off must not take it as checked
        state64, _ = mcl.step(
            jax.random.PRNGKey(0), state64, config, params64, sim.controls[0], _at(sim.observations, 0)
        )
    match = r"state is in 64-bit floats \(state\.particles is float64.*jax_enable_x64 is off"
    with pytest.raises(ValueError, match=match):
        mcl.run(jax.random.PRNGKey(0), state64, config, params, sim.controls, sim.observations)
    with pytest.raises(ValueError, match=match):
        mcl.step(jax.random.PRNGKey(0), state64, config, params, sim.controls[0], _at(sim.observations, 0))
    numpy64 = mcl.MCLState(np.asarray(state64.particles), np.asarray(state64.log_weights))  # NumPy's default dtype
    with pytest.raises(ValueError, match=match):
        mcl.step(jax.random.PRNGKey(0), numpy64, config, params, sim.controls[0], _at(sim.observations, 0))


def test_a_float32_state_with_float64_params_is_refused_with_x64_on_by_name():
    config, params32, sim, state32 = _mcl_setting()
    with jax.enable_x64(True):
        _, params64 = demo_setting(64)  # built under x64: float64
        assert params64.landmarks.dtype == jnp.float64
        sim64 = jax.tree_util.tree_map(
            lambda x: x.astype(jnp.float64) if jnp.issubdtype(x.dtype, jnp.floating) else x, sim
        )
        match = r"state is in 32-bit floats \(state\.particles is float32.*params hold float64"
        with pytest.raises(ValueError, match=match):
            mcl.run(jax.random.PRNGKey(0), state32, config, params64, sim64.controls, sim64.observations)
        with pytest.raises(ValueError, match=match):
            mcl.step(jax.random.PRNGKey(0), state32, config, params64, sim64.controls[0], _at(sim64.observations, 0))
        # one precision throughout is accepted: float32 state and params under x64 compute in float32
        final, _ = mcl.run(jax.random.PRNGKey(0), state32, config, params32, sim.controls, sim.observations)
        assert final.particles.dtype == jnp.float32
        # and a float64 state made under x64 runs under x64
        state64 = mcl.init(
            jax.random.PRNGKey(11), config, params64, START.astype(jnp.float64), jnp.asarray([0.3, 0.3, 0.1])
        )
        final, _ = mcl.run(jax.random.PRNGKey(0), state64, config, params64, sim64.controls, sim64.observations)
        assert final.particles.dtype == jnp.float64


# --------------------------------------------------------------------------- no check skipped


def test_bad_inputs_are_refused_at_every_call_of_an_online_loop():
    """The state, key and parameters of a loop are known after the first call; the inputs are not."""
    config, params, sim, state = _mcl_setting(steps=6)
    for t in range(5):
        state, _ = mcl.step(
            jax.random.fold_in(jax.random.PRNGKey(0), t),
            state,
            config,
            params,
            sim.controls[t],
            _at(sim.observations, t),
        )
    key, control, obs = jax.random.PRNGKey(9), sim.controls[5], _at(sim.observations, 5)
    bad_controls = {
        "NaN": (control.at[0].set(jnp.nan), r"control holds 1 value\(s\) that are not finite"),
        "inf": (control.at[1].set(-jnp.inf), r"control holds 1 value\(s\) that are not finite"),
        "huge": (control.at[0].set(2e6), r"exceed 1e\+06 in magnitude, the first \(2e\+06\) at index \(0,\)"),
        "negative dt": (control.at[2].set(-0.1), "negative time step"),
    }
    for bad, match in bad_controls.values():
        with pytest.raises(ValueError, match=match):
            mcl.step(key, state, config, params, bad, obs)
    valid = int(np.flatnonzero(np.asarray(obs.mask))[0])
    for value, match in ((jnp.nan, "NaN or infinite values in 1 valid slot"), (3e6, "larger than 1e\\+06")):
        bad_obs = obs._replace(z=obs.z.at[valid, 0].set(value))
        with pytest.raises(ValueError, match=match + rf".*index \({valid},\)"):
            mcl.step(key, state, config, params, control, bad_obs)
    with pytest.raises(ValueError, match="mask must be a boolean"):
        mcl.step(key, state, config, params, control, obs._replace(mask=obs.mask.astype(jnp.float32)))
    with pytest.raises(ValueError, match="key must be one PRNG key"):
        mcl.step(jax.random.split(key, 2), state, config, params, control, obs)
    with pytest.raises(ValueError, match="key must be one PRNG key"):
        mcl.step(jnp.zeros(3, jnp.uint32), state, config, params, control, obs)
    mcl.step(key, state, config, params, control, obs)  # and the good inputs still pass


def test_slot_values_outside_the_valid_slots_are_not_read():
    ids, mask = np.asarray([0, 1, 2, 7]), np.asarray([True, False, True, True])
    z = np.ones((4, 2), np.float32)
    z[1] = np.nan  # a masked-out slot
    z[3] = np.inf  # a slot whose id is not on a map of 5 landmarks
    check_slots("observations", ids, mask, z, num_ids=5)
    with pytest.raises(ValueError, match=r"valid slot\(s\), the first at index \(3,\)"):
        check_slots("observations", ids, mask, z)  # without a map every valid slot counts
    z[2, 1] = -2e6
    with pytest.raises(ValueError, match=r"larger than 1e\+06 .* 1 valid slot\(s\), the first at index \(2,\)"):
        check_slots("observations", ids, mask, z, num_ids=5)
    check_slots("observations", np.zeros((0,), int), np.zeros((0,), bool), np.zeros((0, 2)), num_ids=5)


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf, 1e7, -1e7])
def test_magnitude_check_names_the_first_bad_value(value):
    x = np.zeros((2, 3), np.float32)
    x[1, 2] = value
    with pytest.raises(ValueError, match=r"x holds 1 value\(s\) .* at index \(1, 2\)"):
        check_magnitude("x", x)
    check_magnitude("x", np.full((2, 3), 1e6))  # the limit itself is allowed


class _WalkState(NamedTuple):
    particles: jax.Array


@dataclass(frozen=True)
class _WalkConfig:
    pass


def test_one_initial_state_passed_again_and_again_is_checked_once():
    """A benchmark or a test that steps from one initial state many times: the state stays known
    beside the states the calls return, and is not read again."""
    seen = []

    def check_state(config, params, state):
        seen.append(state)

    spec = filter_api.FilterSpec(
        name="walk",
        kernel=lambda key, state, config, params, control, obs: (_WalkState(state.particles + control), jnp.sum(obs)),
        config_type=_WalkConfig,
        check_state=check_state,
        state_type=_WalkState,
    )
    step, _ = filter_api.build(spec)
    state0 = _WalkState(jnp.zeros(4))
    for i in range(4):
        step(jax.random.PRNGKey(i), state0, _WalkConfig(), (), 1.0, 2.0)
    assert len(seen) == 1
    step(jax.random.PRNGKey(0), _WalkState(jnp.zeros(4)), _WalkConfig(), (), 1.0, 2.0)  # the same values, another state
    assert len(seen) == 2
    with pytest.raises(ValueError, match=r"state.particles holds 1 NaN"):
        step(jax.random.PRNGKey(0), _WalkState(jnp.zeros(4).at[2].set(jnp.nan)), _WalkConfig(), (), 1.0, 2.0)


@pytest.mark.parametrize("size", [1, 3, 64, 65, 1000])
def test_the_value_checks_answer_alike_for_few_and_many_values(size):
    """Up to 64 values are compared in Python, more with NumPy: the same answers either way, for
    finite values, NaN, ±inf, a value past the limit, and negative time steps."""
    from jaxnav.core import validation as v

    base = np.linspace(-1.0, 1.0, size).astype(np.float32)
    assert v._all_within(base, 1e6) and v.any_negative(base)  # base[0] = -1
    assert not v.any_negative(np.abs(base)) and not v.any_negative(np.full(size, np.nan, np.float32))
    for bad in (np.nan, np.inf, -np.inf, 2e6):
        x = base.copy()
        x[size // 2] = bad
        assert not v._all_within(x, 1e6)
        with pytest.raises(ValueError, match="not finite or exceed"):
            v.check_magnitude("controls", x)
