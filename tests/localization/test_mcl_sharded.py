"""MCL with its particles spread over devices (``mcl.run_sharded``): the unsharded run's numbers.

The motion noise and the resampling from given weights are exact by construction; the normaliser,
the ESS and the estimate are sums over devices in another order than one device's. The runs below
carried the unsharded particles bit for bit on XLA:CPU; what is guaranteed is float rounding.

The checks that need several devices run in a child process with four CPU devices
(``--xla_force_host_platform_device_count``, read once when JAX starts); the suite's own process
has one, on which ``run_sharded`` must still equal ``run``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.sharding import Mesh
from jax.sharding import PartitionSpec as P

from jaxnav.core import sharded
from jaxnav.demo import demo_setting
from jaxnav.localization import mcl
from jaxnav.sim import landmark_world, trajectories
from tests import child_process

_CHILD = r"""
import json
import jax, jax.numpy as jnp, numpy as np
from jaxnav.core import fastmath, rng
from jaxnav.demo import demo_setting
from jaxnav.localization import mcl
from jaxnav.sim import landmark_world, trajectories
from jax.sharding import Mesh, PartitionSpec as P

assert len(jax.devices()) == 4
start = jnp.asarray([5.0, 1.5, 0.0])
_, params = demo_setting(10)
steps = 25
controls = trajectories.loop_controls(steps, 0.5, 0.21, 0.25)
obs = landmark_world.simulate(jax.random.PRNGKey(1), params.landmarks, start, controls, params.motion, params.sensor).observations

def compare(n, threshold, scheme, seed, devices):
    config = mcl.MCLConfig(num_particles=n, ess_threshold=threshold, resampling=scheme)
    state = mcl.init(jax.random.PRNGKey(0), config, params, start, jnp.full(3, 0.3))
    key = jax.random.PRNGKey(seed)
    f1, t1 = mcl.run(key, state, config, params, controls, obs)
    fd, td = mcl.run_sharded(key, state, config, params, controls, obs, devices=devices)
    same = lambda a, b: bool(np.array_equal(np.asarray(a), np.asarray(b)))
    return {
        "case": [n, threshold, scheme, seed, devices],
        "particles": same(f1.particles, fd.particles),
        "log_weights": same(f1.log_weights, fd.log_weights),
        "ess": same(t1.ess, td.ess),
        "ess_rel": float(np.max(np.abs(np.asarray(t1.ess) / np.asarray(td.ess) - 1))),
        "resampled": same(t1.resampled, td.resampled),
        "times_resampled": int(np.sum(np.asarray(t1.resampled))),
        "estimate": float(np.max(np.abs(np.asarray(t1.estimate) - np.asarray(td.estimate)))),
        "log_likelihood": float(np.max(np.abs(np.asarray(t1.log_likelihood) - np.asarray(td.log_likelihood)))),
        "spread_over": len(fd.particles.sharding.device_set),
    }

out = {"runs": [], "draws": {}, "errors": []}
for threshold, scheme in ((1.0, "systematic"), (0.5, "stratified"), (0.5, "systematic")):
    for seed in (100, 101):
        out["runs"].append(compare(4096, threshold, scheme, seed, None))
out["runs"].append(compare(8192, 0.5, "systematic", 102, 2))
out["runs"].append(compare(1000, 1.0, "systematic", 103, None))

# rng.particle_blocks: the blocks of a draw, concatenated, are the whole draw (fast form and plain).
mesh = Mesh(np.array(jax.devices()), ("particles",))
def blocks(fn):
    def body(key):
        with rng.particle_blocks("particles", 6):
            return fn(key, (6, 3)), fn(key, (5,))  # the second is not a block: the same on every device
    return jax.jit(jax.shard_map(body, mesh=mesh, in_specs=P(), out_specs=(P("particles"), P("particles")), check_vma=False))
