"""Batch Monte Carlo: many seeded runs in vmapped, jitted chunks.

``monte_carlo(fn, key, num_runs, chunk_size)`` splits ``key`` into one key per
run and evaluates ``fn(run_key, *run_args)`` with ``vmap`` over chunks of
``chunk_size`` runs. The chunk size bounds peak memory (all intermediate
arrays of one chunk are alive at once); the last chunk is padded to the same
size so the jitted function compiles exactly once, and the padding is dropped
from the result. Results are stacked along a new leading axis of size
``num_runs`` and returned as NumPy arrays on the host, so a long sweep does not
hold every chunk's output on the device.
"""

from __future__ import annotations

import threading
import weakref
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import memory
from jaxnav.core.filter import check_key
from jaxnav.core.validation import check_positive_int, dtype_of

__all__ = ["monte_carlo", "run_keys", "scan_filter", "compiled_vmap"]

_COMPILED: weakref.WeakKeyDictionary[Callable, dict] = weakref.WeakKeyDictionary()
_COMPILING = threading.Lock()  # guards _COMPILED and _LOCKS
_LOCKS: weakref.WeakKeyDictionary[Callable, dict] = weakref.WeakKeyDictionary()


def compiled_vmap(
    fn: Callable[..., Any],
    *args: Any,
    shared: tuple = (),
    mode: str = "vmap",
    compiler_options: dict | None = None,
) -> Any:
    """``jax.jit(jax.vmap(fn))`` compiled for the shapes of ``args``, cached on the ``fn`` object.

    The executable is called as ``exe(*args, *shared)`` and evaluates
    ``fn(*args_r, *shared)`` for every row ``r`` of ``args`` (their leaves share a
    leading batch axis); ``shared`` are pytrees passed whole to every row (not
    batched), so cells that differ only in the values of ``shared`` arrays (a
    height, a layout, a path) share one compilation.

    ``mode`` says how the rows are evaluated:

    * ``"vmap"`` (default): vectorised, one wide computation;
    * ``"map"``: ``jax.lax.map``, one row after the other inside one compiled
      loop. Right for functions whose ``lax.cond`` branches differ greatly in
      cost: under ``vmap`` a ``cond`` with a batched predicate becomes a
      ``select`` that computes both branches at every call (IR MCL's
      16,000-candidate re-draw makes a run several times slower under ``vmap``).

    Calls with the same ``fn`` object, argument shapes, ``mode`` and
    ``compiler_options`` (XLA options, e.g. ``{"xla_backend_optimization_level": 0}``)
    reuse one executable, so repeated sweeps of one function compile once per
    process; it is thread-safe, and threads asking for the same executable compile
    it once. Returns the executable.
    """
    if mode not in ("vmap", "map"):
        raise ValueError(f"mode must be 'vmap' or 'map', got {mode!r}")
    options = dict(compiler_options or {})
    shared = tuple(shared)
    leaves, tree = jax.tree_util.tree_flatten((args, shared))
    signature = (
        tree,
        tuple((np.shape(x), str(getattr(x, "dtype", None) or np.result_type(x))) for x in leaves),
        mode,
        tuple(sorted(options.items())),
    )
    with _COMPILING:
        per_fn = _COMPILED.setdefault(fn, {})
        lock = _LOCKS.setdefault(fn, {}).setdefault(signature, threading.Lock())
    with lock:  # threads asking for one signature compile it once (sweep compiles cells concurrently)
        if signature not in per_fn:
            n = len(args)

            def batched(*all_args):
                rows, common = all_args[:n], all_args[n:]
                if mode == "vmap":
                    return jax.vmap(lambda *r: fn(*r, *common))(*rows)
                return jax.lax.map(lambda r: fn(*r, *common), rows)

            per_fn[signature] = jax.jit(batched).lower(*args, *shared).compile(compiler_options=options or None)
    return per_fn[signature]


def run_keys(key: jax.Array, num_runs: int) -> jax.Array:
    """The per-run keys :func:`monte_carlo` uses: ``jax.random.split(key, num_runs)``.

    Run ``r`` of a sweep gets the same key whatever the chunk size. Its values agree across
    chunk sizes to float32 rounding, not bit for bit: XLA compiles a ``vmap`` of width 4 and one
    of width 8 into different programs, which may round differently (a particle filter can then
    amplify the difference). With one chunk size the results are bit-identical.
    ``key`` must be one PRNG key (``ValueError`` naming it otherwise).
    """
    check_key(key)
    return jax.random.split(key, num_runs)


