"""W4 kf-batch: a linear Kalman filter over B independent sequences of T = 1000 steps.

Model (the same as ``tests/core/test_kalman.py``): 4-D
constant-velocity state ``(x, y, vx, vy)`` [m, m, m/s, m/s], Δt = 0.1 s,

* ``x_t = A x_{t−1} + w``, ``A = [[I, Δt I], [0, I]]``,
  ``w ~ N(0, Q)``, ``Q = q [[Δt³/3 I, Δt²/2 I], [Δt²/2 I, Δt I]]``,
  ``q = 0.05 m²/s³`` (white-noise acceleration);
* ``z_t = C x_t + v``, ``C = [I 0]`` (2-D position), ``v ~ N(0, R)``,
  ``R = diag(0.3², 0.2²)`` m².

Inputs, generated once with NumPy (``default_rng(0)``, float64, cast to each
implementation's dtype): for each of the B sequences a true start (position
uniform in ±5 m, velocity N(0, 1) m/s), the filter's initial covariance
``P0_b = s_b² diag(1, 1, 0.5, 0.5)`` with ``s_b ~ U(0.5, 2)`` — different
per sequence, so no implementation can share one covariance recursion
across the batch — and ``m0_b`` drawn from ``N(x0_b, P0_b)``; then T steps
of the model. Each implementation filters all B sequences from
``(m0_b, P0_b)`` (predict, then update, at every step) and returns the
filtered means ``[B, T, 4]`` and each sequence's log-likelihood
``Σ_t log N(z_t; C x_t⁻, S_t)`` ``[B]``. ``median_s`` is seconds per batch;
``per_sequence_s = median_s / B``. Sizes B = 1, 100, 1000 (``--quick``: 1,
100), T = 1000.

Implementations
---------------
jaxnav, dynamax and numpy are timed in float32 and in float64 (one row each,
told apart by ``dtype``); the float64 JAX rows convert their inputs, compile
and run inside ``jax.enable_x64(True)``, the float32 rows inside
``jax.enable_x64(False)``, and every JAX row checks that its filtered means
come back in its dtype. Rows of a size are listed float64 first, so that the
floor line of the plot (one per B: the last row's) is the float32 floor.

* ``jaxnav`` ``in_scan``: ``jax.jit(jax.vmap(one sequence))``, one sequence a
  ``lax.scan`` over T of :func:`jaxnav.core.kalman.kalman_predict` and
  :func:`jaxnav.core.kalman.kalman_update` (Joseph form, Cholesky solves).
  ``compile_s`` is measured once per B and dtype. In float32 these run as
  unrolled scalar code, every matrix entry a ``[B]`` vector, which XLA:CPU
  fuses into elementwise loops over the batch; in float64 as small matrix
  products (the measurements behind that choice are in ``kalman.py``).
* ``numpy`` ``per_call``: :func:`benchmarks.peers.numpy_kf.numpy_kf_batch`,
  vectorised over B, a Python loop over T, Joseph form.
* ``filterpy`` ``per_call``: ``filterpy.kalman.KalmanFilter`` per sequence and
  step (float64 only, Joseph form, its ``log_likelihood`` property each step). At
  B > :data:`FILTERPY_SUBSET` only the first ``FILTERPY_SUBSET`` sequences
  are timed and the time is scaled by ``B / FILTERPY_SUBSET`` (the work is
  exactly linear in B: one independent Python loop per sequence); the row
  says so in ``extrapolated_from``.
* ``dynamax`` ``in_scan``: ``jax.jit(jax.vmap(lgssm_filter))`` of
  ``dynamax.linear_gaussian_ssm`` (standard-form covariance update
  ``P − K S Kᵀ``; ``pip install -e '.[bench]'`` installs it), skipped with
  the reason when dynamax is not importable. dynamax conditions on ``z_0``
  before its first prediction, so it is given the predicted prior
  ``(A m0_b, A P0_b Aᵀ + Q)``: the same filter.

Floor
-----
Bytes that must move once for one batch, ``b`` bytes per number (4 for the
float32 rows, 8 for the float64 rows, filterpy's included)::

    observations read        B · T · 2 · b
    filtered means written   B · T · 4 · b
    log-likelihoods written  B · b
    m0, P0 read              B · (4 + 16) · b
    total                    = B · b · (6 T + 21)

``floor_s = total / bandwidth``. The Kalman recursion is compute- and
latency-bound (≈ 300 flops per sequence and step on 4×4 and 2×2 matrices,
T dependent steps), so every implementation is far above this floor.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.harness import Context, guarded, make_row, skipped_row, time_calls
from benchmarks.peers import optional_import
from benchmarks.workloads import Workload, register

NAME = "W4"
T = 1000
DT = 0.1  # s
ACCEL_PSD = 0.05  # q, m²/s³
OBS_SD = (0.3, 0.2)  # m
FLOAT_BYTES = 4
DTYPES = ("float64", "float32")  # the order of the rows of a size
FILTERPY_SUBSET = 5
FLOOR_DOC = (
    "B * b * (6 T + 21) bytes per batch, b = 4 (float32 rows) or 8 (float64 rows): observations read (2 T), "
    "filtered means written (4 T), log-likelihood written (1), m0 and P0 read (4 + 16), per sequence; "
    "/ measured bandwidth"
)

__all__ = [
    "KFInputs",
    "model",
    "make_inputs",
    "floor_bytes",
    "jaxnav_filter",
    "dynamax_filter",
    "jax_args",
]


def floor_bytes(b: int, t: int = T, nbytes: int = FLOAT_BYTES) -> int:
    """Bytes one W4 batch must move once: ``B · b · (2T + 4T + 1 + 4 + 16)``."""
    return b * nbytes * (2 * t + 4 * t + 1 + 4 + 16)


# ---------------------------------------------------------------------------
# model and data


def model(dtype=np.float64) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(A [4,4], Q [4,4], C [2,4], R [2,2])`` of the constant-velocity model."""
    a = np.eye(4)
    a[0, 2] = a[1, 3] = DT
    q = ACCEL_PSD * np.array(
        [[DT**3 / 3, 0, DT**2 / 2, 0], [0, DT**3 / 3, 0, DT**2 / 2], [DT**2 / 2, 0, DT, 0], [0, DT**2 / 2, 0, DT]]
    )
    c = np.zeros((2, 4))
    c[0, 0] = c[1, 1] = 1.0
    r = np.diag(np.square(OBS_SD))
    return tuple(x.astype(dtype) for x in (a, q, c, r))


