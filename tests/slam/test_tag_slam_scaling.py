"""A PF-SLAM / PS-SLAM step touches only the detected tags ([W] §3.3.1): inspected in the jaxpr and the compiled HLO."""

from __future__ import annotations

import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.extend import core as jex_core

from jaxnav.models import hf_rfid
from jaxnav.models.motion import OmniNoise
from jaxnav.slam import pf_slam, ps_slam

MAX_TAGS = 100_003  # a size no other array in the step has
MOTION = OmniNoise(jnp.asarray([0.05, 0.05, 0.02], jnp.float32))
SENSOR = hf_rfid.reader_params(0.06)
IN_PLACE_PRIMITIVES = {"gather", "scatter"}


def _setup(method: str, max_tags: int, lag: int = 20, parallel_slots=None):
    if method == "pf":
        config = pf_slam.PFSLAMConfig(
            num_particles=500, num_tag_particles=100, max_tags=max_tags, parallel_slots=parallel_slots
        )
        return pf_slam, config, pf_slam.PFSLAMParams(MOTION, SENSOR)
    config = ps_slam.PSSLAMConfig(
        num_particles=500, num_tag_particles=100, max_tags=max_tags, lag=lag, parallel_slots=parallel_slots
    )
    return ps_slam, config, ps_slam.PSSLAMParams(MOTION, SENSOR, ps_slam.default_jitter(SENSOR))


def _detections(ids, readers, k=8):
    pad = k - len(ids)
    return hf_rfid.TagDetections(
        jnp.asarray(list(ids) + [0] * pad, jnp.int32),
        jnp.asarray(list(readers) + [0] * pad, jnp.int32),
        jnp.asarray([True] * len(ids) + [False] * pad),
    )


def _table_sized_equations(jaxpr, size, found):
    """(primitive, shapes) of every equation, in every sub-jaxpr, with an operand or result of dimension ``size``."""
    for eqn in jaxpr.eqns:
        shapes = [tuple(v.aval.shape) for v in (*eqn.invars, *eqn.outvars) if hasattr(v.aval, "shape")]
        hit = [s for s in shapes if size in s]
        if hit:
            found.append((eqn.primitive.name, hit))
        for param in eqn.params.values():
            for sub in param if isinstance(param, (list, tuple)) else (param,):
                if isinstance(sub, jex_core.ClosedJaxpr):
                    _table_sized_equations(sub.jaxpr, size, found)
                elif isinstance(sub, jex_core.Jaxpr):
                    _table_sized_equations(sub, size, found)
    return found


@pytest.mark.parametrize("parallel_slots", [None, 3])
@pytest.mark.parametrize("method", ["pf", "ps"])
def test_step_jaxpr_touches_the_table_only_through_gather_and_scatter(method, parallel_slots):
    module, config, params = _setup(method, MAX_TAGS, lag=2, parallel_slots=parallel_slots)
    state = jax.eval_shape(lambda: module.init(jax.random.PRNGKey(0), config, params, jnp.zeros(3)))
    closed = jax.make_jaxpr(module.kernel, static_argnums=(2,))(
        jax.random.PRNGKey(1), state, config, params, jnp.zeros(4), _detections([1, 2], [0, 3])
    )
    found = _table_sized_equations(closed.jaxpr, MAX_TAGS, [])
    assert found, "the table must be read and written"
    assert {name for name, _ in found} == IN_PLACE_PRIMITIVES, found
    # one gather and one scatter per table field
    fields = len(state.tags)
    assert sum(name == "gather" for name, _ in found) == fields
    assert sum(name == "scatter" for name, _ in found) == fields


@pytest.mark.parametrize("parallel_slots", [None, 3])
@pytest.mark.parametrize("method", ["pf", "ps"])
def test_compiled_step_updates_the_table_in_place(method, parallel_slots):
    """The donated step's optimised HLO aliases every table field to its output and copies none of
    them (a copy would cost O(max_tags) per step: the regression this guards against)."""
    module, config, params = _setup(method, MAX_TAGS, lag=2, parallel_slots=parallel_slots)
    state = jax.eval_shape(lambda: module.init(jax.random.PRNGKey(0), config, params, jnp.zeros(3)))
    hlo = (
        module.step.jitted.lower(
            jax.random.PRNGKey(1), state, config, params, jnp.zeros(4), _detections([1, 2], [0, 3])
        )
        .compile()
        .as_text()
    )
    table_copies = [
        line for line in hlo.splitlines() if re.search(r"copy\(", line) and str(MAX_TAGS) in line.split("copy(")[0]
    ]
    assert table_copies == []
    header = hlo.splitlines()[0]
    assert header.count("may-alias") + header.count("must-alias") >= 2 + len(state.tags)


def test_a_100000_tag_map_runs_steps_and_updates_only_the_detected_rows():
    module, config, params = _setup("pf", 100_000)
    state = module.init(jax.random.PRNGKey(0), config, params, jnp.zeros(3))
    u = jnp.asarray([0.0, 0.0, 0.0, 0.1])
    state, info = module.step(jax.random.PRNGKey(1), state, config, params, u, _detections([99_999, 5], [0, 7]))
    state, info = module.step(jax.random.PRNGKey(2), state, config, params, u, _detections([99_999], [0]))
    counts = np.asarray(state.tags.counts)
    assert counts[99_999] == 2 and counts[5] == 1 and counts.sum() == 3
    assert int(info.num_updated) == 1 and int(info.num_ignored) == 0
    assert np.isfinite(np.asarray(info.estimate)).all()


def test_ps_slam_100000_tag_map_runs_a_step():
    module, config, params = _setup("ps", 100_000, lag=4)
    state = module.init(jax.random.PRNGKey(0), config, params, jnp.zeros(3))
    state, info = module.step(
        jax.random.PRNGKey(1), state, config, params, jnp.asarray([0.0, 0.0, 0.0, 0.1]), _detections([99_998], [2])
    )
    assert int(state.tags.counts[99_998]) == 1 and int(info.num_new) == 1
