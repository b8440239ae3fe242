"""Two kinds of bad input refused at every entry point, before anything is computed or allocated.

* **Keys.** Every public function that takes a PRNG key (a filter's ``init``, ``step`` and ``run``,
  the simulators, batch Monte Carlo, the experiment registry and its sweep) refuses a raw key of
  the wrong length, a batch of keys and ``None`` with a ``ValueError`` naming the argument; the
  deterministic filters' ``init`` accept ``None``. The table of calls is checked against the
  modules themselves, so a new function taking a key must be added here.
* **Memory.** A filter whose state or run, or a Monte Carlo chunk, would exceed the device's
  memory is refused with the estimate, the limit and the configuration fields that size it
  (:mod:`jaxnav.core.memory`); the opt-out lets it through.
"""

from __future__ import annotations

import importlib
import inspect
import os
import re
import subprocess
import sys
import textwrap
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav import calibration
from jaxnav.core import batch, memory, weights
from jaxnav.core import filter as filter_api
from jaxnav.core.particle_filter import finish_step
from jaxnav.demo import demo_setting
from jaxnav.experiments import registry, sweep
from jaxnav.experiments.hf_slam import readings
from jaxnav.localization import augmented_mcl, ekf, grid, ir_mcl, kld_mcl, mcl, rfid_anchor, rfid_tag, ukf
from jaxnav.models import hf_rfid
from jaxnav.models import uhf_rfid as U
from jaxnav.models.motion import OmniNoise
from jaxnav.sim import ir_receiver, ir_world, landmark_world, tag_carpet, trajectories, uhf_reader
from jaxnav.slam import ekf_slam, fastslam, pf_slam, ps_slam, tag_slam

POSE = jnp.asarray([5.0, 1.5, 0.0])
COV = jnp.diag(jnp.asarray([1e-3, 1e-3, 1e-4]))

BAD_KEYS = {
    "raw-length-3": np.zeros(3, np.uint32),
    "raw-length-4": np.zeros(4, np.uint32),
    "raw-batch": np.zeros((5, 2), np.uint32),
    "typed-batch": jax.random.split(jax.random.key(0), 5),
    "none": None,
}

FILTER_MODULES = (
    augmented_mcl,
    ekf,
    grid,
    ir_mcl,
    kld_mcl,
    mcl,
    rfid_anchor,
    rfid_tag,
    ukf,
    ekf_slam,
    fastslam,
    pf_slam,
    ps_slam,
)
SEARCHED = (*FILTER_MODULES, tag_slam, ir_receiver, ir_world, landmark_world, tag_carpet, trajectories, uhf_reader)
SEARCHED_NAMES = [m.__name__ for m in SEARCHED] + [
    "jaxnav.core.batch",
    "jaxnav.experiments.registry",
    "jaxnav.experiments.sweep",
    "jaxnav.experiments.hf_slam.readings",
    "jaxnav.calibration",
]
KERNEL_PARTS = {"kernel", "sharded_kernel", "move_and_weight", "resample", "slam_step", "log_likelihood"}
"""Pure pieces of a step, for use inside a caller's trace; they take the key a checked ``step`` gave them."""


def _landmark_params():
    return demo_setting(10)[1]


def _tag_params():
    return pf_slam.PFSLAMParams(OmniNoise(jnp.full(3, 0.01)), hf_rfid.reader_params(0.06))


