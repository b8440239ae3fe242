"""Inputs that JAX would reject with an error naming nothing, or that a cast would silently change,
either work or are refused with a ``ValueError`` that names the argument:

* a negative step count for the control generators of :mod:`jaxnav.sim.trajectories` (zero is an
  empty series);
* float32 controls with float64 landmarks under x64 in the landmark simulator (promoted to one dtype);
* bfloat16 and complex inputs and parameters of every filter (bfloat16 inputs are promoted to
  float32; bfloat16 parameters and anything complex are refused naming the dtype);
* an HF reader index out of range in :func:`jaxnav.models.hf_rfid.landmark_observations`;
* a negative IR receiver level, which the receiver cannot produce.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.localization import ir_mcl
from jaxnav.models import hf_rfid
from jaxnav.sim import landmark_world, trajectories
from tests.test_bad_input import FILTERS, _call, _float_leaves, _names, setups

# --------------------------------------------------------------------------- step counts


@pytest.mark.parametrize("num_steps", [-1, -100, 2.5, True, "3"])
def test_a_step_count_that_is_not_a_count_is_refused_by_name(num_steps):
    with pytest.raises(ValueError, match="num_steps must be a non-negative integer"):
        trajectories.loop_controls(num_steps)
    with pytest.raises(ValueError, match="num_steps must be a non-negative integer"):
        trajectories.random_controls(jax.random.PRNGKey(0), num_steps=num_steps)


def test_zero_steps_give_an_empty_series_of_the_right_shape():
    assert trajectories.loop_controls(0).shape == (0, 3)
    assert trajectories.loop_controls(np.int64(2)).shape == (2, 3)
    start, controls = trajectories.random_controls(jax.random.PRNGKey(0), num_steps=0)
    assert start.shape == (3,) and controls.shape == (0, 4)


# --------------------------------------------------------------------------- mixed precision


def test_the_landmark_simulator_promotes_mixed_precision_to_one_dtype():
    """float32 controls (what loop_controls makes) with float64 landmarks and noise under x64 would
    change the type of the scan's carry: every array is float64, and the run is the one with the
    controls cast to float64 first."""
    s = setups()["mcl"]
    with jax.enable_x64(True):
        p = jax.tree_util.tree_map(lambda x: jnp.asarray(np.asarray(x), jnp.float64), s.params)
        controls = trajectories.loop_controls(4, 0.5, 0.21, 0.25)
        assert controls.dtype == jnp.float32
        start = jnp.asarray([5.0, 1.5, 0.0], jnp.float64)
        sim = landmark_world.simulate(jax.random.PRNGKey(1), p.landmarks, start, controls, p.motion, p.sensor)
        assert {np.dtype(jnp.result_type(x)) for x in (sim.true_poses, sim.controls, sim.observations.z)} == {
            np.dtype(np.float64)
        }
        same = landmark_world.simulate(
            jax.random.PRNGKey(1), p.landmarks, start, controls.astype(jnp.float64), p.motion, p.sensor
        )
        np.testing.assert_array_equal(np.asarray(sim.true_poses), np.asarray(same.true_poses))


# --------------------------------------------------------------------------- bfloat16 and complex


def _cast_first(tree, path, dtype):
    return jax.tree_util.tree_map_with_path(lambda p, x: jnp.asarray(x).astype(dtype) if p == path else x, tree)


@pytest.mark.parametrize("f", FILTERS)
def test_complex_inputs_and_parameters_are_refused_naming_the_argument_and_the_dtype(f):
    s = setups()[f]
    failures = []
    cases = []
    for i, x in enumerate(s.inputs):
        for path, _ in _float_leaves(x):
            inputs = tuple(_cast_first(y, path, jnp.complex64) if j == i else y for j, y in enumerate(s.inputs))
            cases.append((".".join([s.input_names[i], *_names(path)]), dict(inputs=inputs)))
    for path, _ in _float_leaves(s.params):
        cases.append((".".join(["params", *_names(path)]), dict(params=_cast_first(s.params, path, jnp.complex64))))
    for name, kwargs in cases:
        last = name.split(".")[-1]
        try:
            _call(s, **kwargs)()
            failures.append(f"{name}: accepted")
        except ValueError as err:
            if "complex64" not in str(err) or last not in str(err):
                failures.append(f"{name}: {err}")
        except Exception as err:  # noqa: BLE001  (any other kind is a failure to report)
            failures.append(f"{name}: {type(err).__name__}: {err}")
    assert not failures, "\n".join(failures)


@pytest.mark.parametrize("f", FILTERS)
def test_bfloat16_parameters_are_refused_naming_the_field_and_the_dtype(f):
    s = setups()[f]
    for path, _ in _float_leaves(s.params):
        name = ".".join(["params", *_names(path)])
        with pytest.raises(ValueError, match=rf"{name.split('.')[-1]}.* has dtype bfloat16"):
            _call(s, params=_cast_first(s.params, path, jnp.bfloat16))()


# RFID tag localization is left out: its reads have always been cast to float32 before the step.
@pytest.mark.parametrize("f", [f for f in FILTERS if f != "rfid_tag"])
def test_bfloat16_inputs_are_promoted_to_float32(f):
    """The first floating input of every filter in bfloat16 gives the result of the same values in float32."""
    s = setups()[f]
    path, _ = _float_leaves(s.inputs[0])[0]
    half = (_cast_first(s.inputs[0], path, jnp.bfloat16), *s.inputs[1:])
    rounded = (_cast_first(half[0], path, jnp.float32), *s.inputs[1:])
    final, trace = _call(s, inputs=half)()
    expected_final, expected_trace = _call(s, inputs=rounded)()
    for a, b in zip(
        jax.tree_util.tree_leaves((final, trace)), jax.tree_util.tree_leaves((expected_final, expected_trace))
    ):
        assert jnp.result_type(a) == jnp.result_type(b)
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


# --------------------------------------------------------------------------- HF readers


def test_landmark_observations_refuse_a_reader_that_does_not_exist():
    p = hf_rfid.reader_params()  # 8 readers
    det = hf_rfid.TagDetections(
        jnp.asarray([[7, 9, 4], [3, 3, 12]], jnp.int32),
        jnp.asarray([[2, 5, -1], [0, 8, 1]], jnp.int32),
        jnp.asarray([[True, True, False], [True, True, True]]),
    )
    with pytest.raises(ValueError, match=r"detections.readers must index the 8 readers .* got 8 at index \(1, 1\)"):
        hf_rfid.landmark_observations(det, p)
    # the masked-out reader -1 is never read: with the 8 fixed, the call goes through
    ok = det._replace(readers=det.readers.at[1, 1].set(7))
    np.testing.assert_allclose(hf_rfid.landmark_observations(ok, p).z[1, 1], np.asarray(p.offsets)[7])
    # inside a caller's jit the values are unknown: the index is clipped, as before
    z = jax.jit(lambda d: hf_rfid.landmark_observations(d, p).z)(det)
    np.testing.assert_allclose(z[1, 1], np.asarray(p.offsets)[7])


# --------------------------------------------------------------------------- IR receiver levels


def _ir_inputs_with_level(value: float):
    s = setups()["ir_mcl"]
    controls, det = s.inputs
    t, r = (int(i) for i in np.argwhere(np.asarray(det.valid))[0])
    return s, (controls, det._replace(voltage=det.voltage.at[t, r].set(value))), t, r


def test_ir_mcl_refuses_a_negative_receiver_level():
    s, inputs, t, r = _ir_inputs_with_level(-0.3)
    with pytest.raises(
        ValueError, match=rf"detections.voltage holds 1 negative level\(s\), the first \(-0.3 V\) at index \({t}, {r}\)"
    ):
        _call(s, inputs=inputs)()
    one = jax.tree_util.tree_map(lambda x: x[t], inputs)
    with pytest.raises(ValueError, match="detection.voltage holds 1 negative level"):
        ir_mcl.step(jax.random.PRNGKey(0), s.state, s.config, s.params, *one)


def test_ir_mcl_under_jit_drops_and_counts_a_negative_level():
    s, inputs, t, _ = _ir_inputs_with_level(-0.3)
    run = jax.jit(lambda *xs: s.run(jax.random.PRNGKey(7), s.state, s.config, s.params, *xs))
    _, trace = run(*inputs)
    _, clean = run(*s.inputs)
    steps = np.arange(np.shape(trace.num_ignored)[0])
    np.testing.assert_array_equal(np.asarray(trace.num_ignored), np.asarray(clean.num_ignored) + (steps == t))
