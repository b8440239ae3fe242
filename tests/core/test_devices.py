"""Runs spread over devices: the same numbers, bit for bit, on any number of them.

The suite's own process has one CPU device; the checks run in a child process with four
(``--xla_force_host_platform_device_count=4``), which JAX reads once, when its backend starts.
"""

from __future__ import annotations

import jax
import pytest

from jaxnav.core import batch
from tests import child_process

_CHILD = r"""
import json, sys, tempfile, os
import jax, jax.numpy as jnp, numpy as np
from jaxnav.core import monte_carlo
from jaxnav.experiments import sweep as sw
from jaxnav.localization import mcl
from jaxnav.models import landmarks as lm, motion
from jaxnav.sim import landmark_world as world, trajectories

assert len(jax.devices()) == 4, jax.devices()
config = mcl.MCLConfig(num_particles=64, motion_model="velocity")
params = mcl.MCLParams(
    motion.VelocityNoise(jnp.full(6, 0.01), jnp.full(3, 0.01)),
    lm.RangeBearingNoise(jnp.asarray([0.1, 0.05])),
    world.square_room_landmarks(10.0, 6),
)
start = jnp.asarray([5.0, 1.5, 0.0])
controls = trajectories.loop_controls(20, 0.5, 0.21, 0.25)

def filtered(key, scale):  # one MCL run: simulate, filter, score; a pytree of outputs
    k_sim, k_init, k_run = jax.random.split(key, 3)
    sim = world.simulate(k_sim, params.landmarks, start, controls, params.motion, params.sensor)
    state = mcl.init(k_init, config, params, start, jnp.full(3, 0.2))
    trace = mcl.run(k_run, state, config, params, sim.controls, sim.observations)[1]
    err = jnp.linalg.norm(trace.estimate[:, :2] - sim.true_poses[:, :2], axis=1)
    return {"mean_m": err.mean() * scale, "last": trace.estimate[-1], "ess": trace.ess}

def bits(tree):
    return [(np.asarray(x).dtype.str, np.asarray(x).shape, np.asarray(x).tobytes().hex()) for x in jax.tree.leaves(tree)]

out = {}
R = 22
scale = np.linspace(1.0, 2.0, R).astype(np.float32)
for d in (1, 3, None):
    out[f"mc{d}"] = bits(monte_carlo(filtered, jax.random.PRNGKey(3), R, scale, chunk_size=3, devices=d))

# lanes of 2: the same bits whatever the chunk size (2, 4, 6, or the default) and device count
for chunk, d in ((2, 1), (4, 1), (6, 3), (None, None)):
    out[f"lanes{chunk}-{d}"] = bits(monte_carlo(filtered, jax.random.PRNGKey(3), R, scale, chunk_size=chunk, devices=d, lanes=2))

def sweep_fn(key, scale):
    return {"mean_m": filtered(key, scale)["mean_m"]}

cells = [("low", sweep_fn, (jnp.float32(1.0),)), ("high", sweep_fn, (jnp.float32(2.0),))]
folder = tempfile.mkdtemp()
for d in (1, 4):
    out[f"sweep{d}"] = bits(sw.sweep(cells, 10, jax.random.PRNGKey(4), chunk_size=2, progress=False, devices=d))
# interrupted on four devices after its first call, resumed on one: the file of an uninterrupted one-device sweep
whole, parts = os.path.join(folder, "whole.json"), os.path.join(folder, "parts.json")
sw.sweep(cells, 10, jax.random.PRNGKey(4), whole, chunk_size=2, progress=False, devices=1)
def stop(cell, done):
    raise KeyboardInterrupt
try:
    sw.sweep(cells, 10, jax.random.PRNGKey(4), parts, chunk_size=2, progress=False, devices=4, on_chunk=stop)
except KeyboardInterrupt:
    pass
out["interrupted_runs"] = len(json.load(open(parts))["cells"]["low"]["mean_m"])
sw.sweep(cells, 10, jax.random.PRNGKey(4), parts, chunk_size=2, progress=False, devices=1)
out["resumed_same_file"] = open(whole).read() == open(parts).read()

def cholesky_loop(key):  # a program that calls LAPACK: two CPU devices at once would hang XLA:CPU
    y = jax.random.normal(key, (12_500, 3))
    def body(c, _):
        return c + jnp.linalg.cholesky(y[:, :, None] * y[:, None, :] + (3.0 + c) * jnp.eye(3)).sum() * 1e-9, None
    return {"total": jax.lax.scan(body, 0.0, None, length=100)[0]}
for d in (1, 2):
    out[f"lapack{d}"] = bits(monte_carlo(cholesky_loop, jax.random.PRNGKey(5), 4, chunk_size=2, devices=d))
print("RESULT " + json.dumps(out))
"""