def _calls() -> dict[str, tuple[Any, tuple, dict, bool]]:
    """``name -> (function, arguments after the key, keyword arguments, None accepted)``, one
    valid call per public function that takes a key (the key passed first, or as ``key=``)."""
    p = _landmark_params()
    bounds = (0.0, 10.0, 0.0, 10.0)
    ap = augmented_mcl.AugmentedMCLParams(p.motion, p.sensor, p.landmarks, jnp.asarray(bounds))
    layout = ir_world.experiment_layout()
    ir_config = ir_mcl.IRMCLConfig(num_particles=16)
    tag_params = rfid_tag.default_params(gamma=U.GammaParams(20.0, 0.05))
    anchors = np.asarray([[0.0, 0.0, 1.0], [2.0, 0.0, 1.0], [0.0, 3.0, 1.0]], np.float32)
    anchor_params = rfid_anchor.default_params(anchors, gamma=U.GammaParams(20.0, 0.05))
    hf = _tag_params()
    ps = ps_slam.PSSLAMParams(hf.motion, hf.sensor, tag_jitter_sd=jnp.asarray(0.015))
    mc, kc = mcl.MCLConfig(num_particles=16), kld_mcl.KLDMCLConfig(max_particles=32, min_particles=8)
    ac = augmented_mcl.AugmentedMCLConfig(num_particles=16)
    tc = rfid_tag.RFIDTagConfig(num_particles=16)
    poses = np.asarray(ir_world.polyline_path(ir_world.EXPERIMENT_WAYPOINTS, speed=0.2, dt=0.1, num_steps=4))
    receiver = ir_receiver.default_params()
    calls = {
        "mcl.init": (mcl.init, (mc, p, POSE), {}, False),
        "mcl.init_uniform": (mcl.init_uniform, (mc, p, bounds), {}, False),
        "mcl.run_sharded": (lambda key: mcl.run_sharded(key, None, mc, p, None, None, devices=1), (), {}, False),
        "calibration.fit": (lambda key: calibration.fit(lambda k, q: 0.0, key, p, steps=1), (), {}, False),
        "kld_mcl.init": (kld_mcl.init, (kc, p, POSE), {}, False),
        "kld_mcl.init_uniform": (kld_mcl.init_uniform, (kc, p, bounds), {}, False),
        "augmented_mcl.init": (augmented_mcl.init, (ac, ap, POSE), {}, False),
        "augmented_mcl.init_uniform": (augmented_mcl.init_uniform, (ac, ap), {}, False),
        "ekf.init": (ekf.init, (ekf.EKFConfig(), p, POSE, COV), {}, True),
        "ukf.init": (ukf.init, (ukf.UKFConfig(), p, POSE, COV), {}, True),
        "grid.init": (grid.init, (grid.GridConfig(bounds, 10, 10, 8), p), {}, True),
        "ir_mcl.init": (ir_mcl.init, (ir_config, ir_mcl.default_params(ir_config, layout), (0, 4, 0, 4)), {}, False),
        "rfid_tag.init": (rfid_tag.init, (tc, tag_params), {}, False),
        # the key is checked before the reads: these never get read
        "rfid_tag.run_tags": (rfid_tag.run_tags, (tc, tag_params, None), {}, False),
        "rfid_tag.run_tags_jitted": (rfid_tag.run_tags_jitted, (tc, tag_params, None, None), {}, False),
        "rfid_anchor.init": (
            rfid_anchor.init,
            (rfid_anchor.RFIDAnchorConfig(num_particles=16), anchor_params),
            {},
            False,
        ),
        "ekf_slam.init": (
            ekf_slam.init,
            (ekf_slam.EKFSLAMConfig(num_landmarks=4), ekf_slam.EKFSLAMParams(p.motion, p.sensor), POSE, COV),
            {},
            True,
        ),
        "fastslam.init": (
            fastslam.init,
            (
                fastslam.FastSLAMConfig(num_particles=8, num_landmarks=4),
                fastslam.FastSLAMParams(p.motion, p.sensor),
                POSE,
            ),
            {},
            False,
        ),
        "pf_slam.init": (pf_slam.init, (pf_slam.PFSLAMConfig(8, 8, 16), hf, POSE), {}, False),
        "pf_slam.run_sharded": (
            lambda key: pf_slam.run_sharded(key, None, pf_slam.PFSLAMConfig(8, 8, 16), hf, None, None, devices=1),
            (),
            {},
            False,
        ),
        "ps_slam.run_sharded": (
            lambda key: ps_slam.run_sharded(key, None, ps_slam.PSSLAMConfig(8, 8, 16, lag=3), ps, None, None),
            (),
            {},
            False,
        ),
        "tag_slam.run_sharded": (
            lambda key: tag_slam.run_sharded(
                pf_slam.run, pf_slam.kernel, key, None, pf_slam.PFSLAMConfig(8, 8, 16), hf, None, None
            ),
            (),
            {},
            False,
        ),
        "ps_slam.init": (ps_slam.init, (ps_slam.PSSLAMConfig(8, 8, 16, lag=3), ps, POSE), {}, False),
        "tag_slam.initial_particles": (
            tag_slam.initial_particles,
            (pf_slam.PFSLAMConfig(8, 8, 16), POSE, None),
            {},
            False,
        ),
        "landmark_world.simulate": (
            landmark_world.simulate,
            (p.landmarks, POSE, trajectories.loop_controls(4, 0.5, 0.21, 0.25), p.motion, p.sensor),
            {},
            False,
        ),
        "ir_world.simulate": (ir_world.simulate, (layout, poses, 0.1), {}, False),
        "tag_carpet.make_carpet": (tag_carpet.make_carpet, ((1.0, 1.0),), {"density": 16.0}, False),
        "tag_carpet.simulate": (
            tag_carpet.simulate,
            (
                tag_carpet.make_carpet(jax.random.PRNGKey(3), (1.0, 1.0), density=16.0),
                hf.sensor,
                POSE,
                np.tile([[0.2, 0.0, 0.0, 0.5]], (4, 1)),
                np.full(3, 0.01),
            ),
            {},
            False,
        ),
        "tag_carpet.kidnapping_scenario": (
            tag_carpet.kidnapping_scenario,
            (None, hf.sensor, np.full(3, 0.01)),
            {},
            False,
        ),
        "trajectories.random_controls": (trajectories.random_controls, (), {"num_steps": 4}, False),
        "uhf_reader.simulate_reads": (
            uhf_reader.simulate_reads,
            (np.zeros((4, 4), np.float32) + [0, 0, 0.5, 0], np.asarray([[1.0, 1.0, 0.8]], np.float32)),
            {},
            False,
        ),
        # key=None means "along direction" there: only the other bad keys apply
        "uhf_reader.anchor_position": (uhf_reader.anchor_position, (), {"tag": [1.0, 1.0, 0.8], "distance": 0.5}, True),
        "ir_receiver.sample_waveform": (ir_receiver.sample_waveform, (np.zeros(3), layout, receiver), {}, False),
        "ir_receiver.detect": (ir_receiver.detect, (np.zeros(3), layout, receiver), {}, False),
        "ir_receiver.calibration_sweep": (ir_receiver.calibration_sweep, (receiver,), {}, False),
        "batch.monte_carlo": (batch.monte_carlo, (), {"fn": lambda k: jnp.zeros(2), "num_runs": 2}, False),
        "batch.run_keys": (batch.run_keys, (), {"num_runs": 2}, False),
        "batch.scan_filter": (
            batch.scan_filter,
            (),
            {
                "step": None,
                "config": None,
                "params": None,
                "controls": jnp.zeros((2, 1)),
                "observations": jnp.zeros((2, 1)),
                "state": None,
            },
            True,
        ),
        "registry.run": (registry.run, (), {"name": "table-3.1", "runs": 1}, False),
        "sweep.sweep": (sweep.sweep, (), {"cells": [], "runs": 1}, False),
        "sweep.cell_key": (sweep.cell_key, (), {"cell_id": "a"}, False),
        "sweep.run_key": (sweep.run_key, (), {"cell_id": "a", "r": 0}, False),
        # the key is checked before the setting is read
        "readings.tuning_grid": (readings.tuning_grid, (None, (0.1,), (5,), 1), {}, False),
    }
    for mod in FILTER_MODULES:
        for name in ("step", "run"):
            fn = getattr(mod, name)
            config = calls[f"{mod.__name__.rsplit('.', 1)[1]}.init"][1][0]
            others = [None] * (len(inspect.signature(fn).parameters) - 3 - (name == "run"))
            calls[f"{mod.__name__.rsplit('.', 1)[1]}.{name}"] = (
                lambda key, *a, _fn=fn, _config=config, _others=others: _fn(key, None, _config, *_others),
                (),
                {},
                fn in (ekf.step, ekf.run, ukf.step, ukf.run, grid.step, grid.run, ekf_slam.step, ekf_slam.run),
            )
    return calls


