"""W2 mcl-step: one Monte Carlo localization step on N pose particles.

The workload: velocity motion with Gaussian noise
sd ``(0.02 m, 0.02 m, 0.01 rad)``, ``v = 0.5 m/s, ω = 0.1 rad/s, Δt = 0.1 s``;
8 landmarks on the border of a 10 m square (:func:`square_room_landmarks(10, 8)`),
each observed every step by range-bearing (sd ``0.1 m, 0.05 rad``); Gaussian
log-likelihood summed over the 8; ``logsumexp`` normalisation; ESS; systematic
resampling every step. Median seconds per step over T = 50 steps,
N = 1e3, 1e4, 1e5, 1e6 (``--quick``: 1e3, 1e4).

Data
----
One trajectory from :func:`jaxnav.sim.landmark_world.simulate` (key 0, start
pose ``(5, 5, 0)``, controls ``(0.5, 0.1, 0.1)`` for 50 steps, the W2 noise
as the true noise), shared by every implementation. The initial particles come
from :func:`jaxnav.localization.mcl.init` (key 1, sd ``(0.05, 0.05, 0.02)``)
and are handed to the peers as NumPy arrays.

Implementations
---------------
* ``jaxnav`` ``per_call``: the public :func:`mcl.step` (host-side validation,
  then the jitted step) called 50 times from Python; median of the per-step
  times (each ``block_until_ready`` on the new state and info).
* ``jaxnav-nocheck`` ``per_call``: the same with the internal
  ``mcl.step.jitted`` (no validation), to expose the validation overhead.
* ``jaxnav`` ``in_scan``: :func:`mcl.run` over the 50 steps (one ``lax.scan``),
  time / 50.
* ``jaxnav-plain`` ``in_scan``: the same ``mcl.run`` with the library's CPU
  fast paths switched off (:func:`jaxnav.core.fastmath.use_plain_forms`):
  ``jax.random`` draws, ``jnp.sin``/``cos``/``arctan2`` and ``jnp.cumsum``. Its
  ratio to the ``jaxnav`` row is what those paths buy on the machine that runs
  the benchmark (they were chosen on XLA:CPU; another machine may differ).
* ``jax-baseline`` ``in_scan``: a hand-written plain-JAX ``lax.scan`` of the
  same model (Euler motion, no guards, no pose estimate,
  ``jnp.searchsorted``). Not a peer: it shows what plain JAX reaches on the
  machine that runs the benchmark.
* ``numpy`` ``per_call``: :class:`benchmarks.peers.numpy_mcl.NumpyMCL`,
  float32, vectorised, Euler motion.
* ``filterpy`` ``per_call``: the same NumPy step with
  ``filterpy.monte_carlo.systematic_resample`` as the resampler (a Python
  loop), capped by a time budget.
* ``particles`` ``per_call``: a ``particles.FeynmanKac`` bootstrap model run
  by ``particles.SMC(fk, N, resampling="systematic", ESSrmin=1.0)``; one
  ``next(alg)`` for ``t ≥ 1`` is one step (resample, move, weigh); ``t = 0``
  (no resampling) is left out of the median.

jaxnav's velocity model moves along the exact arc (``sinc`` form) and its
step also computes the weighted-mean pose estimate; the peers use the
Euler motion of the workload's definition and skip the estimate, so jaxnav does
slightly more arithmetic per step than they do.

Floor
-----
Bytes that must move once per step, ``b`` the float size (4, jaxnav's
float32), int32 indices::

    motion:     particles read + written       2 · 3 · N · b
    weights:    log-weights written + read     2 · N · b
    resampling: indices written                N · 4
    gather:     particles read + written       2 · 3 · N · b
    total       = N · (14 · b + 4)  = 60 · N bytes for float32

``floor_s = total / bandwidth`` (the same on every row of a size).
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable

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

NAME = "W2"
T = 50
POSE_SD = (0.02, 0.02, 0.01)
SENSOR_SD = (0.1, 0.05)
CONTROL = (0.5, 0.1, 0.1)  # v [m/s], ω [rad/s], Δt [s]
START = (5.0, 5.0, 0.0)
INIT_SD = (0.05, 0.05, 0.02)
FLOAT_BYTES = 4  # jaxnav float32
FLOOR_DOC = (
    "N * (14*b + 4) bytes per step, b = 4 (float32): particles (3 floats) read+written by the motion "
    "(6Nb), log-weights written+read (2Nb), int32 indices written (4N), particles gathered read+written "
    "(6Nb); = 60 N bytes; / measured bandwidth"
)


def floor_bytes(n: int, b: int = FLOAT_BYTES) -> int:
    """Bytes one W2 step must move once: ``N · (2·3·b + 2·b + 4 + 2·3·b) = N · (14·b + 4)``.

    Motion reads and writes the particles (3 floats each), the log-weights are
    written and read back, the int32 resampling indices are written, and the
    gather reads and writes the particles again.
    """
    motion = 2 * 3 * n * b
    log_weights = 2 * n * b
    indices = n * 4
    gather = 2 * 3 * n * b
    return motion + log_weights + indices + gather


# ---------------------------------------------------------------------------
# shared data


_DATA_CACHE: dict = {}


def _world():
    """Landmarks, controls, simulated observations (shared by all N)."""
    if "world" in _DATA_CACHE:
        return _DATA_CACHE["world"]
    from jaxnav.models.landmarks import RangeBearingNoise
    from jaxnav.models.motion import VelocityNoise
    from jaxnav.sim.landmark_world import simulate, square_room_landmarks

    landmarks = square_room_landmarks(10.0, 8)
    controls = jnp.tile(jnp.asarray(CONTROL, jnp.float32), (T, 1))
    motion_noise = VelocityNoise(alphas=jnp.zeros((6,), jnp.float32), pose_sd=jnp.asarray(POSE_SD, jnp.float32))
    sensor_noise = RangeBearingNoise(jnp.asarray(SENSOR_SD, jnp.float32))
    sim = simulate(jax.random.key(0), landmarks, jnp.asarray(START, jnp.float32), controls, motion_noise, sensor_noise)
    sim = jax.block_until_ready(sim)
    _DATA_CACHE["world"] = (landmarks, motion_noise, sensor_noise, sim)
    return _DATA_CACHE["world"]


def _per_step_timing(
    start: Callable[[], Callable[[int], object]],
    *,
    passes: int,
    budget_s: float,
    first: int = 0,
    min_steps: int = 5,
) -> Timing:
    """Median per-step time over ``passes`` runs of steps ``first … T−1``.

    ``start()`` resets the filter and returns ``step(t)``, which performs step
    ``t`` and blocks until it is done. Stops early once ``budget_s`` of timed
    steps is spent (after at least ``min_steps`` steps).
    """
    samples: list[float] = []
    spent = 0.0
    with _GcOff():
        for _ in range(passes):
            step = start()
            for t in range(first, T):
                t0 = time.perf_counter()
                step(t)
                dt = time.perf_counter() - t0
                samples.append(dt)
                spent += dt
                if spent >= budget_s and len(samples) >= min_steps:
                    return Timing.from_samples(samples)
    return Timing.from_samples(samples)


# ---------------------------------------------------------------------------
# jaxnav


def _config_params(n: int):
    from jaxnav.localization import mcl

    landmarks, motion_noise, sensor_noise, _ = _world()
    config = mcl.MCLConfig(num_particles=n, motion_model="velocity", resampling="systematic", ess_threshold=1.0)
    params = mcl.MCLParams(motion_noise, sensor_noise, landmarks)
    return config, params


def _initial_state(n: int):
    """jaxnav's initial particles (key 1), shared with every implementation."""
    from jaxnav.localization import mcl

    config, params = _config_params(n)
    return jax.block_until_ready(
        mcl.init(jax.random.key(1), config, params, jnp.asarray(START, jnp.float32), jnp.asarray(INIT_SD, jnp.float32))
    )


