"""Batch Monte Carlo: many seeded runs in vmapped, jitted chunks.

``monte_carlo(fn, key, num_runs, chunk_size)`` splits ``key`` into one key per
run and evaluates ``fn(run_key, *run_args)`` with ``vmap`` over chunks of
``chunk_size`` runs. The chunk size bounds peak memory (all intermediate
arrays of one chunk are alive at once); the last chunk is padded to the same
size so the jitted function compiles exactly once, and the padding is dropped
from the result. Results are stacked along a new leading axis of size
``num_runs`` and returned as NumPy arrays on the host, so a long sweep does not
hold every chunk's output on the device.

Devices: with several devices (every device by default: the GPUs of a
machine, the CPU devices of ``XLA_FLAGS=--xla_force_host_platform_device_count=N``, every
process's under ``jax.distributed``: :mod:`jaxnav.core.processes`),
one call evaluates one chunk per device, through ``jax.shard_map`` over a
one-axis mesh named ``"runs"``. Each device runs the same program as a single
device would on its chunk, so a run's result depends on its key and the chunk
width only: bit for bit the same on 1, 2 or 4 devices (``tests/core/test_devices.py``).
"""

from __future__ import annotations

import threading
import weakref
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import memory, processes
from jaxnav.core.filter import check_key
from jaxnav.core.validation import check_positive_int, dtype_of

__all__ = [
    "monte_carlo",
    "run_keys",
    "scan_filter",
    "compiled_vmap",
    "run_devices",
    "calls_lapack",
    "LAPACK_LOCK",
    "RUN_AXIS",
]

_COMPILED: weakref.WeakKeyDictionary[Callable, dict] = weakref.WeakKeyDictionary()
_COMPILING = threading.Lock()  # guards _COMPILED and _LOCKS
_LOCKS: weakref.WeakKeyDictionary[Callable, dict] = weakref.WeakKeyDictionary()
LAPACK_LOCK = threading.Lock()
"""Held while a program that calls LAPACK runs on the CPU (:func:`calls_lapack`); a caller that runs
such programs from several threads takes it around each call (:func:`jaxnav.experiments.sweep.sweep`)."""
RUN_AXIS = "runs"
"""The name of the mesh axis that :func:`compiled_vmap` spreads the runs over."""


def calls_lapack(exe: Any) -> bool:
    """Whether ``exe`` (compiled, or lowered: ``jax.jit(f).lower(...)``) calls LAPACK (a Cholesky, LU, QR, SVD or eigen-decomposition custom call).

    XLA:CPU runs a LAPACK call on a batch of many small matrices as tasks on the thread pool that
    also runs the programs, and waits for them: two such programs started at once from two threads
    can each hold a pool thread while waiting for tasks queued behind the other, and never finish
    (measured with jax 0.10.2 on 2 cores: a loop over the Cholesky factors of 25,000 3 × 3 matrices,
    started twice at once, hangs; one at a time, or beside programs without LAPACK, it does not).
    One such program spread over two CPU devices hangs the same way, so :func:`compiled_vmap`
    runs its blocks one after the other on one device.
    """
    try:
        text = exe.as_text()
    except Exception:  # an executable without HLO text: assume it may
        return True
    return 'custom_call_target="lapack_' in text or "custom_call @lapack_" in text  # compiled, or lowered


def run_devices(devices: Any = None) -> tuple:
    """The devices a batch of runs is spread over: every device of the default backend (``None``:
    ``jax.devices()``, this process's devices, or every process's under ``jax.distributed``:
    :mod:`jaxnav.core.processes`), this process's first ``n`` (an integer ``n ≥ 1``; under
    ``jax.distributed`` each process then computes every run itself, and process 0 writes), or the
    given sequence of distinct devices. ``ValueError`` naming ``devices`` otherwise."""
    if devices is None:
        return tuple(jax.devices())
    if isinstance(devices, (int, np.integer)) and not isinstance(devices, bool):
        local = jax.local_devices()
        if not 1 <= devices <= len(local):
            raise ValueError(f"devices must be between 1 and the {len(local)} local device(s), got {devices}")
        return tuple(local[: int(devices)])
    try:
        chosen = tuple(devices)
    except TypeError:
        chosen = ()
    if not chosen or not all(isinstance(d, jax.Device) for d in chosen) or len(set(chosen)) != len(chosen):
        raise ValueError(
            f"devices must be None, a number of local devices or a sequence of distinct jax devices, got {devices!r}"
        )
    return chosen