@pytest.fixture(scope="module")
def four_devices() -> dict:
    return child_process.run(_CHILD, devices=4, timeout=300)


def test_monte_carlo_gives_the_same_bits_on_one_to_four_devices(four_devices):
    """22 MCL runs in chunks of 3 on 1 and 3 devices (the last call padded) and on all four by default:
    every output leaf (a mean, the last estimates, the ESS traces) is the same, bit for bit."""
    one = four_devices["mc1"]
    assert one and four_devices["mc3"] == one and four_devices["mcNone"] == one


def test_with_lanes_the_bits_do_not_depend_on_the_chunk_size(four_devices):
    """``lanes=2``: chunks of 2, 4 and 6 runs (6 on three devices) and the default (all runs at once over
    four devices, rounded up to whole lanes) give the same bits for all 22 runs."""
    first = four_devices["lanes2-1"]
    assert first and all(four_devices[k] == first for k in ("lanes4-1", "lanes6-3", "lanesNone-None"))


def test_lanes_must_divide_the_chunk():
    from jaxnav.core import monte_carlo

    with pytest.raises(ValueError, match="multiple of lanes"):
        monte_carlo(lambda k: jax.random.normal(k), jax.random.PRNGKey(0), 8, chunk_size=6, lanes=4)
    with pytest.raises(ValueError, match="lanes"):
        monte_carlo(lambda k: jax.random.normal(k), jax.random.PRNGKey(0), 8, lanes=0)
    with pytest.raises(ValueError, match="jit"):
        monte_carlo(lambda k: jax.random.normal(k), jax.random.PRNGKey(0), 8, lanes=2, jit=False)


def test_a_sweep_gives_the_same_bits_on_any_device_count_and_resumes_on_another(four_devices):
    """A two-cell sweep of 10 runs in chunks of 2 on 1 and 4 devices gives the same runs; one interrupted
    on four devices after its first call (four chunks, not yet all runs) and resumed on one writes the
    same checkpoint, byte for byte, as an uninterrupted one-device sweep."""
    assert four_devices["sweep1"] == four_devices["sweep4"]
    assert 0 < four_devices["interrupted_runs"] < 10
    assert four_devices["resumed_same_file"]


def test_a_program_that_calls_lapack_finishes_over_devices_with_the_same_bits(four_devices):
    """Two CPU devices running a LAPACK program at once hang XLA:CPU (:func:`jaxnav.core.batch.calls_lapack`);
    spread over two devices, it runs block by block on one and gives the one-device bits."""
    assert four_devices["lapack1"] == four_devices["lapack2"]


@pytest.mark.parametrize("devices", [0, 2, -1, True, "cpu", 1.5, (), "dup"])
def test_bad_devices_are_refused_by_name(devices):
    """This process has one device: 0, 2, a negative count, a bool, a string, a float, an empty
    sequence and a repeated device are refused naming ``devices``."""
    if devices == "dup":
        devices = [jax.devices()[0]] * 2
    with pytest.raises(ValueError, match="devices"):
        batch.run_devices(devices)


def test_the_default_is_every_local_device():
    assert batch.run_devices() == tuple(jax.local_devices())
    assert batch.run_devices(1) == tuple(jax.local_devices()[:1])
    assert batch.run_devices(jax.local_devices()) == tuple(jax.local_devices())