_CALLS: dict | None = None


def calls() -> dict[str, tuple[Any, tuple, dict, bool]]:
    global _CALLS
    if _CALLS is None:
        _CALLS = _calls()
    return _CALLS


def test_every_public_function_taking_a_key_is_in_the_table():
    """Found from the modules' signatures: a new function that takes a key fails this until it is added."""
    found = set()
    for module_name in SEARCHED_NAMES:
        module = importlib.import_module(module_name)
        for name, fn in vars(module).items():
            if name.startswith("_") or name in KERNEL_PARTS or not callable(fn) or isinstance(fn, type):
                continue
            if getattr(fn, "__module__", None) != module.__name__:
                continue
            try:
                parameters = inspect.signature(fn).parameters
            except (TypeError, ValueError):
                continue
            if "key" in parameters:
                found.add(f"{module_name.rsplit('.', 1)[1]}.{name}")
    missing = found - set(calls())
    assert not missing, f"functions taking a key that no test here calls: {sorted(missing)}"


@pytest.mark.parametrize("kind", list(BAD_KEYS))
def test_every_entry_point_refuses_a_bad_key_by_name(kind):
    bad = BAD_KEYS[kind]
    failures = []
    for name, (fn, args, kwargs, none_ok) in calls().items():
        if bad is None and none_ok:
            continue
        try:
            if args or not kwargs:
                fn(bad, *args, **kwargs)
            else:  # all by keyword
                fn(**kwargs, key=bad)
        except ValueError as err:
            if not str(err).startswith("key must be"):
                failures.append(f"{name}: ValueError not naming the key first: {err}")
        except Exception as err:  # noqa: BLE001  (any other kind is the failure this test looks for)
            failures.append(f"{name}: {type(err).__name__}: {str(err)[:200]}")
        else:
            failures.append(f"{name}: accepted")
    assert not failures, f"{len(failures)} of {len(calls())} entry points:\n" + "\n".join(failures)


