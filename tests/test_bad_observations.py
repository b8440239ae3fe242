"""Bad observation slots never become a silent wrong answer, in any landmark filter.

A NaN or an infinity in a valid slot is refused on the host with the argument and the slot
named; inside a caller's ``jit`` (values unknown on the host) the slot is dropped and counted
in ``info.num_ignored``, and every estimate stays finite. An integer mask of 0/1 filters exactly like
the boolean one; other integers (a 0/2 mask, which a bitwise ``&`` would turn into "drop every
slot") are refused on the host and read as nonzero = set inside a caller's ``jit``; a float mask or
float ids are refused.

The filters are the landmark filters' setups of ``test_bad_input.py`` (same states, configs,
parameters, keys and inputs), run the way that file runs them (:func:`~tests.test_bad_input._call`
on the host, :func:`~tests.test_bad_input._jit_run` inside a caller's ``jit``): the programs of a
clean run are then the same programs, compiled once for both files (the suite shares one persistent
compilation cache). None of the claims depends on the sizes.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.models import hf_rfid
from jaxnav.models.motion import OmniNoise
from jaxnav.slam import pf_slam
from tests.test_bad_input import T, _call, _jit_run, setups

BAD_STEP = 1  # the step whose first slot the tests poison: steps follow it, over which the effect could spread


def _setup(name):
    """``(setup, controls, observations)`` of the filter ``name`` (``test_bad_input.setups``)."""
    s = setups()[name]
    controls, obs = s.inputs
    assert bool(obs.mask[BAD_STEP, 0])  # the slot the tests poison is a real observation
    return s, controls, obs


def _run(s, u, obs):
    """The filter's ``run`` on the host, on these controls and observations."""
    return _call(s, inputs=(u, obs))()


NAMES = ["ekf", "ukf", "mcl", "grid", "ekf_slam", "fastslam1", "fastslam2"]


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("value", [np.nan, np.inf])
def test_a_non_finite_valid_slot_is_refused_on_the_host(name, value):
    s, u, obs = _setup(name)
    bad = obs._replace(z=obs.z.at[BAD_STEP, 0, 0].set(value))
    with pytest.raises(ValueError, match=rf"observations.z holds NaN or infinite values .* index \({BAD_STEP}, 0\)"):
        _run(s, u, bad)


@pytest.mark.parametrize("name", NAMES)
def test_a_non_finite_valid_slot_under_jit_is_dropped_and_counted(name):
    s, u, obs = _setup(name)
    bad = obs._replace(z=obs.z.at[BAD_STEP, 0, 1].set(jnp.inf))
    final, trace = _jit_run(s, (u, bad))
    for leaf in jax.tree_util.tree_leaves((final, trace.estimate)):
        if jnp.issubdtype(leaf.dtype, jnp.floating):
            assert np.all(np.isfinite(np.asarray(leaf)) | np.isneginf(np.asarray(leaf))), name
    _, clean = _run(s, u, obs)
    np.testing.assert_array_equal(
        np.asarray(trace.num_ignored), np.asarray(clean.num_ignored) + (np.arange(T) == BAD_STEP)
    )
    # the same as masking the slot out
    _, masked = _run(s, u, obs._replace(mask=obs.mask.at[BAD_STEP, 0].set(False)))
    np.testing.assert_allclose(np.asarray(trace.estimate), np.asarray(masked.estimate), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("name", NAMES)
def test_an_integer_mask_of_zeros_and_ones_is_the_boolean_mask_and_others_are_refused(name):
    s, u, obs = _setup(name)
    _, expected = _run(s, u, obs)
    _, ones = _run(s, u, obs._replace(mask=obs.mask.astype(jnp.int32)))
    np.testing.assert_array_equal(np.asarray(ones.estimate), np.asarray(expected.estimate))
    twos = obs._replace(mask=obs.mask.astype(jnp.int32) * 2)
    with pytest.raises(ValueError, match=r"observations.mask must be boolean or integers 0 and 1, got 2 at index"):
        _run(s, u, twos)
    # inside a caller's jit: nonzero = set. The caller's jit is another XLA program than the
    # filter's own, which may round differently (measured: up to 2.4e-6 m): equal to float32 rounding
    _, traced = _jit_run(s, (u, twos))
    np.testing.assert_allclose(np.asarray(traced.estimate), np.asarray(expected.estimate), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("name", NAMES)
def test_float_masks_and_float_ids_are_refused_by_name(name):
    s, u, obs = _setup(name)
    with pytest.raises(ValueError, match="observations.mask must be a boolean array"):
        _run(s, u, obs._replace(mask=obs.mask.astype(jnp.float32)))
    with pytest.raises(ValueError, match="observations.ids must be an integer array"):
        _run(s, u, obs._replace(ids=obs.ids.astype(jnp.float32)))


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