def _jaxnav_inputs(n: int):
    """Per-step keys, controls and observations, sliced on the device before any timing."""
    from jaxnav.models.landmarks import RangeBearingObs

    _, _, _, sim = _world()
    run_key = jax.random.key(2)
    keys = [jax.random.fold_in(run_key, t) for t in range(T)]
    ctrls = [sim.controls[t] for t in range(T)]
    obs = [RangeBearingObs(sim.observations.ids[t], sim.observations.z[t], sim.observations.mask[t]) for t in range(T)]
    return jax.block_until_ready((run_key, keys, ctrls, obs))


def _jaxnav_per_call(ctx: Context, size: dict, n: int, state0, floor_s: float, impl: str) -> dict:
    """``mcl.step`` (impl ``jaxnav``) or ``mcl.step.jitted`` (``jaxnav-nocheck``) called once per step."""
    from jaxnav.localization import mcl

    config, params = _config_params(n)
    _, keys, ctrls, obs = _jaxnav_inputs(n)
    fn = mcl.step if impl == "jaxnav" else mcl.step.jitted
    # Both per_call rows share one executable: compiled (and timed) once.
    compile_s = ctx.compile_s((NAME, "step", n), mcl.step.jitted, keys[0], state0, config, params, ctrls[0], obs[0])
    jax.block_until_ready(fn(keys[0], state0, config, params, ctrls[0], obs[0]))  # warm-up

    def start():
        box = [state0]

        def step(t):
            new_state, info = fn(keys[t], box[0], config, params, ctrls[t], obs[t])
            jax.block_until_ready((new_state, info))
            box[0] = new_state

        return step

    big = n >= 10**6
    t = _per_step_timing(start, passes=ctx.reps(1 if big else 3), budget_s=20.0 if big else 30.0)
    return make_row(
        NAME,
        impl,
        size,
        "per_call",
        t,
        compile_s=compile_s,
        floor_s=floor_s,
        dtype="float32",
        steps=t.repeats,
        note="public mcl.step (host-side validation + jitted step)"
        if impl == "jaxnav"
        else "internal mcl.step.jitted, no validation",
    )