def test_the_deterministic_filters_accept_none_as_the_key_but_not_a_batch_of_keys():
    p = _landmark_params()
    for mod, config in ((ekf, ekf.EKFConfig()), (ukf, ukf.UKFConfig())):
        assert mod.init(None, config, p, POSE, COV).mean.shape == (3,)
        with pytest.raises(ValueError, match=r"^key must be one PRNG key .* shape \(5, 2\)"):
            mod.init(BAD_KEYS["raw-batch"], config, p, POSE, COV)


def test_a_tracer_key_inside_jit_and_vmap_still_works_and_is_shape_checked():
    p, c = _landmark_params(), mcl.MCLConfig(num_particles=8)
    keys = jax.random.split(jax.random.PRNGKey(0), 3)
    states = jax.vmap(lambda k: mcl.init(k, c, p, POSE, jnp.full(3, 0.1)))(keys)
    assert states.particles.shape == (3, 8, 3)
    np.testing.assert_array_equal(states.particles[1], mcl.init(keys[1], c, p, POSE, jnp.full(3, 0.1)).particles)
    with pytest.raises(ValueError, match=r"^key must be one PRNG key .* shape \(4,\)"):
        jax.jit(lambda k: mcl.init(k, c, p, POSE).particles)(np.zeros(4, np.uint32))


# --------------------------------------------------------------------------- memory


_CHILD = """
import resource
resource.setrlimit(resource.RLIMIT_AS, (__LIMIT__, __LIMIT__))
import jax, jax.numpy as jnp, numpy as np
from jaxnav.core import batch
from jaxnav.demo import demo_setting
from jaxnav.localization import kld_mcl, mcl
from jaxnav.models import hf_rfid
from jaxnav.models.motion import OmniNoise
from jaxnav.slam import ekf_slam, fastslam, pf_slam, ps_slam

key = jax.random.PRNGKey(0)
_, p = demo_setting(10)
pose = jnp.asarray([5.0, 1.5, 0.0])
hf = pf_slam.PFSLAMParams(OmniNoise(jnp.full(3, 0.01)), hf_rfid.reader_params(0.06))
ps = ps_slam.PSSLAMParams(hf.motion, hf.sensor, tag_jitter_sd=jnp.asarray(0.015))
small = mcl.init(key, mcl.MCLConfig(num_particles=64), p, pose)  # a normal filter runs under this limit
print("SMALL", small.particles.shape, flush=True)
cases = {
    "mcl": lambda: mcl.init(key, mcl.MCLConfig(num_particles=2**31), p, pose),
    "mcl-uniform": lambda: mcl.init_uniform(key, mcl.MCLConfig(num_particles=2**31), p, (0, 10, 0, 10)),
    "kld": lambda: kld_mcl.init(key, kld_mcl.KLDMCLConfig(max_particles=2**30), p, pose),
    "fastslam": lambda: fastslam.init(
        key, fastslam.FastSLAMConfig(num_particles=100, num_landmarks=2**22), fastslam.FastSLAMParams(p.motion, p.sensor), pose
    ),
    "ekf_slam": lambda: ekf_slam.init(
        None, ekf_slam.EKFSLAMConfig(num_landmarks=2**15), ekf_slam.EKFSLAMParams(p.motion, p.sensor), pose, jnp.eye(3)
    ),
    "pf_slam": lambda: pf_slam.init(key, pf_slam.PFSLAMConfig(max_tags=2**24), hf, pose),
    "ps_slam": lambda: ps_slam.init(key, ps_slam.PSSLAMConfig(max_tags=2**22), ps, pose),
    "monte_carlo": lambda: batch.monte_carlo(lambda k: jnp.zeros((1000, 1000)), key, 10_000),
    "monte_carlo-chunk": lambda: batch.monte_carlo(lambda k: jnp.zeros((1000, 1000)), key, 10_000, chunk_size=5_000),
}
for name, call in cases.items():
    try:
        call()
    except ValueError as err:
        print(f"REFUSED {name}: {err}", flush=True)
    except BaseException as err:
        print(f"FAILED {name}: {type(err).__name__}: {err}", flush=True)
    else:
        print(f"ACCEPTED {name}", flush=True)
"""