def compiled_vmap(
    fn: Callable[..., Any],
    *args: Any,
    shared: tuple = (),
    mode: str = "vmap",
    compiler_options: dict | None = None,
    devices: Any = 1,
    lanes: int | None = None,
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

    ``devices`` (:func:`run_devices`; default one device): with ``D > 1`` devices the rows are
    split into ``D`` equal blocks, one per device (``jax.shard_map`` over the mesh axis
    :data:`RUN_AXIS`; the leading axis must be a multiple of ``D``), and each device evaluates its
    block with the program one device would run on it: the rows' values are bit for bit those of
    ``D`` separate calls of width ``rows / D``. The outputs come back as arrays sharded over the
    devices.

    ``lanes`` (``"vmap"`` mode): each device's rows are vmapped ``lanes`` at a time, the groups one
    after the other in a ``lax.map``; a row's value then depends on ``lanes`` alone, not on how many
    rows a call or a device has (each device's rows must be a multiple of it).
    """
    if mode not in ("vmap", "map"):
        raise ValueError(f"mode must be 'vmap' or 'map', got {mode!r}")
    if lanes is not None:
        lanes = check_positive_int("lanes", lanes)
    devices = run_devices(devices)
    options = dict(compiler_options or {})
    shared = tuple(shared)
    leaves, tree = jax.tree_util.tree_flatten((args, shared))
    signature = (
        tree,
        tuple((np.shape(x), str(getattr(x, "dtype", None) or np.result_type(x))) for x in leaves),
        mode,
        tuple(sorted(options.items())),
        tuple(d.id for d in devices),
        lanes,
    )
    with _COMPILING:
        per_fn = _COMPILED.setdefault(fn, {})
        lock = _LOCKS.setdefault(fn, {}).setdefault(signature, threading.Lock())
    with lock:  # threads asking for one signature compile it once (sweep compiles cells concurrently)
        if signature not in per_fn:
            n = len(args)

            def batched(*all_args):
                rows, common = all_args[:n], all_args[n:]
                if mode == "vmap" and lanes is not None:
                    return _in_lanes(lambda *r: fn(*r, *common), rows, lanes)
                if mode == "vmap":
                    return jax.vmap(lambda *r: fn(*r, *common))(*rows)
                return jax.lax.map(lambda r: fn(*r, *common), rows)

            program, placement = (
                (jax.jit(batched), ()) if len(devices) == 1 else _sharded(batched, devices, args, shared)
            )
            lowered = program.lower(*args, *shared)
            if len(devices) > 1 and devices[0].platform == "cpu" and calls_lapack(lowered):
                blocks = jax.tree_util.tree_map(
                    lambda a: jax.ShapeDtypeStruct((np.shape(a)[0] // len(devices), *np.shape(a)[1:]), dtype_of(a)),
                    args,
                )
                local = [d for d in devices if d.process_index == jax.process_index()][:1] or jax.local_devices()[:1]
                one = compiled_vmap(
                    fn, *blocks, shared=shared, mode=mode, compiler_options=compiler_options, devices=local, lanes=lanes
                )
                exe = _BlockByBlock(one, len(args), len(devices))
            else:
                exe = lowered.compile(compiler_options=options or None)
                if processes.spans_processes(devices):
                    exe = processes.AcrossProcesses(exe, placement)
            per_fn[signature] = exe
    return per_fn[signature]


def _in_lanes(row_fn: Callable, rows: tuple, lanes: int) -> Any:
    """``vmap(row_fn)`` over ``rows`` (leading axis a multiple of ``lanes``), ``lanes`` rows at a time."""
    count = np.shape(jax.tree_util.tree_leaves(rows)[0])[0]
    if count % lanes:
        raise ValueError(f"lanes ({lanes}) must divide the rows each device evaluates ({count})")
    groups = jax.tree_util.tree_map(lambda x: x.reshape(count // lanes, lanes, *x.shape[1:]), rows)
    out = jax.lax.map(lambda g: jax.vmap(row_fn)(*g), groups)
    return jax.tree_util.tree_map(lambda x: x.reshape(count, *x.shape[2:]), out)


class _BlockByBlock:
    """A program of ``size`` devices that calls LAPACK, run as ``size`` calls of the one-device
    program ``one`` on consecutive blocks of rows, one after the other (:func:`calls_lapack`): the
    same values, bit for bit, as the devices would give. Otherwise it is ``one``
    (``memory_analysis``, ``as_text``: a block's, which is what one device holds)."""

    def __init__(self, one: Any, num_row_args: int, size: int):
        self.one, self.num_row_args, self.size = one, num_row_args, size

    def __call__(self, *args: Any) -> Any:
        rows, shared = args[: self.num_row_args], args[self.num_row_args :]
        width = np.shape(jax.tree_util.tree_leaves(rows)[0])[0] // self.size
        outs = [
            self.one(*jax.tree_util.tree_map(lambda a, i=i: a[i * width : (i + 1) * width], rows), *shared)
            for i in range(self.size)
        ]
        return jax.tree_util.tree_map(lambda *xs: jnp.concatenate(xs), *outs)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.one, name)


def _sharded(batched: Callable, devices: tuple, args: tuple, shared: tuple) -> tuple[Any, tuple]:
    """``batched`` with its row arguments split over ``devices`` (one block each) and ``shared`` copied
    to all, jitted; and the sharding of each argument. ``check_vma=False``: a user's function need not say which of its values vary
    across devices (a ``lax.cond`` with a constant branch would otherwise be refused)."""
    size = len(devices)
    for leaf in jax.tree_util.tree_leaves(args):
        if np.shape(leaf)[0] % size:
            raise ValueError(f"{size} devices need a multiple of {size} rows, got a leaf of shape {np.shape(leaf)}")
    mesh = jax.sharding.Mesh(np.asarray(devices), (RUN_AXIS,))
    rows, whole = jax.sharding.PartitionSpec(RUN_AXIS), jax.sharding.PartitionSpec()
    specs = (rows,) * len(args) + (whole,) * len(shared)
    program = jax.shard_map(batched, mesh=mesh, in_specs=specs, out_specs=rows, check_vma=False)
    placement = tuple(jax.sharding.NamedSharding(mesh, spec) for spec in specs)
    return jax.jit(program, in_shardings=placement, out_shardings=jax.sharding.NamedSharding(mesh, rows)), placement


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
    devices: Any = None,
    lanes: int | None = None,
) -> Any:
    """Evaluate ``fn(key_r, *args_r)`` for ``r = 0 … num_runs − 1``, vmapped in chunks.

    Args:
        fn: a pure function of a PRNG key and optional per-run arguments,
            returning a pytree of arrays.
        key: master key, one PRNG key; run ``r`` receives ``run_keys(key, num_runs)[r]``.
        num_runs: R ≥ 1.
        *run_args: pytrees whose leaves have leading axis ``num_runs`` (e.g.
            simulated data per run); sliced per chunk.
        chunk_size: runs per vmapped call on one device, the chunk's width (default: all at once,
            divided among the devices). A run's value depends on its key and this width only: on
            any number of devices it is bit for bit the same for the same width (between widths
            it agrees to float32 rounding: :func:`run_keys`). Bounds memory: a chunk whose
            inputs, outputs and XLA's working memory (from the compiled chunk; without ``jit``,
            ``chunk_size`` times one run's outputs from :func:`jax.eval_shape`) exceed the
            device's memory is refused with a ``ValueError`` before anything is allocated
            (:mod:`jaxnav.core.memory`, which also says how to go ahead anyway).
        progress: optional ``callback(done, total)`` called after every chunk.
        jit: jit the vmapped function (one compilation for all chunks, cached
            across calls with the same ``fn`` object: :func:`compiled_vmap`).
        devices: where the chunks run (:func:`run_devices`: every device by default, a
            number of them, or a sequence); one call evaluates a chunk on each device at once
            (module docstring), never more devices than there are chunks. Without ``jit``, one
            device.
        lanes: vmap a chunk's runs ``lanes`` at a time, one group after the other
            (:func:`compiled_vmap`): a run's value then depends on its key and ``lanes`` only,
            bit for bit the same for any ``chunk_size`` (a multiple of ``lanes``; the default
            chunk is rounded up to one) and any number of devices. Default: the whole chunk at
            once, fastest, whose width decides the rounding.

    Returns:
        The pytree of ``fn``'s outputs with a leading axis of size ``num_runs``,
        as NumPy arrays.
    """
    check_key(key)
    num_runs = check_positive_int("num_runs", num_runs)  # 2.5 is refused, never silently 2
    devs = run_devices(devices) if jit else (None,)
    if lanes is not None and not jit:
        raise ValueError("lanes needs jit=True (the groups run in a compiled loop)")
    if chunk_size is None:
        chunk = -(-num_runs // len(devs))
    else:
        chunk = min(check_positive_int("chunk_size", chunk_size), num_runs)
    if lanes is not None:
        lanes = check_positive_int("lanes", lanes)
        if chunk_size is not None and chunk_size % lanes:
            raise ValueError(f"chunk_size ({chunk_size}) must be a multiple of lanes ({lanes})")
        chunk = -(-chunk // lanes) * lanes  # whole groups (a run past the end is padding)
    if not jit or not processes.spans_processes(devs):  # every process must hold a block of every call
        devs = devs[: -(-num_runs // chunk)]  # no device without a chunk of its own
    group = chunk * len(devs)  # runs per call: one chunk per device
    for i, arg in enumerate(run_args):
        for leaf in jax.tree_util.tree_leaves(arg):
            if np.shape(leaf)[:1] != (num_runs,):
                raise ValueError(
                    f"run_args[{i}] must have leading axis num_runs={num_runs}, got a leaf of shape {np.shape(leaf)}"
                )
    _check_chunk_fits(fn, key, run_args, chunk, chunk_size, num_runs, jit, devs, lanes)
    keys = run_keys(key, num_runs)
    batched = (lambda *a: compiled_vmap(fn, *a, devices=devs, lanes=lanes)(*a)) if jit else jax.vmap(fn)

    outputs = []
    for start in range(0, num_runs, group):
        stop = min(start + group, num_runs)
        valid = stop - start
        sl = _pad_slice(keys, start, stop, group)
        args = jax.tree_util.tree_map(lambda a: _pad_slice(a, start, stop, group), run_args)
        out = batched(sl, *args)
        outputs.append(jax.tree_util.tree_map(lambda x: np.asarray(x)[:valid], out))
        if progress is not None:
            progress(stop, num_runs)
    return jax.tree_util.tree_map(lambda *xs: np.concatenate(xs, axis=0), *outputs)


def _check_chunk_fits(
    fn: Callable[..., Any],
    key: Any,
    run_args: tuple,
    chunk: int,
    chunk_size: Any,
    num_runs: int,
    jit: bool,
    devices: tuple,
    lanes: int | None = None,
) -> None:
    """Refuse a chunk that would exceed the device's memory (:mod:`jaxnav.core.memory`), before allocating it.

    Jitted, the chunk's program is compiled here (:func:`compiled_vmap` keeps it for the chunks, so
    ``fn`` is traced once) and XLA's own account is used: its inputs, outputs and working memory.
    Without ``jit``, :func:`jax.eval_shape` gives one run's outputs, times ``chunk``, plus the inputs.
    """
    if not memory.guard_enabled():
        return
    group = chunk * len(devices)  # one chunk per device; XLA's memory statistics are per device
    keys = jax.ShapeDtypeStruct((group, *np.shape(key)), key.dtype)
    # the dtype a chunk is sliced with: a NumPy float64 stays one (the chunks' signature)
    args = jax.tree_util.tree_map(
        lambda a: jax.ShapeDtypeStruct(
            (group, *np.shape(a)[1:]), dtype_of(a), weak_type=getattr(a, "weak_type", False)
        ),
        run_args,
    )
    if jit:
        exe = compiled_vmap(fn, keys, *args, devices=devices, lanes=lanes)
        try:
            stats = exe.memory_analysis()
            need = stats.argument_size_in_bytes + stats.output_size_in_bytes + stats.temp_size_in_bytes
        except Exception:  # noqa: BLE001  (a backend without XLA's memory statistics)
            need = memory.tree_bytes((keys, args, exe.out_info)) // len(devices)
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
