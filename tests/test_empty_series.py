"""Zero-length inputs are valid for every filter: a run of zero steps, or observations with zero
slots, returns the initial state and an empty trace (zero steps) or the state after the motion
updates alone (zero slots).

The cases come from the filters' own setups in ``test_bad_input.py``, so every public filter is
covered: on the host, with ``donate_state=True``, inside a caller's ``jit`` and over runs with
:func:`jaxnav.core.monte_carlo`.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest

from jaxnav.core import monte_carlo
from tests.test_bad_input import FILTERS, setups


def _no_steps(inputs: tuple) -> tuple:
    return jax.tree_util.tree_map(lambda x: x[:0], inputs)


def _no_slots(inputs: tuple) -> tuple:
    """The observation (the last input) with its slot axis, axis 1, cut to zero length."""
    *head, obs = inputs
    return (*head, jax.tree_util.tree_map(lambda x: x[:, :0] if np.ndim(x) >= 2 else x, obs))


def _key(s):
    return None if s.deterministic else jax.random.PRNGKey(3)


def _copy(tree):
    return jax.tree_util.tree_map(lambda x: np.array(x), tree)


def _assert_same(a, b):
    for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def _assert_empty_trace(trace):
    leaves = jax.tree_util.tree_leaves(trace)
    assert leaves, "the trace has no fields"
    assert all(np.shape(leaf)[0] == 0 for leaf in leaves), [np.shape(leaf) for leaf in leaves]


@pytest.mark.parametrize("name", FILTERS)
def test_zero_steps_return_the_initial_state(name):
    s = setups()[name]
    initial = _copy(s.state)
    final, trace = s.run(_key(s), s.state, s.config, s.params, *_no_steps(s.inputs))
    _assert_same(final, initial)
    _assert_empty_trace(trace)
    # donated: the initial state's buffers are given to the run; the result is still that state
    donated = jax.tree_util.tree_map(jax.numpy.array, initial)
    final, trace = s.run(_key(s), donated, s.config, s.params, *_no_steps(s.inputs), donate_state=True)
    _assert_same(final, initial)
    _assert_empty_trace(trace)


@pytest.mark.parametrize("name", FILTERS)
def test_zero_steps_under_jit_and_monte_carlo(name):
    s = setups()[name]
    inputs = _no_steps(s.inputs)

    def one_run(key):
        return s.run(None if s.deterministic else key, s.state, s.config, s.params, *inputs)

    final, trace = jax.jit(one_run)(jax.random.PRNGKey(0))
    _assert_same(final, s.state)
    _assert_empty_trace(trace)
    finals, traces = monte_carlo(one_run, jax.random.PRNGKey(1), 3, chunk_size=2)
    for x, y in zip(jax.tree_util.tree_leaves(finals), jax.tree_util.tree_leaves(s.state), strict=True):
        np.testing.assert_array_equal(x, np.broadcast_to(np.asarray(y), x.shape))
    assert all(np.shape(leaf)[:2] == (3, 0) for leaf in jax.tree_util.tree_leaves(traces))


# Filters whose slots are fixed by their hardware, one per receiver or anchor: fewer is a shape error.
FIXED_SLOTS = {"ir_mcl": "detections", "rfid_anchor": "reads"}


@pytest.mark.parametrize("name", FILTERS)
def test_zero_slots_are_steps_without_observations(name):
    """With no observation slots every step is a motion update alone: finite, one trace row per step."""
    s = setups()[name]
    inputs = _no_slots(s.inputs)
    if name in FIXED_SLOTS:
        with pytest.raises(ValueError, match=FIXED_SLOTS[name]):
            s.run(_key(s), s.state, s.config, s.params, *inputs)
        return
    final, trace = s.run(_key(s), s.state, s.config, s.params, *inputs)
    num_steps = np.shape(jax.tree_util.tree_leaves(s.inputs)[0])[0]
    assert all(np.shape(leaf)[0] == num_steps for leaf in jax.tree_util.tree_leaves(trace))
    for leaf in jax.tree_util.tree_leaves((final, trace)):
        v = np.asarray(leaf)
        if v.dtype.kind == "f":
            assert not np.isnan(v).any() and not (v == np.inf).any()
