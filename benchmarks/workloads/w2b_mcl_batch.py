"""W2b mcl-batch: one step of R independent W2 filters at once, the shape of a Monte Carlo study.

The workload: the W2 model (:mod:`benchmarks.workloads.w2_mcl`:
Euler/velocity motion with noise sd ``(0.02 m, 0.02 m, 0.01 rad)``, 8
landmarks on a 10 m square observed by range-bearing with sd ``(0.1 m,
0.05 rad)``, ``logsumexp`` normalisation, ESS, systematic resampling every
step), R = 100 independent runs of N = 1,000 particles each, every run with its
own data and keys. Median seconds per step of all R runs together, T = 50
steps. Sizes ``{R: 10, N: 1000}`` and ``{R: 100, N: 1000}`` (``--quick``: both).

Data
----
R trajectories from :func:`jaxnav.sim.landmark_world.simulate`, run ``r`` with
the key ``fold_in(key(0), r)`` (one ``vmap`` at setup), the W2 start pose
``(5, 5, 0)``, controls ``(0.5, 0.1, 0.1)`` for 50 steps and the W2 noise as
the true noise. Run ``r``'s initial particles come from
:func:`jaxnav.localization.mcl.init` with the key ``fold_in(key(1), r)`` (sd
``(0.05, 0.05, 0.02)``) and are handed to the peers as NumPy arrays; jaxnav's
run ``r`` uses the key ``fold_in(key(2), r)``.

Implementations
---------------
* ``jaxnav`` ``in_scan``: :func:`jaxnav.core.batch.compiled_vmap` (the
  library's ``jax.jit(jax.vmap(fn))``, compiled once and cached) of
  ``mcl.run.jitted`` over the runs: one compiled program runs the 50-step
  ``lax.scan`` of all R filters; time / 50. ``compile_s`` is that
  program's compile time.
* ``jaxnav-plain`` ``in_scan``: the same program traced with the library's CPU
  fast paths off (as W2's row of that name).
* ``numpy`` ``per_call``: :class:`benchmarks.peers.numpy_mcl_batch.NumpyMCLBatch`,
  float32 ``[R, N]`` arrays, one NumPy call per operation for all runs and
  every row resampled by one ``searchsorted`` over the row-shifted cumulative
  sums; median of the per-step times.
* ``particles`` ``per_call``: ``particles.multiSMC`` with one
  ``FeynmanKac`` model per run (a ``dict`` of R models, ``nruns=1``,
  ``nprocs=1``, ``resampling="systematic"``, ``ESSrmin=1``), each the W2
  model of :func:`benchmarks.peers.numpy_mcl.make_particles_fk` on its own
  data; the runs are done one after the other, the library's way of running R
  independent SMCs in one process. Time of the whole call / 50 (``particles``
  does the first move and weighting without a resampling, so 49 resamplings
  per run instead of 50).

jaxnav moves along the exact arc (``sinc`` form) and computes each run's
weighted-mean pose; the peers use Euler motion and skip the estimate (see W2).

Floor
-----
R times the bytes of one W2 step (:func:`benchmarks.workloads.w2_mcl.floor_bytes`),
``R · N · (14 · b + 4) = 60 · R · N`` bytes for float32; ``floor_s = bytes /
bandwidth``, the same on every row of a size.
"""

from __future__ import annotations

import contextlib
import time
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.harness import (
    PLAIN_NOTE,
    Context,
    Timing,
    _GcOff,
    guarded,
    make_row,
    plain_forms,
    skipped_row,
    time_calls,
)
from benchmarks.peers import optional_import
from benchmarks.workloads import Workload, register
from benchmarks.workloads import w2_mcl as w2

NAME = "W2b"
T = w2.T
FLOOR_DOC = "R * N * (14*b + 4) bytes per step, b = 4 (float32): R times the W2 floor (60 R N bytes); / bandwidth"


def floor_bytes(r: int, n: int) -> int:
    """Bytes one step of the R runs must move once: R × the W2 floor of N particles (bytes)."""
    return r * w2.floor_bytes(n)


# ---------------------------------------------------------------------------
# data


_DATA_CACHE: dict = {}


def runs_world(r: int):
    """``(landmarks, motion_noise, sensor_noise, sims)``: R simulated runs, leaves with a leading ``[R]`` axis.

    Run ``i`` is :func:`jaxnav.sim.landmark_world.simulate` with the key ``fold_in(key(0), i)``,
    the W2 landmarks, start pose, controls and noise.
    """
    if ("world", r) in _DATA_CACHE:
        return _DATA_CACHE[("world", r)]
    from jaxnav.sim.landmark_world import simulate

    landmarks, motion_noise, sensor_noise, _ = w2._world()
    controls = jnp.tile(jnp.asarray(w2.CONTROL, jnp.float32), (T, 1))
    start = jnp.asarray(w2.START, jnp.float32)
    keys = fold_in_keys(0, r)
    sims = jax.vmap(lambda k: simulate(k, landmarks, start, controls, motion_noise, sensor_noise))(keys)
    _DATA_CACHE[("world", r)] = jax.block_until_ready((landmarks, motion_noise, sensor_noise, sims))
    return _DATA_CACHE[("world", r)]