def _jaxnav_in_scan(ctx: Context, size: dict, n: int, state0, floor_s: float, plain: bool = False) -> dict:
    """``mcl.run`` over the 50 steps (one ``lax.scan``), time / 50; ``plain``: the same with the
    library's CPU fast paths off (:func:`benchmarks.harness.plain_forms`), the row ``jaxnav-plain``."""
    from jaxnav.localization import mcl

    _, _, _, sim = _world()
    config, params = _config_params(n)
    run_key = jax.random.key(2)
    args = (run_key, state0, config, params, sim.controls, sim.observations)
    with plain_forms() if plain else contextlib.nullcontext():
        compile_s = ctx.compile_s((NAME, "run-plain" if plain else "run", n), mcl.run.jitted, *args)
        fn = lambda: jax.block_until_ready(mcl.run(*args))
        big = n >= 10**6
        # At 1e6 one run takes tens of seconds: no separate warm-up (the executable is compiled and cached).
        t = time_calls(fn, repeats=ctx.reps(3 if big else 10), warmup=0 if big else 1, budget_s=60.0, min_repeats=2)
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
        note="mcl.run over 50 steps, time / 50" + (PLAIN_NOTE if plain else ""),
    )


def _baseline_rows(ctx: Context, size: dict, n: int, state0, floor_s: float) -> list[dict]:
    """Hand-written plain-JAX lax.scan of W2 (no guards), the reference of what plain JAX reaches."""
    landmarks, _, _, sim = _world()
    pose_sd = jnp.asarray(POSE_SD, jnp.float32)
    sd = jnp.asarray(SENSOR_SD, jnp.float32)
    log_norm = -math.log(SENSOR_SD[0]) - math.log(SENSOR_SD[1]) - math.log(2 * math.pi)

    def step(carry, inputs):
        x, lw = carry
        key, u, z = inputs
        k1, k2 = jax.random.split(key)
        v, w, dt = u[0], u[1], u[2]
        th = x[:, 2]
        move = jnp.stack([v * dt * jnp.cos(th), v * dt * jnp.sin(th), jnp.broadcast_to(w * dt, th.shape)], -1)
        x = x + move + jax.random.normal(k1, x.shape, x.dtype) * pose_sd
        dx = landmarks[None, :, 0] - x[:, None, 0]
        dy = landmarks[None, :, 1] - x[:, None, 1]
        rr = (z[None, :, 0] - jnp.sqrt(dx * dx + dy * dy)) / sd[0]
        rb = z[None, :, 1] - (jnp.arctan2(dy, dx) - x[:, None, 2])
        rb = (rb - 2 * jnp.pi * jnp.round(rb / (2 * jnp.pi))) / sd[1]
        ll = jnp.sum(log_norm - 0.5 * (rr * rr + rb * rb), axis=1)
        lw = lw + ll
        lse = jax.scipy.special.logsumexp(lw)
        lw = lw - lse
        wts = jnp.exp(lw)
        ess = 1.0 / jnp.sum(wts * wts)
        cdf = jnp.cumsum(wts)
        pts = (jax.random.uniform(k2, (), x.dtype) + jnp.arange(n, dtype=x.dtype)) / n
        idx = jnp.minimum(jnp.searchsorted(cdf, pts, side="right"), n - 1)
        x = x[idx]
        lw = jnp.full((n,), -math.log(n), lw.dtype)
        return (x, lw), (lse, ess)

    @jax.jit
    def run(key, x0, lw0, controls, zs):
        keys = jax.vmap(lambda t: jax.random.fold_in(key, t))(jnp.arange(controls.shape[0]))
        return jax.lax.scan(step, (x0, lw0), (keys, controls, zs))

    args = (jax.random.key(3), state0.particles, state0.log_weights, sim.controls, sim.observations.z)
    compile_s = ctx.compile_s((NAME, "baseline", n), run, *args)
    fn = lambda: jax.block_until_ready(run(*args))
    big = n >= 10**6
    t = time_calls(fn, repeats=ctx.reps(3 if big else 10), warmup=0 if big else 1, budget_s=60.0, min_repeats=2)
    return [
        make_row(
            NAME,
            "jax-baseline",
            size,
            "in_scan",
            t.per(T),
            compile_s=compile_s,
            floor_s=floor_s,
            steps=T,
            dtype="float32",
            note="hand-written plain-JAX lax.scan (not a peer; STYLE.md item 14)",
        )
    ]