def monte_carlo(
    fn: Callable[..., Any],
    key: jax.Array,
    num_runs: int,
    *run_args: Any,
    chunk_size: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    jit: bool = True,
) -> Any:
    """Evaluate ``fn(key_r, *args_r)`` for ``r = 0 … num_runs − 1``, vmapped in chunks.

    Args:
        fn: a pure function of a PRNG key and optional per-run arguments,
            returning a pytree of arrays.
        key: master key, one PRNG key; run ``r`` receives ``run_keys(key, num_runs)[r]``.
        num_runs: R ≥ 1.
        *run_args: pytrees whose leaves have leading axis ``num_runs`` (e.g.
            simulated data per run); sliced per chunk.
        chunk_size: runs per vmapped call (default: all at once). Bounds memory: a chunk whose
            inputs, outputs and XLA's working memory (from the compiled chunk; without ``jit``,
            ``chunk_size`` times one run's outputs from :func:`jax.eval_shape`) exceed the
            device's memory is refused with a ``ValueError`` before anything is allocated
            (:mod:`jaxnav.core.memory`, which also says how to go ahead anyway).
        progress: optional ``callback(done, total)`` called after every chunk.
        jit: jit the vmapped function (one compilation for all chunks, cached
            across calls with the same ``fn`` object: :func:`compiled_vmap`).

    Returns:
        The pytree of ``fn``'s outputs with a leading axis of size ``num_runs``,
        as NumPy arrays.
    """
    check_key(key)
    num_runs = check_positive_int("num_runs", num_runs)  # 2.5 is refused, never silently 2
    chunk = num_runs if chunk_size is None else check_positive_int("chunk_size", chunk_size)
    chunk = min(chunk, num_runs)
    for i, arg in enumerate(run_args):
        for leaf in jax.tree_util.tree_leaves(arg):
            if np.shape(leaf)[:1] != (num_runs,):
                raise ValueError(
                    f"run_args[{i}] must have leading axis num_runs={num_runs}, got a leaf of shape {np.shape(leaf)}"
                )
    _check_chunk_fits(fn, key, run_args, chunk, chunk_size, num_runs, jit)
    keys = run_keys(key, num_runs)
    batched = (lambda *a: compiled_vmap(fn, *a)(*a)) if jit else jax.vmap(fn)

    outputs = []
    for start in range(0, num_runs, chunk):
        stop = min(start + chunk, num_runs)
        valid = stop - start
        sl = _pad_slice(keys, start, stop, chunk)
        args = jax.tree_util.tree_map(lambda a: _pad_slice(a, start, stop, chunk), run_args)
        out = batched(sl, *args)
        outputs.append(jax.tree_util.tree_map(lambda x: np.asarray(x)[:valid], out))
        if progress is not None:
            progress(stop, num_runs)
    return jax.tree_util.tree_map(lambda *xs: np.concatenate(xs, axis=0), *outputs)


def _check_chunk_fits(
    fn: Callable[..., Any], key: Any, run_args: tuple, chunk: int, chunk_size: Any, num_runs: int, jit: bool
) -> None:
    """Refuse a chunk that would exceed the device's memory (:mod:`jaxnav.core.memory`), before allocating it.

    Jitted, the chunk's program is compiled here (:func:`compiled_vmap` keeps it for the chunks, so
    ``fn`` is traced once) and XLA's own account is used: its inputs, outputs and working memory.
    Without ``jit``, :func:`jax.eval_shape` gives one run's outputs, times ``chunk``, plus the inputs.
    """
    if not memory.guard_enabled():
        return
    keys = jax.ShapeDtypeStruct((chunk, *np.shape(key)), key.dtype)
    # the dtype a chunk is sliced with: a NumPy float64 stays one (the chunks' signature)
    args = jax.tree_util.tree_map(
        lambda a: jax.ShapeDtypeStruct(
            (chunk, *np.shape(a)[1:]), dtype_of(a), weak_type=getattr(a, "weak_type", False)
        ),
        run_args,
    )
    if jit:
        exe = compiled_vmap(fn, keys, *args)
        try:
            stats = exe.memory_analysis()
            need = stats.argument_size_in_bytes + stats.output_size_in_bytes + stats.temp_size_in_bytes
        except Exception:  # noqa: BLE001  (a backend without XLA's memory statistics)
            need = memory.tree_bytes((keys, args, exe.out_info))
        what = f"a monte_carlo chunk of {chunk} runs (its inputs, outputs and XLA's working memory)"
    else:
        rows = jax.tree_util.tree_map(lambda a: jax.ShapeDtypeStruct(a.shape[1:], a.dtype), (keys, args))
        per_run = memory.output_bytes(fn, rows[0], *rows[1])
        if per_run is None:  # fn cannot be traced abstractly: the call itself says why
            return
        need = chunk * per_run + memory.tree_bytes((keys, args))
        what = f"a monte_carlo chunk of {chunk} runs (its inputs and outputs)"
    size = f"chunk_size ({chunk_size})" if chunk_size is not None else f"chunk_size (None: all {num_runs} runs at once)"
    memory.check_fits(need, what=what, fields=size)


def _pad_slice(x: Any, start: int, stop: int, size: int) -> jax.Array:
    """``x[start:stop]`` padded to ``size`` rows by repeating the last row."""
    part = x[start:stop]
    missing = size - (stop - start)
    if missing == 0:
        return part
    pad = jnp.repeat(part[-1:], missing, axis=0)
    return jnp.concatenate([part, pad], axis=0)


def scan_filter(
    step: Callable,
    config: Any,
    params: Any,
    controls: jax.Array,
    observations: Any,
    state: Any,
    key: jax.Array | None = None,
    unroll: int = 1,
) -> tuple[Any, Any]:
    """Every filter's ``run``: one ``lax.scan`` of ``step`` over time.

    With a ``key``, step ``t`` is ``step(fold_in(key, t), state, config, params, u_t, z_t)`` (so a
    Python loop of ``step`` calls with those keys reproduces the scan); without one the filter is
    deterministic and ``step(state, config, params, u_t, z_t)``. Returns ``(final_state, trace)``.
    ``unroll`` steps share one loop iteration (``lax.scan``'s ``unroll``): with 2, a state that a
    step rebuilds out of place (a gather) is written straight into the loop's buffer every
    second step instead of being copied back at every step, for a longer compilation.
    ``key`` must be one PRNG key or ``None`` (``ValueError`` naming it otherwise; its shape is
    checked under a trace too).
    """
    check_key(key, allow_none=True)
    if key is None:
        return jax.lax.scan(lambda s, x: step(s, config, params, *x), state, (controls, observations), unroll=unroll)

    def body(carry, inputs):
        t, u, z = inputs
        return step(jax.random.fold_in(key, t), carry, config, params, u, z)

    return jax.lax.scan(body, state, (jnp.arange(controls.shape[0]), controls, observations), unroll=unroll)