EXPECTED = {
    "mcl": r"mcl\.init .* 32 GiB .*MCLConfig\.num_particles \(2147483648\)",
    "mcl-uniform": r"mcl\.init_uniform .* 32 GiB .*MCLConfig\.num_particles \(2147483648\)",
    "kld": r"kld_mcl\.init .* 16 GiB .*KLDMCLConfig\.max_particles \(1073741824\)",
    "fastslam": r"fastslam\.init .* GiB .*FastSLAMConfig\.num_particles \(100\), FastSLAMConfig\.num_landmarks \(4194304\)",
    "ekf_slam": r"ekf_slam\.init .* 16 GiB .*EKFSLAMConfig\.num_landmarks \(32768\)",
    "pf_slam": r"pf_slam\.init .* GiB .*PFSLAMConfig\.max_tags \(16777216\)",
    "ps_slam": r"ps_slam\.init .* GiB .*PSSLAMConfig\.max_tags \(4194304\), PSSLAMConfig\.lag \(20\)",
    "monte_carlo": r"monte_carlo chunk of 10000 runs .* GiB .*chunk_size \(None: all 10000 runs at once\)",
    "monte_carlo-chunk": r"monte_carlo chunk of 5000 runs .* GiB .*chunk_size \(5000\)",
}


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="RLIMIT_AS caps a process's memory on Linux")
def test_oversized_configurations_are_refused_without_allocating_them():
    """In a child capped at 3 GiB of address space: a small filter runs, and every oversized request
    is refused with a ValueError naming its fields, the estimate and the limit; none is allocated
    (the child would die or raise MemoryError/XLA's RESOURCE_EXHAUSTED otherwise)."""
    env = {k: v for k, v in os.environ.items() if k != memory.ENV_VAR}
    env["JAX_PLATFORMS"] = "cpu"
    code = textwrap.dedent(_CHILD).replace("__LIMIT__", str(3 * 2**30))
    child = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    out = child.stdout
    assert child.returncode == 0, f"the child died (status {child.returncode}):\n{out}\n{child.stderr[-3000:]}"
    assert "SMALL (64, 3)" in out, out
    lines = {line.split(" ", 2)[1].rstrip(":"): line for line in out.splitlines() if line.split(" ")[0] != "SMALL"}
    for name, pattern in EXPECTED.items():
        line = lines.get(name, f"(no line for {name})")
        assert line.startswith(f"REFUSED {name}:"), line
        assert "address-space limit" in line and "more than the 3 GiB" in line, line
        assert "allow_large_allocations" in line, line
        assert re.search(pattern, line), f"{pattern!r} not in {line}"


def _tiny_limit(monkeypatch, nbytes: int = 4096) -> None:
    monkeypatch.setattr(memory, "limit_bytes", lambda device=None: (nbytes, "a device of 4 KiB"))
    monkeypatch.delenv(memory.ENV_VAR, raising=False)


def test_the_opt_out_lets_an_init_above_the_limit_through(monkeypatch):
    _tiny_limit(monkeypatch)
    p, c, key = _landmark_params(), mcl.MCLConfig(num_particles=1024), jax.random.PRNGKey(0)
    with pytest.raises(
        ValueError,
        match=r"mcl\.init \(the state it returns\) would need about 16 KiB \(16384 bytes\), more than the "
        r"4 KiB of a device of 4 KiB: lower MCLConfig\.num_particles \(1024\)",
    ):
        mcl.init(key, c, p, POSE)
    with memory.allow_large_allocations():
        assert mcl.init(key, c, p, POSE).particles.shape == (1024, 3)
    with pytest.raises(ValueError, match="would need about 16 KiB"):  # the block is over
        mcl.init(key, c, p, POSE)
    monkeypatch.setenv(memory.ENV_VAR, "1")
    assert mcl.init(key, c, p, POSE).particles.shape == (1024, 3)