def fold_in_keys(seed: int, r: int) -> jax.Array:
    """``[R]`` keys ``fold_in(key(seed), i)``, ``i = 0 … R − 1``."""
    return jax.vmap(lambda i: jax.random.fold_in(jax.random.key(seed), i))(jnp.arange(r))


def initial_states(r: int, n: int):
    """R initial MCL states (leaves ``[R, …]``): run ``i`` is ``mcl.init`` with the key ``fold_in(key(1), i)``."""
    if ("states", r, n) in _DATA_CACHE:
        return _DATA_CACHE[("states", r, n)]
    from jaxnav.localization import mcl

    config, params = w2._config_params(n)
    start = jnp.asarray(w2.START, jnp.float32)
    sd = jnp.asarray(w2.INIT_SD, jnp.float32)
    states = jax.vmap(lambda k: mcl.init(k, config, params, start, sd))(fold_in_keys(1, r))
    _DATA_CACHE[("states", r, n)] = jax.block_until_ready(states)
    return _DATA_CACHE[("states", r, n)]


# ---------------------------------------------------------------------------
# jaxnav


_RUN_ONE: dict = {}


def run_one(n: int, plain: bool = False):
    """``f(key, state, controls, observations, params) = mcl.run.jitted(key, state, config, params, …)`` for N.

    One function object per N (and per ``plain``: the ``jaxnav-plain`` row's program is traced with the
    fast paths off), so that :func:`jaxnav.core.batch.compiled_vmap` (which caches on the function)
    compiles each batched program once.
    """
    if (n, plain) not in _RUN_ONE:
        from jaxnav.localization import mcl

        config, _ = w2._config_params(n)

        def f(key, state, controls, observations, params):
            return mcl.run.jitted(key, state, config, params, controls, observations)

        _RUN_ONE[n, plain] = f
    return _RUN_ONE[n, plain]


class _CompiledVmap:
    """:func:`jaxnav.core.batch.compiled_vmap` behind the ``.lower(*args).compile()`` that
    :meth:`Context.compile_s` times, so the compile time is measured once and the program is
    the one the library caches."""

    def __init__(self, fn, shared):
        self.fn, self.shared = fn, shared

    def lower(self, *args):
        from jaxnav.core import batch

        return SimpleNamespace(compile=lambda: batch.compiled_vmap(self.fn, *args, shared=self.shared))


def jaxnav_batched(r: int, n: int, ctx: Context | None = None, plain: bool = False):
    """``(run_all, compile_s)``: ``run_all()`` steps all R runs through the T steps and returns
    ``(final_states, traces)`` with a leading ``[R]`` axis (not blocked).

    ``compile_s`` is measured through ``ctx`` (None without one).
    """
    from jaxnav.core import batch

    _, _, _, sims = runs_world(r)
    _, params = w2._config_params(n)
    fn = run_one(n, plain)
    args = (fold_in_keys(2, r), initial_states(r, n), sims.controls, sims.observations)
    compile_s = None
    if ctx is not None:
        compile_s = ctx.compile_s((NAME, "run-plain" if plain else "run", r, n), _CompiledVmap(fn, (params,)), *args)
    exe = batch.compiled_vmap(fn, *args, shared=(params,))
    return (lambda: exe(*args, params)), compile_s


def _jaxnav_in_scan(ctx: Context, size: dict, r: int, n: int, floor_s: float, plain: bool = False) -> dict:
    """The batched ``mcl.run``; ``plain``: traced with the CPU fast paths off (row ``jaxnav-plain``)."""
    with plain_forms() if plain else contextlib.nullcontext():
        run_all, compile_s = jaxnav_batched(r, n, ctx, plain)
        fn = lambda: jax.block_until_ready(run_all())
        t = time_calls(fn, repeats=ctx.reps(10), warmup=1, budget_s=60.0, min_repeats=2)
    return make_row(
        NAME,
        "jaxnav-plain" if plain else "jaxnav",
        size,
        "in_scan",
        t.per(T),
        compile_s=compile_s,
        floor_s=floor_s,
        steps=T,
        dtype="float32",
        note=f"batch.compiled_vmap of mcl.run.jitted over {r} runs (one lax.scan of 50 steps), time / 50"
        + (PLAIN_NOTE if plain else ""),
    )


# ---------------------------------------------------------------------------
# peers