# ---------------------------------------------------------------------------
# peers


def _peer_inputs(state0):
    landmarks, _, _, sim = _world()
    return (
        np.asarray(state0.particles),
        np.asarray(landmarks),
        np.asarray(sim.controls),
        np.asarray(sim.observations.z),
    )


def _numpy_row(ctx: Context, size: dict, n: int, state0, floor_s: float, cls_name: str = "numpy") -> dict:
    from benchmarks.peers import numpy_mcl

    x0, lm, controls, zs = _peer_inputs(state0)
    if cls_name == "numpy":
        cls, budget, note = numpy_mcl.NumpyMCL, 30.0, "vectorised NumPy, float32, Euler motion"
    else:
        mod, why = optional_import("filterpy.monte_carlo")
        if mod is None:
            return skipped_row(NAME, "filterpy", size, "per_call", why)
        cls, budget = numpy_mcl.FilterpyMCL, 12.0
        note = "NumPy float32 motion+likelihood, filterpy.monte_carlo.systematic_resample (Python loop); 12 s budget"

    filters = []

    def start():
        pf = cls(x0, lm, POSE_SD, SENSOR_SD, seed=7, dtype=numpy_mcl.DEFAULT_DTYPE)
        filters.append(pf)

        def step(t):
            pf.step(controls[t], zs[t])

        return step

    np.random.seed(8)  # filterpy's resampler draws from the global generator
    warm = start()
    warm(0)  # warm-up (first-touch of the buffers)
    big = n >= 10**6
    t = _per_step_timing(start, passes=ctx.reps(1 if n >= 10**5 else 3), budget_s=budget)
    extra = {}
    if cls_name == "filterpy":
        extra["index_errors"] = sum(pf.index_errors for pf in filters)  # redrawn resamplings, see FilterpyMCL
    return make_row(
        NAME,
        cls_name,
        size,
        "per_call",
        t,
        floor_s=floor_s,
        dtype="float32",
        steps=t.repeats,
        note=note + ("" if t.repeats >= T or not big else f"; {t.repeats} steps timed"),
        **extra,
    )