class KFInputs(NamedTuple):
    """W4 inputs (float64): ``m0 [B, 4]``, ``p0 [B, 4, 4]``, ``zs [B, T, 2]``, and the true states ``xs [B, T, 4]``."""

    m0: np.ndarray
    p0: np.ndarray
    zs: np.ndarray
    xs: np.ndarray


def make_inputs(b: int, t: int = T, seed: int = 0) -> KFInputs:
    """Simulate ``b`` independent sequences of ``t`` steps of the W4 model (NumPy, seeded)."""
    a, q, c, r = model()
    rng = np.random.default_rng(seed)
    x = np.concatenate([rng.uniform(-5.0, 5.0, (b, 2)), rng.normal(0.0, 1.0, (b, 2))], axis=1)
    scale = rng.uniform(0.5, 2.0, b)
    p0 = np.zeros((b, 4, 4))
    p0[:, np.arange(4), np.arange(4)] = scale[:, None] ** 2 * np.array([1.0, 1.0, 0.5, 0.5])
    m0 = x + rng.standard_normal((b, 4)) * np.sqrt(np.diagonal(p0, axis1=1, axis2=2))
    lq, lr = np.linalg.cholesky(q), np.linalg.cholesky(r)
    zs = np.empty((b, t, 2))
    xs = np.empty((b, t, 4))
    for k in range(t):
        x = x @ a.T + rng.standard_normal((b, 4)) @ lq.T
        xs[:, k] = x
        zs[:, k] = x @ c.T + rng.standard_normal((b, 2)) @ lr.T
    return KFInputs(m0, p0, zs, xs)


_CACHE: dict = {}


def _inputs(b: int) -> KFInputs:
    if b not in _CACHE:
        _CACHE.clear()  # keep one batch in memory
        _CACHE[b] = make_inputs(b)
    return _CACHE[b]


# ---------------------------------------------------------------------------
# jaxnav (public primitives)


def _batch_run(update):
    """``jit(vmap(scan over T of kalman_predict + update))`` → ``(means [B,T,n], log_lik [B])``."""
    from jaxnav.core.kalman import Gaussian, kalman_predict

    def run(m0, p0, zs, a, q, c, r):
        def one(m, p, z_seq):
            def body(g, z):
                prior = kalman_predict(g.mean, g.cov, a, q)
                res = update(prior.mean, prior.cov, z, c, r)
                return Gaussian(res.mean, res.cov), (res.mean, res.log_likelihood)

            _, (means, lls) = jax.lax.scan(body, Gaussian(m, p), z_seq)
            return means, jnp.sum(lls)

        return jax.vmap(one)(m0, p0, zs)

    return jax.jit(run)


