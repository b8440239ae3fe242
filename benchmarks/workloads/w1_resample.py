"""W1 resample: the four resampling schemes of N normalised weights, in float32 and float64.

Weights ``w = exp(z) / Σ exp(z)``, ``z ~ N(0, 1)`` drawn once with
``np.random.default_rng(0)``; N = 1e3, 1e4, 1e5, 1e6, 1e7, 1e8 (``--quick``:
1e3, 1e4). Median time per resampling of N ancestors from N weights.

Every row carries ``scheme`` (``systematic``, ``stratified``, ``multinomial``,
``residual``), ``dtype`` (of the weights the implementation is given) and
``index_dtype`` (of the ancestors it returned).

Implementations
---------------
* ``jaxnav``: ``jaxnav.core.resampling.SCHEMES[scheme](key, log_w, N)`` on the
  log-weights ``log w`` (jaxnav's resamplers take log-weights), exact integer
  CDF, int32 ancestors in order. float32 and float64: the float64 rows build
  their inputs, compile and run inside ``jax.enable_x64(True)`` and the float32
  rows inside ``jax.enable_x64(False)``, so each row sees the precision it
  names and the process's setting is restored after every row.

  - ``per_call``: one jitted call per resampling, a fresh key each call.
  - ``in_scan``: one jitted ``lax.scan`` of ``S`` resamplings with key
    ``fold_in(key, s)``; time / S. The weights are scanned over as ``xs``
    (``S`` copies, made outside the timed call) so that XLA cannot hoist the
    loop-invariant work out of the loop: each of the S resamplings really reads
    its weights. ``S`` (``scan_length`` on the row) is 50 up to N = 1e5, then
    ``max(2, 1e7 / N)`` (10 at 1e6, 2 above), and never more than a quarter
    of the available memory holds.

* ``blackjax`` (``per_call``): ``blackjax.smc.resampling.<scheme>(key, w, N)``,
  jitted, on normalised float32 and float64 weights (float64 again inside
  ``jax.enable_x64(True)``). Its systematic, stratified and multinomial
  schemes are a float cumulative sum and ``jnp.searchsorted`` (multinomial on
  sorted uniforms from exponential spacings); residual adds a random
  permutation of the N draws (a sort).
* ``numpy`` (``per_call``), float64, written to be fast (one vectorised pass
  per stage, int64 ancestors):

  - systematic: ``searchsorted(cumsum(w), (arange(N) + u) / N, "right")``;
  - stratified: the same with ``u`` an array of N uniforms;
  - multinomial: N sorted uniforms as normalised cumulative sums of N + 1
    exponential spacings, then ``searchsorted`` (sorted ancestors);
  - residual: ``⌊N w_i⌋`` copies by ``np.repeat``, the remaining
    ``N − Σ⌊N w_i⌋`` ancestors drawn as in multinomial from the residuals
    ``N w_i − ⌊N w_i⌋`` (copies, then draws: the two parts are each sorted).

* ``particles`` (``per_call``): ``particles.resampling.<scheme>(w)`` (numba
  ``inverse_cdf`` on uniforms that NumPy draws), float64; its numba JIT is
  compiled before any timing.
* ``filterpy`` (``per_call``):
  ``filterpy.monte_carlo.<scheme>_resample(w)``, float64. Systematic,
  stratified and residual are pure-Python loops over N (about a microsecond a
  particle); multinomial is ``searchsorted`` on unsorted uniforms. Repeats are
  capped by an 8 s budget per row. filterpy's residual is timed as shipped (it
  normalises ``w − ⌊N w⌋`` where ``N w − ⌊N w⌋`` is meant).

Limits
------
* **Memory.** Before a size, the bytes it needs (inputs 32 B and at most
  ``WORK_BYTES`` B of working memory per particle) are compared with the
  memory available (``MemAvailable``); a size that does not fit writes one
  skipped row per planned measurement, with the reason. Each JAX row also
  checks its compiled executable's own temporary and output bytes
  (``memory_analysis``) and each NumPy-side peer ``PEER_BYTES`` B per particle.
* **Time.** A peer row whose time per call, extrapolated from the two
  previous sizes of the same run (``t ∝ N^p``, ``1 ≤ p ≤ 2``), would exceed
  ``CALL_CAP_S[peer]`` (filterpy 2 s, blackjax 5 s) is skipped with the
  estimate as its reason (filterpy at 1e7 and 1e8, the slow blackjax schemes
  at 1e7 and 1e8). Such rows skip before any measuring, so the CPU monitor
  and re-measurement of ``guarded`` do not apply to them. jaxnav's rows and
  the NumPy peer are never skipped for time. At N ≥ 1e7 the timed repeats are
  fewer (per_call: one warm-up call and 2–5 timed calls; in_scan at 1e8: two
  timed scans without a warm-up scan, since one call takes seconds).

Floor
-----
``floor_s = N · (itemsize of the weights + 4) bytes / bandwidth``: read N
weights and write N int32 ancestors once, so 8 N bytes for float32 rows and
12 N bytes for float64 rows (the peers' float64 rows included, whatever index
type they write). Every row of a size carries the floor of its dtype.
"""