_particles_warm = False


def _particles_row(ctx: Context, size: dict, n: int, state0, floor_s: float) -> dict:
    global _particles_warm
    particles, why = optional_import("particles")
    if particles is None:
        return skipped_row(NAME, "particles", size, "per_call", why)
    from benchmarks.peers import numpy_mcl

    x0, lm, controls, zs = _peer_inputs(state0)
    np.random.seed(9)  # particles' resamplers draw from the global generator

    def make_alg(x0_, n_):
        fk = numpy_mcl.make_particles_fk(particles, x0_, controls, zs, lm, POSE_SD, SENSOR_SD, seed=10)
        return particles.SMC(fk=fk, N=n_, resampling="systematic", ESSrmin=1.0)

    if not _particles_warm:  # numba compiles inverse_cdf on first use: not timed
        warm = make_alg(x0[:16], 16)
        for _ in range(3):
            next(warm)
        _particles_warm = True

    def start():
        alg = make_alg(x0, n)
        next(alg)  # t = 0: M0 + logG, no resampling; not timed

        def step(t):
            next(alg)

        return step

    t = _per_step_timing(start, passes=ctx.reps(1 if n >= 10**5 else 3), budget_s=30.0, first=1)
    return make_row(
        NAME,
        "particles",
        size,
        "per_call",
        t,
        floor_s=floor_s,
        dtype="float32 particles, float64 weights",
        steps=t.repeats,
        note="particles.SMC(FeynmanKac, resampling='systematic', ESSrmin=1.0), next(alg) per step",
    )


def run(ctx: Context, size: dict) -> list[dict]:
    n = int(size["N"])
    floor_s = ctx.floor(floor_bytes(n))
    state0 = _initial_state(n)
    rows = []
    for impl in ("jaxnav", "jaxnav-nocheck"):
        rows += guarded(
            ctx, NAME, impl, size, "per_call", lambda impl=impl: _jaxnav_per_call(ctx, size, n, state0, floor_s, impl)
        )
    rows += guarded(ctx, NAME, "jaxnav", size, "in_scan", lambda: _jaxnav_in_scan(ctx, size, n, state0, floor_s))
    rows += guarded(
        ctx,
        NAME,
        "jaxnav-plain",
        size,
        "in_scan",
        lambda: _jaxnav_in_scan(ctx, size, n, state0, floor_s, plain=True),
    )
    rows += guarded(ctx, NAME, "jax-baseline", size, "in_scan", lambda: _baseline_rows(ctx, size, n, state0, floor_s))
    rows += guarded(ctx, NAME, "numpy", size, "per_call", lambda: _numpy_row(ctx, size, n, state0, floor_s, "numpy"))
    rows += guarded(
        ctx, NAME, "filterpy", size, "per_call", lambda: _numpy_row(ctx, size, n, state0, floor_s, "filterpy")
    )
    rows += guarded(ctx, NAME, "particles", size, "per_call", lambda: _particles_row(ctx, size, n, state0, floor_s))
    return rows


register(
    Workload(
        name=NAME,
        title="W2 MCL step, 8 landmarks (time per step)",
        sizes=[{"N": 10**3}, {"N": 10**4}, {"N": 10**5}, {"N": 10**6}],
        run=run,
        x_key="N",
        floor_doc=FLOOR_DOC,
    )
)