key = jax.random.PRNGKey(7)
for plain in (False, True):
    fastmath.use_plain_forms(plain)
    for name, fn, ref in (
        ("normal", rng.normal, jax.random.normal),
        ("uniform", lambda k, s: rng.uniform(k, s, minval=-2.0, maxval=3.0), lambda k, s: jax.random.uniform(k, s, minval=-2.0, maxval=3.0)),
        ("bits", rng.bits, jax.random.bits),
    ):
        whole, other = blocks(fn)(key)
        # bit for bit, or (the plain form's floats, which another program computes) the largest relative difference
        diff = lambda a, b: 0.0 if np.array_equal(a, b) else float(np.max(np.abs(a / b - 1)))
        out["draws"][f"{name}-{'plain' if plain else 'fast'}"] = [
            diff(np.asarray(whole), np.asarray(ref(key, (24, 3)))),
            diff(np.asarray(other), np.tile(np.asarray(ref(key, (5,))), 4)),
        ]
    fastmath.use_plain_forms(False)

# the gradient of the log-likelihood (stop-gradient resampling) through the spread filter, against run's
from jaxnav import calibration
from jaxnav.models import landmarks as lm
config = mcl.MCLConfig(num_particles=4096, ess_threshold=0.5)
state = mcl.init(jax.random.PRNGKey(0), config, params, start, jnp.full(3, 0.3))
def log_lik(sd, spread):
    p = params._replace(sensor=lm.RangeBearingNoise(sd))
    if spread:
        return mcl.run_sharded(jax.random.PRNGKey(5), state, config, p, controls, obs)[1].log_likelihood.sum()
    return calibration.log_likelihood(mcl.kernel, jax.random.PRNGKey(5), state, config, p, controls, obs)
out["gradients"] = [np.asarray(jax.grad(log_lik)(params.sensor.sd, spread)).tolist() for spread in (False, True)]

config = mcl.MCLConfig(num_particles=30)
state = mcl.init(jax.random.PRNGKey(0), config, params, start, jnp.full(3, 0.3))
try:
    mcl.run_sharded(jax.random.PRNGKey(0), state, config, params, controls, obs)
except ValueError as e:
    out["errors"].append(str(e))