from __future__ import annotations

import itertools
import math
import os

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.harness import Context, Timing, guarded, make_row, skipped_row, time_calls
from benchmarks.peers import optional_import
from benchmarks.workloads import Workload, register

NAME = "W1"
SCHEMES = ("systematic", "stratified", "multinomial", "residual")
DTYPES = ("float32", "float64")
FLOOR_DOC = (
    "N * (itemsize of the weights + 4) bytes: read N weights (4 B float32, 8 B float64) + write N int32 "
    "indices, / measured bandwidth"
)

INPUT_BYTES = 32  # per particle, held for a whole size: w (f64), log w (f32 and f64), blackjax's w (f32 or f64)
WORK_BYTES = 90  # per particle, the largest working set of one row (jaxnav multinomial in_scan, float64, S = 2)
PEER_BYTES = 80  # per particle, an upper bound on a NumPy-side peer's temporaries (numpy residual: ~64)
MEMORY_FRACTION = 0.8  # of MemAvailable that one size, or one row, may plan to use
ROW_BUDGET_S = 5.0  # timed seconds per row after which timing stops (once min_repeats calls were timed)
CALL_CAP_S = {"filterpy": 2.0, "blackjax": 5.0}  # peers whose rows are skipped above this extrapolated s/call

_FILTERPY = {s: f"{s}_resample" for s in SCHEMES}
_BLACKJAX_NOTE = {
    "systematic": "cumsum + jnp.searchsorted",
    "stratified": "cumsum + jnp.searchsorted",
    "multinomial": "sorted uniforms from exponential spacings, cumsum + jnp.searchsorted",
    "residual": "floor copies by jnp.repeat, multinomial on the residuals, random permutation (a sort)",
}


# --------------------------------------------------------------------------- sizes, memory, repeats


def floor_bytes(n: int, dtype: str = "float32") -> int:
    """Bytes W1 must move once: N weights of ``dtype`` read, N int32 indices written."""
    return n * (np.dtype(dtype).itemsize + 4)


def make_weights(n: int) -> np.ndarray:
    """``exp(z)`` normalised, ``z ~ N(0, 1)`` with seed 0 (float64)."""
    z = np.random.default_rng(0).standard_normal(n)
    w = np.exp(z - z.max())
    w /= w.sum()
    return w