_JITTED: dict = {}


def jaxnav_filter():
    """The jitted ``jaxnav`` batch filter ``(m0, p0, zs, A, Q, C, R) -> (means, log_lik)``."""
    if "jaxnav" not in _JITTED:
        from jaxnav.core.kalman import kalman_update

        _JITTED["jaxnav"] = _batch_run(kalman_update)
    return _JITTED["jaxnav"]


def dynamax_filter():
    """The jitted, vmapped dynamax ``lgssm_filter`` (same signature), or ``(None, reason)`` if not importable."""
    if "dynamax" in _JITTED:
        return _JITTED["dynamax"], None
    mod, why = optional_import("dynamax.linear_gaussian_ssm")
    if mod is None:
        return None, why

    def run(m0, p0, zs, a, q, c, r):
        n, mdim = a.shape[0], c.shape[0]
        dyn = mod.ParamsLGSSMDynamics(
            weights=a, bias=jnp.zeros(n, a.dtype), input_weights=jnp.zeros((n, 0), a.dtype), cov=q
        )
        emi = mod.ParamsLGSSMEmissions(
            weights=c, bias=jnp.zeros(mdim, c.dtype), input_weights=jnp.zeros((mdim, 0), c.dtype), cov=r
        )

        def one(m, p, z_seq):
            # dynamax conditions on z_0 first: give it the predicted prior of step 1
            init = mod.ParamsLGSSMInitial(mean=a @ m, cov=a @ p @ a.T + q)
            post = mod.lgssm_filter(mod.ParamsLGSSM(init, dyn, emi), z_seq, jnp.zeros((z_seq.shape[0], 0), z_seq.dtype))
            return post.filtered_means, post.marginal_loglik

        return jax.vmap(one)(m0, p0, zs)

    _JITTED["dynamax"] = jax.jit(run)
    return _JITTED["dynamax"], None


# ---------------------------------------------------------------------------
# rows


def jax_args(inp: KFInputs, dtype=jnp.float32):
    """``(m0, p0, zs, A, Q, C, R)`` as device arrays of ``dtype``, the arguments of the jitted filters."""
    arrays = (inp.m0, inp.p0, inp.zs) + model()
    return jax.block_until_ready(tuple(jnp.asarray(x, dtype) for x in arrays))


def _reps(ctx: Context, b: int) -> int:
    return ctx.reps(10 if b <= 100 else 5)


def _x64(dtype: str):
    """float64 rows run inside ``jax.enable_x64(True)``, float32 rows inside ``jax.enable_x64(False)``."""
    return jax.enable_x64(dtype == "float64")


def _jax_row(ctx: Context, size: dict, impl: str, fn, inp: KFInputs, dtype: str, floor_s: float, note: str) -> dict:
    """Time the jitted ``fn`` on ``inp`` converted to ``dtype`` (the caller holds the x64 setting)."""
    b = int(size["B"])
    args = jax_args(inp, jnp.dtype(dtype))
    compile_s = ctx.compile_s((NAME, impl, dtype, b), fn, *args)  # before any call: a compiled call is cached
    means, _ = jax.block_until_ready(fn(*args))
    if means.dtype != jnp.dtype(dtype):
        raise TypeError(f"{impl} returned {means.dtype} filtered means for {dtype} inputs")
    call = lambda: jax.block_until_ready(fn(*args))
    t = time_calls(call, repeats=_reps(ctx, b), warmup=1, budget_s=30.0, min_repeats=3)
    return make_row(
        NAME,
        impl,
        size,
        "in_scan",
        t,
        compile_s=compile_s,
        floor_s=floor_s,
        per_sequence_s=t.median_s / b,
        dtype=dtype,
        note=note,
    )


