"""W1 resample: systematic resampling of N normalised weights.

Weights ``w = exp(z) / Σ exp(z)``, ``z ~ N(0, 1)`` drawn once with
``np.random.default_rng(0)``; N = 1e3, 1e4, 1e5, 1e6 (``--quick``: 1e3, 1e4).
Median time per call.

Implementations
---------------
* ``jaxnav`` ``per_call``: ``jax.jit(lambda key, lw: systematic(key, lw, N))``
  on float32 log-weights ``log w`` (jaxnav's resamplers take log-weights and
  normalise them themselves), a fresh key each call.
* ``jaxnav`` ``in_scan``: one jitted ``lax.scan`` of ``S = 50`` calls, key
  ``fold_in(key, s)``; time / S. The weights are scanned over as ``xs``
  (``S`` copies, made outside the timed call) so that XLA cannot hoist the
  loop-invariant normalisation and cumulative sum out of the loop: each of
  the S calls really reads its weights.
* ``numpy``: ``np.searchsorted(np.cumsum(W), (u + arange(N)) / N, "right")``,
  float64 weights, int64 indices, one uniform per call.
* ``filterpy``: ``filterpy.monte_carlo.systematic_resample`` (a Python
  ``while`` loop over N), float64; capped by a time budget.
* ``particles``: ``particles.resampling.systematic`` (numba ``inverse_cdf``),
  float64; its numba JIT compilation happens before timing.

Floor
-----
``floor_s = N · (4 + 4) bytes / bandwidth``: read N float32 weights and write
N int32 indices once (jaxnav's dtypes; the float64 peers must move twice that
or more). The same ``floor_s`` is written on every row of a size.
"""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.harness import Context, guarded, make_row, skipped_row, time_calls
from benchmarks.peers import optional_import
from benchmarks.workloads import Workload, register

NAME = "W1"
SCAN_LENGTH = 50
FLOOR_DOC = "N * (4 + 4) bytes: read N float32 weights + write N int32 indices, / measured bandwidth"


def floor_bytes(n: int) -> int:
    """Bytes W1 must move once for jaxnav's dtypes: N float32 weights read, N int32 indices written."""
    return n * (4 + 4)


def make_weights(n: int) -> np.ndarray:
    """``exp(z)`` normalised, ``z ~ N(0, 1)`` with seed 0 (float64)."""
    z = np.random.default_rng(0).standard_normal(n)
    w = np.exp(z - z.max())
    return w / w.sum()


def _keys(seed: int, count: int) -> itertools.cycle:
    return itertools.cycle(list(jax.random.split(jax.random.key(seed), count)))


def _jaxnav_per_call(ctx: Context, size: dict, n: int, lw: jax.Array, floor_s: float) -> dict:
    """One jitted call per resampling, a fresh key each call."""
    from jaxnav.core.resampling import systematic

    f = jax.jit(lambda key, log_w: systematic(key, log_w, log_w.shape[0]))
    key0 = jax.random.key(1)
    compile_s = ctx.compile_s((NAME, "per_call", n), f, key0, lw)
    reps = ctx.reps(50 if n <= 10**5 else 15)
    keys = _keys(2, reps + 3)
    t = time_calls(lambda: jax.block_until_ready(f(next(keys), lw)), repeats=reps, warmup=2, budget_s=20.0)
    return make_row(NAME, "jaxnav", size, "per_call", t, compile_s=compile_s, floor_s=floor_s,
                    dtype="float32 log-weights -> int32 indices")


def _jaxnav_in_scan(ctx: Context, size: dict, n: int, lw: jax.Array, floor_s: float) -> dict:
    """S calls inside one jitted lax.scan; the weights are scanned over as xs."""
    from jaxnav.core.resampling import systematic

    key0 = jax.random.key(1)
    s = SCAN_LENGTH

    def scan_fn(key, lw_stack):
        def body(carry, xs):
            i, log_w = xs
            return systematic(jax.random.fold_in(key, i), log_w, log_w.shape[0]), None

        init = jnp.zeros((lw_stack.shape[1],), jnp.int32)
        idx, _ = jax.lax.scan(body, init, (jnp.arange(lw_stack.shape[0]), lw_stack))
        return idx

    g = jax.jit(scan_fn)
    lw_stack = jax.block_until_ready(jnp.broadcast_to(lw, (s, n)) + jnp.zeros((s, 1), lw.dtype))
    compile_s = ctx.compile_s((NAME, "in_scan", n), g, key0, lw_stack)
    reps = ctx.reps(10 if n <= 10**5 else 3)
    keys = _keys(3, reps + 2)
    t = time_calls(lambda: jax.block_until_ready(g(next(keys), lw_stack)), repeats=reps, warmup=1, budget_s=40.0)
    del lw_stack
    return make_row(NAME, "jaxnav", size, "in_scan", None, median_s=t.median_s / s, compile_s=compile_s,
                    floor_s=floor_s, min_s=t.min_s / s, repeats=t.repeats, scan_length=s,
                    dtype="float32 log-weights -> int32 indices")