def scan_length(n: int, itemsize: int = 8, available: int | None = None) -> int:
    """Resamplings per ``in_scan`` call: 50 up to N = 1e5, ``max(2, 1e7 // N)`` above, and at most what a
    quarter of ``available`` bytes holds as ``S`` stacked copies of the weights (but at least 1)."""
    s = 50 if n <= 10**5 else max(2, 10**7 // n)
    if available is not None:
        s = min(s, max(1, int(available // 4 // (n * itemsize))))
    return s


def size_bytes(n: int) -> int:
    """What one size needs at most at one time: its inputs and the largest row's working memory."""
    return n * (INPUT_BYTES + WORK_BYTES)


def available_bytes() -> int | None:
    """``MemAvailable`` of ``/proc/meminfo`` in bytes (None where it cannot be read)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def _gib(b: float) -> str:
    return f"{b / 2**30:.1f} GiB"


def _label(n: int) -> str:
    e = math.log10(n)
    return f"1e{int(round(e))}" if n == 10 ** int(round(e)) else str(n)


def _memory_reason(what: str, need: int) -> str | None:
    """None if ``need`` bytes fit in ``MEMORY_FRACTION`` of the available memory, else the reason."""
    avail = available_bytes()
    if avail is None or need <= MEMORY_FRACTION * avail:
        return None
    return f"memory: {what} needs about {_gib(need)}, {_gib(avail)} available (limit {MEMORY_FRACTION:.0%} of it)"


class _Plan:
    """Repeats and warm-ups for one size: fewer at N ≥ 1e7, where one call takes 0.1 s to seconds."""

    def __init__(self, ctx: Context, n: int):
        if n <= 10**5:
            per_call, per_warm, scan_reps, scan_warm, peer_warm = 50, 2, 10, 1, 2
        elif n <= 10**6:
            per_call, per_warm, scan_reps, scan_warm, peer_warm = 15, 2, 3, 1, 2
        elif n <= 10**7:
            per_call, per_warm, scan_reps, scan_warm, peer_warm = 5, 1, 2, 1, 1
        else:
            per_call, per_warm, scan_reps, scan_warm, peer_warm = 2, 1, 2, 0, 0
        self.per_call = ctx.reps(per_call)
        self.per_call_warmup = per_warm
        self.in_scan = ctx.reps(scan_reps)
        self.in_scan_warmup = scan_warm
        self.peer_warmup = peer_warm  # NumPy-side peers (no compilation to warm)
        self.min_repeats = 3 if n <= 10**7 else 2
        self.min_scan_repeats = 3 if n <= 10**6 else 2


def _time(fn, reps: int, warmup: int, min_repeats: int, budget_s: float = ROW_BUDGET_S) -> Timing:
    return time_calls(fn, repeats=reps, warmup=warmup, budget_s=budget_s, min_repeats=min(min_repeats, reps))


# --------------------------------------------------------------------------- time caps for slow peers

_HISTORY: dict[int, dict[tuple, list[tuple[int, float]]]] = {}


def _record(ctx: Context, key: tuple, n: int, seconds: float) -> None:
    _HISTORY.setdefault(id(ctx), {}).setdefault(key, []).append((n, seconds))


def predicted_call_s(history: list[tuple[int, float]], n: int) -> tuple[float, str] | None:
    """Seconds per call at ``n`` extrapolated from earlier sizes (``t ∝ N^p``, ``p`` from the last two sizes,
    clipped to [1, 2]) and a description of the estimate; None without an earlier smaller size."""
    pts = sorted(p for p in history if p[0] < n)
    if not pts:
        return None
    n1, t1 = pts[-1]
    p = 1.0
    if len(pts) >= 2:
        n0, t0 = pts[-2]
        if t0 > 0 and t1 > 0 and n1 > n0:
            p = min(2.0, max(1.0, math.log(t1 / t0) / math.log(n1 / n0)))
    return t1 * (n / n1) ** p, f"{t1:.3g} s at N={_label(n1)}, t ∝ N^{p:.2f}"


def _time_reason(ctx: Context, impl: str, key: tuple, n: int) -> str | None:
    cap = CALL_CAP_S.get(impl)
    if cap is None:
        return None
    est = predicted_call_s(_HISTORY.get(id(ctx), {}).get(key, []), n)
    if est is None or est[0] <= cap:
        return None
    return f"time: estimated {est[0]:.3g} s per call ({est[1]}), over the {cap:g} s per call allowed for {impl} in W1"


# --------------------------------------------------------------------------- rows


def _keys(seed: int, count: int) -> itertools.cycle:
    return itertools.cycle(list(jax.random.split(jax.random.key(seed), count)))


def _check(out, n: int) -> str:
    """Raise unless ``out`` holds N ancestors in [0, N); returns their dtype."""
    a = np.asarray(out)
    if a.shape != (n,) or a.min() < 0 or a.max() >= n:
        raise ValueError(f"bad ancestors: shape {a.shape}, range [{a.min()}, {a.max()}] for N={n}")
    return str(a.dtype)


def _jax_memory_reason(what: str, jitted, *args, extra: int = 0) -> str | None:
    """Check the compiled executable's temporaries and outputs (already compiled: the cache answers)."""
    try:
        ma = jitted.lower(*args).compile().memory_analysis()
        need = int(ma.temp_size_in_bytes + ma.output_size_in_bytes) + extra
    except Exception:  # no memory analysis on this backend: rely on the size-level check
        return None
    return _memory_reason(what, need)


def _common(scheme: str, dtype: str, floor_s: float) -> dict:
    return {"scheme": scheme, "dtype": dtype, "floor_s": floor_s}


def _jax_per_call(
    ctx: Context, size: dict, plan: _Plan, impl: str, scheme: str, dtype: str, fn, x, floor_s: float, note: str
) -> dict:
    """One jitted ``fn(key, x)`` per resampling, a fresh key each call (caller holds the x64 setting)."""
    n = x.shape[0]
    f = jax.jit(fn)
    key0 = jax.random.key(1)
    compile_s = ctx.compile_s((NAME, impl, scheme, dtype, "per_call", n), f, key0, x)
    why = _jax_memory_reason(f"{impl} {scheme} {dtype} at N={_label(n)}", f, key0, x)
    if why:
        return skipped_row(NAME, impl, size, "per_call", why, compile_s=compile_s, **_common(scheme, dtype, floor_s))
    reps = plan.per_call
    keys = _keys(2, reps + plan.per_call_warmup + 1)
    last = {}

    def call():
        last["out"] = jax.block_until_ready(f(next(keys), x))

    t = _time(call, reps, plan.per_call_warmup, plan.min_repeats)
    index_dtype = _check(last.pop("out"), n)
    _record(ctx, (impl, scheme, dtype, "per_call"), n, t.median_s)
    return make_row(
        NAME,
        impl,
        size,
        "per_call",
        t,
        compile_s=compile_s,
        index_dtype=index_dtype,
        note=note,
        **_common(scheme, dtype, floor_s),
    )


def _jaxnav_in_scan(
    ctx: Context, size: dict, plan: _Plan, scheme: str, dtype: str, lw: jax.Array, floor_s: float
) -> dict:
    """S resamplings inside one jitted lax.scan; the weights are scanned over as xs (caller holds x64)."""
    from jaxnav.core.resampling import SCHEMES as JAXNAV_SCHEMES

    resample = JAXNAV_SCHEMES[scheme]
    n = lw.shape[0]
    itemsize = lw.dtype.itemsize
    s = scan_length(n, itemsize, available_bytes())
    key0 = jax.random.key(1)

    def scan_fn(key, lw_stack):
        def body(carry, xs):
            i, log_w = xs
            return resample(jax.random.fold_in(key, i), log_w, log_w.shape[0]), None

        init = jnp.zeros((lw_stack.shape[1],), jnp.int32)
        idx, _ = jax.lax.scan(body, init, (jnp.arange(lw_stack.shape[0]), lw_stack))
        return idx

    g = jax.jit(scan_fn)
    spec = jax.ShapeDtypeStruct((s, n), lw.dtype)
    compile_s = ctx.compile_s((NAME, "jaxnav", scheme, dtype, "in_scan", n, s), g, key0, spec)
    why = _jax_memory_reason(
        f"jaxnav {scheme} {dtype} in_scan (S={s}) at N={_label(n)}", g, key0, spec, extra=s * n * itemsize
    )
    if why:
        return skipped_row(
            NAME, "jaxnav", size, "in_scan", why, compile_s=compile_s, scan_length=s, **_common(scheme, dtype, floor_s)
        )
    lw_stack = jax.block_until_ready(jnp.broadcast_to(lw, (s, n)) + jnp.zeros((s, 1), lw.dtype))
    reps = plan.in_scan
    keys = _keys(3, reps + plan.in_scan_warmup + 1)
    last = {}

    def call():
        last["out"] = jax.block_until_ready(g(next(keys), lw_stack))

    try:
        t = _time(call, reps, plan.in_scan_warmup, plan.min_scan_repeats)
    finally:
        del lw_stack
    index_dtype = _check(last.pop("out"), n)
    return make_row(
        NAME,
        "jaxnav",
        size,
        "in_scan",
        t.per(s),
        compile_s=compile_s,
        scan_length=s,
        index_dtype=index_dtype,
        note="exact integer CDF; sorted int32 ancestors",
        **_common(scheme, dtype, floor_s),
    )


def _peer_row(
    ctx: Context,
    size: dict,
    plan: _Plan,
    impl: str,
    scheme: str,
    fn,
    n: int,
    floor_s: float,
    note: str,
    reps: int | None = None,
    warmup: int | None = None,
    budget_s: float = ROW_BUDGET_S,
) -> dict:
    """A NumPy-side peer ``fn()`` on float64 weights."""
    dtype = "float64"
    last = {}

    def call():
        last["out"] = fn()

    reps = plan.per_call if reps is None else reps
    t = _time(call, reps, plan.peer_warmup if warmup is None else warmup, plan.min_repeats, budget_s)
    index_dtype = _check(last.pop("out"), n)
    _record(ctx, (impl, scheme, dtype, "per_call"), n, t.median_s)
    return make_row(
        NAME, impl, size, "per_call", t, index_dtype=index_dtype, note=note, **_common(scheme, dtype, floor_s)
    )


# --------------------------------------------------------------------------- the NumPy peer


def numpy_resampler(scheme: str, w: np.ndarray, rng: np.random.Generator):
    """A fast vectorised float64 NumPy resampler of normalised ``w``: ``f() -> int64 ancestors [N]``.

    Per-size constants (``arange(N)``) are made once, outside the returned function, as a filter would.
    """
    n = w.shape[0]
    grid = np.arange(n, dtype=np.float64)
    inv_n = 1.0 / n
    last = n - 1

    def search(cdf, u):
        idx = np.searchsorted(cdf, u, side="right")
        np.minimum(idx, last, out=idx)  # u above a cumulative sum that rounded below 1
        return idx

    def sorted_uniforms(m, top):
        """m sorted uniforms on [0, top): normalised cumulative sums of m + 1 exponential spacings."""
        z = np.cumsum(rng.standard_exponential(m + 1))
        u = z[:-1]
        u *= top / z[-1]
        return u

    if scheme == "systematic":

        def f():
            u = grid + rng.random()
            u *= inv_n
            return search(np.cumsum(w), u)
    elif scheme == "stratified":

        def f():
            u = rng.random(n)
            u += grid
            u *= inv_n
            return search(np.cumsum(w), u)
    elif scheme == "multinomial":

        def f():
            cdf = np.cumsum(w)
            return search(cdf, sorted_uniforms(n, cdf[-1]))
    elif scheme == "residual":
        particles = np.arange(n, dtype=np.int64)

        def f():
            nw = w * n
            copies = nw.astype(np.int64)  # ⌊N w_i⌋ (w ≥ 0)
            fixed = min(int(copies.sum()), n)
            out = np.empty(n, np.int64)
            out[:fixed] = np.repeat(particles, copies)[:fixed]
            if fixed < n:
                nw -= copies  # the residuals
                cdf = np.cumsum(nw)
                out[fixed:] = search(cdf, sorted_uniforms(n - fixed, cdf[-1]))
            return out
    else:
        raise ValueError(f"unknown scheme {scheme!r}")
    return f


# --------------------------------------------------------------------------- one size


def _precision(dtype: str):
    """float64 rows run inside ``jax.enable_x64(True)``, float32 rows inside ``jax.enable_x64(False)``."""
    return jax.enable_x64(dtype == "float64")


_particles_warm = False


def _planned(n: int) -> list[tuple[str, str, str, str]]:
    """Every (implementation, scheme, dtype, mode) measured at a size, in run order."""
    out = []
    for scheme in SCHEMES:
        for dtype in DTYPES:
            out += [("jaxnav", scheme, dtype, "per_call"), ("jaxnav", scheme, dtype, "in_scan")]
        out += [("blackjax", scheme, dtype, "per_call") for dtype in DTYPES]
        out += [(peer, scheme, "float64", "per_call") for peer in ("numpy", "filterpy", "particles")]
    return out


def run(ctx: Context, size: dict) -> list[dict]:
    global _particles_warm
    n = int(size["N"])
    x64_before = bool(jax.config.jax_enable_x64)
    floors = {dt: ctx.floor(floor_bytes(n, dt)) for dt in DTYPES}
    # implementations the run leaves out (a preset) give no row, not even a skipped one
    planned = [p for p in _planned(n) if ctx.wants(p[0])]
    why = _memory_reason(
        f"N={_label(n)} ({INPUT_BYTES} B of inputs + up to {WORK_BYTES} B per particle)", size_bytes(n)
    )
    if why:
        return [
            skipped_row(NAME, impl, size, mode, why, **_common(scheme, dtype, floors[dtype]))
            for impl, scheme, dtype, mode in planned
        ]

    plan = _Plan(ctx, n)
    w = make_weights(n)
    log_w = np.log(w)
    with _precision("float32"):
        lw = {"float32": jax.block_until_ready(jnp.asarray(log_w, jnp.float32))}
    with _precision("float64"):
        lw["float64"] = jax.block_until_ready(jnp.asarray(log_w, jnp.float64))
    del log_w

    from jaxnav.core.resampling import SCHEMES as JAXNAV_SCHEMES

    bj, bj_why = optional_import("blackjax.smc.resampling")
    mc, mc_why = optional_import("filterpy.monte_carlo")
    rs, rs_why = optional_import("particles.resampling")
    # numba compiles inverse_cdf on the first call: not timed
    if rs is not None and not _particles_warm and ctx.wants("particles"):
        np.random.seed(6)
        for scheme in SCHEMES:
            getattr(rs, scheme)(np.full(10, 0.1))
        _particles_warm = True

    rows: list[dict] = []

    def jaxnav_per_call(scheme, dtype):
        resample = JAXNAV_SCHEMES[scheme]
        with _precision(dtype):
            return _jax_per_call(
                ctx,
                size,
                plan,
                "jaxnav",
                scheme,
                dtype,
                lambda key, x: resample(key, x, x.shape[0]),
                lw[dtype],
                floors[dtype],
                "exact integer CDF; sorted int32 ancestors",
            )

    def jaxnav_in_scan(scheme, dtype):
        with _precision(dtype):
            return _jaxnav_in_scan(ctx, size, plan, scheme, dtype, lw[dtype], floors[dtype])

    def blackjax_per_call(scheme, dtype):
        resample = getattr(bj, scheme)
        with _precision(dtype):
            x = jax.block_until_ready(jnp.asarray(w, dtype))
            try:
                return _jax_per_call(
                    ctx,
                    size,
                    plan,
                    "blackjax",
                    scheme,
                    dtype,
                    lambda key, x: resample(key, x, x.shape[0]),
                    x,
                    floors[dtype],
                    f"jitted, {dtype}: {_BLACKJAX_NOTE[scheme]}",
                )
            finally:
                del x

    def numpy_per_call(scheme):
        f = numpy_resampler(scheme, w, np.random.default_rng(4))
        return _peer_row(
            ctx,
            size,
            plan,
            "numpy",
            scheme,
            f,
            n,
            floors["float64"],
            "vectorised float64: cumsum + searchsorted"
            + ("; floor copies by np.repeat, then sorted draws" if scheme == "residual" else ""),
        )

    def filterpy_per_call(scheme):
        np.random.seed(5)  # filterpy draws from the global NumPy generator
        f = getattr(mc, _FILTERPY[scheme])
        loop = scheme != "multinomial"
        return _peer_row(
            ctx,
            size,
            plan,
            "filterpy",
            scheme,
            lambda: f(w),
            n,
            floors["float64"],
            ("pure-Python loop over N" if loop else "searchsorted on unsorted uniforms")
            + "; repeats capped by an 8 s budget",
            reps=20 if n <= 10**4 else 5,
            warmup=1 if n <= 10**5 else 0,
            budget_s=8.0,
        )

    def particles_per_call(scheme):
        np.random.seed(6)  # particles draws from the global NumPy generator
        f = getattr(rs, scheme)
        return _peer_row(
            ctx,
            size,
            plan,
            "particles",
            scheme,
            lambda: f(w),
            n,
            floors["float64"],
            "numba inverse_cdf; JIT warm-up excluded",
        )

    missing = {
        "blackjax": bj_why if bj is None else None,
        "filterpy": mc_why if mc is None else None,
        "particles": rs_why if rs is None else None,
    }

    def skip_reason(impl: str, scheme: str, dtype: str, mode: str) -> str | None:
        """Why a peer row is not measured at all, decided before measuring (so that no CPU monitoring or
        re-measurement of guarded applies to it): not installed, over the time cap, or, for the NumPy-side
        peers, over the memory limit (the JAX rows check their compiled executable instead)."""
        if missing.get(impl):
            return missing[impl]
        why = _time_reason(ctx, impl, (impl, scheme, dtype, mode), n)
        if why is None and impl in ("numpy", "filterpy", "particles"):
            why = _memory_reason(f"{impl} {scheme} at N={_label(n)}", n * PEER_BYTES)
        return why

    measure = {
        ("jaxnav", "per_call"): jaxnav_per_call,
        ("jaxnav", "in_scan"): jaxnav_in_scan,
        ("blackjax", "per_call"): blackjax_per_call,
        ("numpy", "per_call"): lambda scheme, dtype: numpy_per_call(scheme),
        ("filterpy", "per_call"): lambda scheme, dtype: filterpy_per_call(scheme),
        ("particles", "per_call"): lambda scheme, dtype: particles_per_call(scheme),
    }
    for impl, scheme, dtype, mode in planned:
        why = skip_reason(impl, scheme, dtype, mode)
        if why:
            rows.append(skipped_row(NAME, impl, size, mode, why, **_common(scheme, dtype, floors[dtype])))
            continue
        fn = measure[(impl, mode)]
        new = guarded(ctx, NAME, impl, size, mode, lambda fn=fn, s=scheme, d=dtype: fn(s, d))
        for r in new:  # an error row from guarded lacks these
            r.setdefault("scheme", scheme)
            r.setdefault("dtype", dtype)
            r.setdefault("floor_s", floors[dtype])
        rows += new
    if bool(jax.config.jax_enable_x64) != x64_before:
        raise RuntimeError(f"W1 changed jax_enable_x64 from {x64_before} to {jax.config.jax_enable_x64}")
    return rows


register(
    Workload(
        name=NAME,
        title="W1 resampling (systematic, stratified, multinomial, residual; float32, float64): time per call",
        sizes=[{"N": 10**k} for k in range(3, 9)],
        run=run,
        x_key="N",
        floor_doc=FLOOR_DOC,
        series_key="scheme",
    )
)