def peer_inputs(r: int, n: int):
    """NumPy ``(x0 [R, N, 3], landmarks [K, 2], controls [R, T, 3], zs [R, T, K, 2])``."""
    landmarks, _, _, sims = runs_world(r)
    states = initial_states(r, n)
    return (
        np.asarray(states.particles),
        np.asarray(landmarks),
        np.asarray(sims.controls),
        np.asarray(sims.observations.z),
    )


def _numpy_row(ctx: Context, size: dict, r: int, n: int, floor_s: float) -> dict:
    from benchmarks.peers.numpy_mcl_batch import DEFAULT_DTYPE, NumpyMCLBatch

    x0, lm, controls, zs = peer_inputs(r, n)
    # per-step inputs of all runs, contiguous, made before any timing
    ctrl_t = [np.ascontiguousarray(controls[:, t]) for t in range(T)]
    z_t = [np.ascontiguousarray(zs[:, t], dtype=DEFAULT_DTYPE) for t in range(T)]

    def start():
        pf = NumpyMCLBatch(x0, lm, w2.POSE_SD, w2.SENSOR_SD, seed=7, dtype=DEFAULT_DTYPE)

        def step(t):
            pf.step(ctrl_t[t], z_t[t])

        return step

    start()(0)  # warm-up (first touch of the buffers)
    t = w2._per_step_timing(start, passes=ctx.reps(3), budget_s=30.0)
    return make_row(
        NAME,
        "numpy",
        size,
        "per_call",
        t,
        floor_s=floor_s,
        dtype="float32",
        steps=t.repeats,
        note="NumpyMCLBatch: [R, N] float32 arrays, one searchsorted over row-shifted CDFs + one take per step",
    )


def _logLt(pf):
    return pf.logLt


def particles_fks(particles, x0, lm, controls, zs) -> dict:
    """One W2 ``FeynmanKac`` model per run (run ``i``'s particles, controls and observations; seed 10 + i)."""
    from benchmarks.peers import numpy_mcl

    return {
        i: numpy_mcl.make_particles_fk(particles, x0[i], controls[i], zs[i], lm, w2.POSE_SD, w2.SENSOR_SD, seed=10 + i)
        for i in range(x0.shape[0])
    }


def _particles_row(ctx: Context, size: dict, r: int, n: int, floor_s: float) -> dict:
    particles, why = optional_import("particles")
    if particles is None:
        return skipped_row(NAME, "particles", size, "per_call", why)
    x0, lm, controls, zs = peer_inputs(r, n)
    np.random.seed(9)  # particles seeds its global-generator resamplers from here

    def call(fks, n_):
        return particles.multiSMC(
            fk=fks, N=n_, nruns=1, nprocs=1, resampling="systematic", ESSrmin=1.0, out_func=_logLt
        )

    call(particles_fks(particles, x0[:2, :16], lm, controls[:2], zs[:2]), 16)  # numba compiles inverse_cdf: untimed
    samples: list[float] = []
    spent = 0.0
    with _GcOff():
        for _ in range(ctx.reps(3)):
            fks = particles_fks(particles, x0, lm, controls, zs)  # fresh models (random streams), untimed
            t0 = time.perf_counter()
            out = call(fks, n)
            dt = time.perf_counter() - t0
            samples.append(dt)
            spent += dt
            if len(out) != r:
                raise RuntimeError(f"multiSMC returned {len(out)} runs, expected {r}")
            if spent >= 60.0:
                break
    t = Timing.from_samples(samples)
    return make_row(
        NAME,
        "particles",
        size,
        "per_call",
        t.per(T),
        floor_s=floor_s,
        steps=T,
        dtype="float32 particles, float64 weights",
        note=f"particles.multiSMC(fk={{run: FeynmanKac}} x {r}, nruns=1, nprocs=1), per-run data; "
        "runs one after the other; whole call / 50",
    )


def run(ctx: Context, size: dict) -> list[dict]:
    r, n = int(size["R"]), int(size["N"])
    floor_s = ctx.floor(floor_bytes(r, n))
    rows = []
    rows += guarded(ctx, NAME, "jaxnav", size, "in_scan", lambda: _jaxnav_in_scan(ctx, size, r, n, floor_s))
    rows += guarded(
        ctx, NAME, "jaxnav-plain", size, "in_scan", lambda: _jaxnav_in_scan(ctx, size, r, n, floor_s, plain=True)
    )
    rows += guarded(ctx, NAME, "numpy", size, "per_call", lambda: _numpy_row(ctx, size, r, n, floor_s))
    rows += guarded(ctx, NAME, "particles", size, "per_call", lambda: _particles_row(ctx, size, r, n, floor_s))
    return rows


register(
    Workload(
        name=NAME,
        title="W2b MCL batch: R runs of N particles, one step of all runs (time per step)",
        sizes=[{"R": 10, "N": 1000}, {"R": 100, "N": 1000}],
        run=run,
        x_key="R",
        floor_doc=FLOOR_DOC,
    )
)