def _numpy_row(ctx: Context, size: dict, inp: KFInputs, dtype: str, floor_s: float) -> dict:
    from benchmarks.peers.numpy_kf import numpy_kf_batch

    b = int(size["B"])
    a, q, c, r = model()
    m0, p0, zs = (np.asarray(x, dtype) for x in (inp.m0, inp.p0, inp.zs))
    t = time_calls(
        lambda: numpy_kf_batch(m0, p0, zs, a, q, c, r, dtype=np.dtype(dtype).type),
        repeats=_reps(ctx, b),
        warmup=1,
        budget_s=30.0,
        min_repeats=3,
    )
    return make_row(
        NAME,
        "numpy",
        size,
        "per_call",
        t,
        floor_s=floor_s,
        per_sequence_s=t.median_s / b,
        dtype=dtype,
        note="vectorised over B, Python loop over T, Joseph form",
    )


def _filterpy_row(ctx: Context, size: dict, inp: KFInputs, floor_s: float) -> dict:
    mod, why = optional_import("filterpy.kalman")
    if mod is None:
        return skipped_row(NAME, "filterpy", size, "per_call", why, dtype="float64")
    from benchmarks.peers.numpy_kf import filterpy_kf

    b = int(size["B"])
    sub = min(b, FILTERPY_SUBSET)
    a, q, c, r = model()
    seqs = list(range(sub))
    t = time_calls(
        lambda: filterpy_kf(inp.m0, inp.p0, inp.zs, a, q, c, r, seqs),
        repeats=ctx.reps(3),
        warmup=0,
        budget_s=10.0,
        min_repeats=2,
    )
    scale = b / sub
    extra = {"extrapolated_from": sub} if sub < b else {}
    return make_row(
        NAME,
        "filterpy",
        size,
        "per_call",
        None,
        median_s=t.median_s * scale,
        floor_s=floor_s,
        min_s=t.min_s * scale,
        repeats=t.repeats,
        per_sequence_s=t.median_s / sub,
        dtype="float64",
        note="KalmanFilter.predict/update + log_likelihood per step, Python loops over sequences and T"
        + (f"; {sub} of {b} sequences timed, time x {scale:g}" if sub < b else ""),
        **extra,
    )


def _dynamax_row(ctx: Context, size: dict, inp: KFInputs, dtype: str, floor_s: float) -> dict:
    fn, why = dynamax_filter()
    if fn is None:
        return skipped_row(NAME, "dynamax", size, "in_scan", why, dtype=dtype)
    return _jax_row(
        ctx,
        size,
        "dynamax",
        fn,
        inp,
        dtype,
        floor_s,
        "jit(vmap(dynamax.linear_gaussian_ssm.lgssm_filter)), standard-form update P - K S K^T",
    )


def _in_x64(dtype: str, fn):
    """``fn`` run inside the x64 setting of ``dtype``."""

    def run():
        with _x64(dtype):
            return fn()

    return run


def run(ctx: Context, size: dict) -> list[dict]:
    b = int(size["B"])
    if int(size["T"]) != T:
        raise ValueError(f"W4 is defined for T = {T}")
    inp = _inputs(b)
    x64_before = bool(jax.config.jax_enable_x64)
    rows = []
    for dtype in DTYPES:
        floor_s = ctx.floor(floor_bytes(b, nbytes=np.dtype(dtype).itemsize))
        rows += guarded(
            ctx,
            NAME,
            "jaxnav",
            size,
            "in_scan",
            _in_x64(
                dtype,
                lambda: _jax_row(
                    ctx,
                    size,
                    "jaxnav",
                    jaxnav_filter(),
                    inp,
                    dtype,
                    floor_s,
                    "jit(vmap(lax.scan of kalman_predict + kalman_update))",
                ),
            ),
        )
        rows += guarded(ctx, NAME, "numpy", size, "per_call", lambda: _numpy_row(ctx, size, inp, dtype, floor_s))
        if dtype == "float64":
            rows += guarded(ctx, NAME, "filterpy", size, "per_call", lambda: _filterpy_row(ctx, size, inp, floor_s))
        rows += guarded(
            ctx, NAME, "dynamax", size, "in_scan", _in_x64(dtype, lambda: _dynamax_row(ctx, size, inp, dtype, floor_s))
        )
    if bool(jax.config.jax_enable_x64) != x64_before:
        raise RuntimeError(f"W4 changed jax_enable_x64 from {x64_before} to {jax.config.jax_enable_x64}")
    return rows


register(
    Workload(
        name=NAME,
        title="W4 linear KF, 4-D CV state, T = 1000 (time per batch of B sequences)",
        sizes=[{"B": 1, "T": T}, {"B": 100, "T": T}, {"B": 1000, "T": T}],
        run=run,
        x_key="B",
        floor_doc=FLOOR_DOC,
        series_key="dtype",
    )
)