def _numpy_row(ctx: Context, size: dict, n: int, w: np.ndarray, floor_s: float) -> dict:
    rng = np.random.default_rng(4)
    grid = np.arange(n, dtype=np.float64)
    inv_n = 1.0 / n

    def numpy_systematic():
        cdf = np.cumsum(w)
        u = (grid + rng.random()) * inv_n
        idx = np.searchsorted(cdf, u, side="right")
        np.minimum(idx, n - 1, out=idx)
        return idx

    reps = ctx.reps(50 if n <= 10**5 else 15)
    t = time_calls(numpy_systematic, repeats=reps, warmup=2, budget_s=20.0)
    return make_row(NAME, "numpy", size, "per_call", t, floor_s=floor_s, dtype="float64 weights -> int64 indices")


def _filterpy_row(ctx: Context, size: dict, n: int, w: np.ndarray, floor_s: float) -> dict:
    mc, why = optional_import("filterpy.monte_carlo")
    if mc is None:
        return skipped_row(NAME, "filterpy", size, "per_call", why)
    np.random.seed(5)  # filterpy draws its uniform from the global NumPy generator
    reps = ctx.reps(20 if n <= 10**4 else 5)
    # A Python loop: ~1 µs per particle, so cap by budget (and no warm-up at 1e6).
    t = time_calls(lambda: mc.systematic_resample(w), repeats=reps, warmup=1 if n <= 10**5 else 0,
                   budget_s=8.0, min_repeats=3)
    return make_row(NAME, "filterpy", size, "per_call", t, floor_s=floor_s, dtype="float64 weights -> int32 indices",
                    note="pure-Python while loop; repeats capped by an 8 s budget")


_particles_warm = False


def _particles_row(ctx: Context, size: dict, n: int, w: np.ndarray, floor_s: float) -> dict:
    global _particles_warm
    rs, why = optional_import("particles.resampling")
    if rs is None:
        return skipped_row(NAME, "particles", size, "per_call", why)
    np.random.seed(6)  # particles draws from the global NumPy generator
    if not _particles_warm:  # numba compiles inverse_cdf on the first call: not timed
        rs.systematic(np.full(10, 0.1))
        _particles_warm = True
    reps = ctx.reps(50 if n <= 10**5 else 15)
    t = time_calls(lambda: rs.systematic(w), repeats=reps, warmup=2, budget_s=20.0)
    return make_row(NAME, "particles", size, "per_call", t, floor_s=floor_s, dtype="float64 weights -> int64 indices",
                    note="numba inverse_cdf; JIT warm-up excluded")


def run(ctx: Context, size: dict) -> list[dict]:
    n = int(size["N"])
    w = make_weights(n)
    lw = jax.block_until_ready(jnp.asarray(np.log(w), jnp.float32))
    floor_s = ctx.floor(floor_bytes(n))
    rows = []
    rows += guarded(ctx, NAME, "jaxnav", size, "per_call", lambda: _jaxnav_per_call(ctx, size, n, lw, floor_s))
    rows += guarded(ctx, NAME, "jaxnav", size, "in_scan", lambda: _jaxnav_in_scan(ctx, size, n, lw, floor_s))
    rows += guarded(ctx, NAME, "numpy", size, "per_call", lambda: _numpy_row(ctx, size, n, w, floor_s))
    rows += guarded(ctx, NAME, "filterpy", size, "per_call", lambda: _filterpy_row(ctx, size, n, w, floor_s))
    rows += guarded(ctx, NAME, "particles", size, "per_call", lambda: _particles_row(ctx, size, n, w, floor_s))
    return rows


register(
    Workload(
        name=NAME,
        title="W1 systematic resampling (time per call)",
        sizes=[{"N": 10**3}, {"N": 10**4}, {"N": 10**5}, {"N": 10**6}],
        run=run,
        x_key="N",
        floor_doc=FLOOR_DOC,
    )
)