@dataclass(frozen=True)
class WalkConfig:  # no SIZE_FIELDS: its integer fields are named
    num_particles: int = 64


class WalkState(NamedTuple):
    particles: jax.Array
    log_weights: jax.Array


def _walk_kernel(key, state, config, params, control, observation):
    moved = state.particles + control + 0.1 * jax.random.normal(key, state.particles.shape)
    res, info = finish_step(key, moved, weights.normalize(state.log_weights - 0.5 * (observation - moved[:, 0]) ** 2))
    return WalkState(res.particles, res.log_weights), info


def test_a_run_above_the_limit_is_refused_once_measured_and_the_measure_is_memoised(monkeypatch):
    _, walk_run = filter_api.build(filter_api.FilterSpec(name="walk", kernel=_walk_kernel, config_type=WalkConfig))
    config, key = WalkConfig(), jax.random.PRNGKey(0)
    state = WalkState(jnp.zeros((64, 1)), jnp.full((64,), -jnp.log(64.0)))
    u, z = jnp.full(8, 0.1), jnp.linspace(0.1, 0.8, 8)
    _tiny_limit(monkeypatch, 1024)
    measured = []
    tree_bytes = memory.tree_bytes
    monkeypatch.setattr(memory, "tree_bytes", lambda tree: measured.append(1) or tree_bytes(tree))
    with pytest.raises(
        ValueError,
        match=r"walk run over 8 steps \(the initial and final states and the trace\) would need about "
        r".* KiB .*: lower WalkConfig\.num_particles \(64\) or the number of steps per call",
    ):
        walk_run(key, state, config, None, u, z)
    assert measured, "the run was not measured"
    count = len(measured)
    with pytest.raises(ValueError, match="walk run over 8 steps"):
        walk_run(jax.random.PRNGKey(1), state, config, None, u + 1, z)  # same shapes: not measured again
    assert len(measured) == count
    with memory.allow_large_allocations():
        final, trace = walk_run(key, state, config, None, u, z)
    assert trace.estimate.shape[0] == 8 and final.particles.shape == (64, 1)
    assert walk_run.trace_count() == 1, "the measure must share its trace with the run"


def test_a_monte_carlo_chunk_above_the_limit_is_refused_and_a_smaller_one_runs(monkeypatch):
    """XLA's account of the compiled chunk (inputs, outputs, working memory: about 33 KiB for 32 runs
    of 64 normals, 9 KiB for 8) against a limit of 16 KiB; ``fn`` is traced once for all of it."""
    _tiny_limit(monkeypatch, 16 * 1024)
    traces = []

    def fn(k):
        traces.append(1)
        return jax.random.normal(k, (64,))

    with pytest.raises(
        ValueError,
        match=r"monte_carlo chunk of 32 runs \(its inputs, outputs and XLA's working memory\) would need about "
        r"3\d\.\d KiB .*more than the 16 KiB of a device of 4 KiB: lower chunk_size \(32\)",
    ):
        batch.monte_carlo(fn, jax.random.PRNGKey(0), 64, chunk_size=32)
    with pytest.raises(ValueError, match=r"lower chunk_size \(None: all 64 runs at once\)"):
        batch.monte_carlo(fn, jax.random.PRNGKey(0), 64)
    traces.clear()
    out = batch.monte_carlo(fn, jax.random.PRNGKey(0), 64, chunk_size=8)
    assert out.shape == (64, 64) and len(traces) == 1
    with pytest.raises(ValueError, match=r"monte_carlo chunk of 64 runs \(its inputs and outputs\) .* 16.5 KiB"):
        batch.monte_carlo(fn, jax.random.PRNGKey(0), 64, chunk_size=64, jit=False)  # 64 × 256 + 512 bytes
    with memory.allow_large_allocations():
        assert batch.monte_carlo(fn, jax.random.PRNGKey(0), 64, chunk_size=64, jit=False).shape == (64, 64)


def test_the_limit_is_the_device_memory_or_what_this_process_may_use():
    limit = memory.limit_bytes()
    assert limit is not None and limit[0] > 2**20
    device = jax.devices()[0]
    stats = device.memory_stats()
    if stats and stats.get("bytes_limit"):
        assert limit[0] == stats["bytes_limit"]
    else:
        host = memory.host_memory_bytes()
        assert limit == host
        assert host[0] <= os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