print("RESULT " + json.dumps(out))
"""


@pytest.fixture(scope="module")
def child():
    return child_process.run(_CHILD, devices=4, timeout=600)


def test_whole_rows_per_device_carry_the_unsharded_particles(child):
    whole_rows = [r for r in child["runs"] if r["case"][0] % 4096 == 0]
    assert len(whole_rows) == 7
    for r in whole_rows:
        # bit for bit as measured with this XLA and these flags (the module docstring): a failure here
        # on another XLA is a weight rounded differently, to be read with the tolerances below
        assert r["particles"] and r["log_weights"] and r["resampled"], r
        assert r["spread_over"] == (r["case"][4] or 4), r
        # sums over devices in another order: the unsharded values up to float rounding
        assert r["ess_rel"] < 1e-5 and r["estimate"] < 1e-4 and r["log_likelihood"] < 1e-4, r
    conditional = [r for r in whole_rows if r["case"][1] < 1.0]
    assert conditional and all(0 < r["times_resampled"] < 25 for r in conditional)  # the decisions were tested


def test_the_log_likelihood_gradient_is_run_s(child):
    """The ancestors' log-weights travel with them (stop-gradient resampling): the gradient through the
    spread filter is the unsharded one, up to the order of the sums."""
    single, spread = (np.asarray(g) for g in child["gradients"])
    assert np.all(np.isfinite(single)) and np.all(single != 0)
    np.testing.assert_allclose(spread, single, rtol=1e-3)


def test_smaller_blocks_agree_to_the_filter_s_accuracy(child):
    (r,) = [r for r in child["runs"] if r["case"][0] == 1000]
    # 250 particles per device: a weight rounded differently can move an ancestor, and the clouds
    # then differ by Monte Carlo noise, well below the filter's error (tens of mm)
    assert r["estimate"] < 0.05, r


def test_particle_blocks_are_blocks_of_the_whole_draw(child):
    assert set(child["draws"]) == {f"{n}-{m}" for n in ("normal", "uniform", "bits") for m in ("fast", "plain")}
    for name, differences in child["draws"].items():
        # the fast form hashes each device's own counters: exact; the plain form slices jax.random's
        # whole draw, whose floats XLA:CPU may round differently in another program (one ulp measured
        # for normals under the suite's unoptimised compilation)
        assert (
            max(differences) == 0.0 if name.endswith("fast") or name.startswith("bits") else max(differences) < 1e-6
        ), (
            name,
            differences,
        )


def test_particles_must_divide_over_the_devices(child):
    (message,) = child["errors"]
    assert "num_particles (30)" in message and "4 devices" in message


def _setting(num_particles=64, **kw):
    start = jnp.asarray([5.0, 1.5, 0.0])
    _, params = demo_setting(10)
    controls = trajectories.loop_controls(12, 0.5, 0.21, 0.25)
    sim = landmark_world.simulate(
        jax.random.PRNGKey(1), params.landmarks, start, controls, params.motion, params.sensor
    )
    config = mcl.MCLConfig(num_particles=num_particles, **kw)
    state = mcl.init(jax.random.PRNGKey(0), config, params, start, jnp.full(3, 0.3))
    return state, config, params, controls, sim.observations


def test_one_device_is_run():
    state, config, params, controls, obs = _setting(ess_threshold=0.5)
    key = jax.random.PRNGKey(5)
    want = mcl.run(key, state, config, params, controls, obs)
    got = mcl.run_sharded(key, state, config, params, controls, obs, devices=1)
    for a, b in zip(jax.tree_util.tree_leaves(want), jax.tree_util.tree_leaves(got), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.parametrize(
    "change, words",
    [
        ({"resampling": "multinomial"}, "cannot be spread over devices"),
        ({"gaussian_refresh": True}, "gaussian_refresh"),
    ],
)
def test_what_cannot_be_spread_is_refused_by_name(change, words):
    state, config, params, controls, obs = _setting(**change)
    with pytest.raises(ValueError, match=words):
        mcl.run_sharded(jax.random.PRNGKey(5), state, config, params, controls, obs, devices=1)


def test_bad_input_is_refused_as_run_refuses_it():
    state, config, params, controls, obs = _setting()
    with pytest.raises(ValueError, match="controls"):
        mcl.run_sharded(jax.random.PRNGKey(5), state, config, params, controls[:, :2], obs, devices=1)
    with pytest.raises(ValueError, match="devices"):
        mcl.run_sharded(jax.random.PRNGKey(5), state, config, params, controls, obs, devices=0)


def _one_step_on_one_device(config, params):
    mesh = Mesh(np.asarray(jax.local_devices()[:1]), (sharded.PARTICLE_AXIS,))
    blocks = mcl.MCLState(P(sharded.PARTICLE_AXIS), P(sharded.PARTICLE_AXIS))
    step = lambda key, state, control, obs: mcl.sharded_kernel(key, state, config, params, control, obs)  # noqa: E731
    return jax.jit(
        jax.shard_map(step, mesh=mesh, in_specs=(P(), blocks, P(), P()), out_specs=(blocks, P()), check_vma=False)
    )


def test_the_sharded_kernel_keeps_its_state_on_inputs_outside_the_domain():
    """Inside a caller's trace the host checks cannot see values: a negative time step leaves the
    particles as they were and is flagged, as :func:`mcl.kernel` does."""
    state, config, params, controls, obs = _setting()
    step = _one_step_on_one_device(config, params)
    first = jax.tree_util.tree_map(lambda x: x[0], obs)
    moved, info = step(jax.random.PRNGKey(3), state, controls[0], first)
    kept, flagged = step(jax.random.PRNGKey(3), state, controls[0].at[2].set(-0.1), first)
    assert not bool(info.invalid_inputs) and bool(flagged.invalid_inputs)
    assert not np.array_equal(np.asarray(moved.particles), np.asarray(state.particles))
    np.testing.assert_array_equal(np.asarray(kept.particles), np.asarray(state.particles))


def test_the_sharded_kernel_refuses_a_gaussian_refresh():
    state, config, params, controls, obs = _setting(gaussian_refresh=True)
    first = jax.tree_util.tree_map(lambda x: x[0], obs)
    with pytest.raises(ValueError, match="gaussian_refresh"):
        _one_step_on_one_device(config, params)(jax.random.PRNGKey(3), state, controls[0], first)
