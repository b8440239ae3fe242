"""Resumable batch Monte Carlo over the cells of an experiment.

A *cell* is one (setting, method) of a table or one point of a curve. All
``R`` seeded runs of a cell go through one jitted, ``vmap``-ed function in
chunks of ``chunk_size`` runs (the chunk bounds memory: every array of a
chunk's runs is alive at once). After every chunk the per-run results are
appended to a JSON checkpoint, written atomically (temporary file, then
rename), so an interrupted sweep keeps every finished chunk and
:func:`sweep` called again with the same arguments resumes where it stopped.

Keys: run ``r`` of cell ``c`` uses ``fold_in(fold_in(key, crc32(c)), r)``, so
its result depends neither on the chunk size nor on ``R`` (the first 10 runs
of a 100-run sweep are the 10 runs of a 10-run sweep) nor on the order of
the cells. A resumed sweep therefore gives the same numbers as one that ran
through. A checkpoint made with another seed, other cell definitions or
another jaxnav version is refused rather than mixed in; after changing the
code between two sweeps, start afresh (``fresh=True``, ``--fresh``): a
checkpoint cannot tell that its cells now compute something else.

Parallelism: ``workers`` chunks run at once in threads (XLA releases the
GIL), two by default on a two-core CPU, while the cells compile one after
the other in another thread: a cell's chunks start as soon as it is
compiled. Results are still saved in chunk order, so the numbers and the
checkpoint do not depend on ``workers``.

Summaries: :func:`mean_ci` gives the mean and the 95 % Student-t interval
``mean ± t_{0.975, R−1}·s/√R`` of the runs.
"""

from __future__ import annotations

import json
import os
import sys
import zlib
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import jax
import numpy as np

from jaxnav.core.batch import compiled_vmap

__all__ = [
    "cell_key",
    "run_key",
    "sweep",
    "default_workers",
    "Progress",
    "FAST_COMPILE",
    "LIGHT_COMPILE",
]

FAST_COMPILE = {"xla_backend_optimization_level": 0, "xla_cpu_use_fusion_emitters": False}
"""XLA options that trade run time for compile time: the CPU backend's LLVM optimisation off
and its older fusion code generator (a quick PF-SLAM cell compiles in 1.7 s instead of 7.9 s
and runs 4× slower on this CPU): right for the quick variants, whose runs take a fraction
of their compilation. (The level alone compiled in 3.0 s; the quick HF experiments took 84 s
with both options against 107 s with the level alone.)"""

LIGHT_COMPILE = {"xla_backend_optimization_level": 1}
"""XLA options that halve a full HF-RFID SLAM cell's compilation at no cost in run time: LLVM's
optimisation level 1 instead of 3. Table 3.1's cells (R = 10, this 2-core CPU): PF-SLAM at
100 tags/m² compiled in 6.8 s instead of 13.1 s, FastSLAM in 11.4 s instead of 14.0 s, and ran
as fast (0.41 / 0.40 s and 0.64 / 0.70 s per run). The code rounds differently in places: on
Table 3.1's 400 runs the scores differed in the last bit of a float32 at most, but on the other
tables and figures 13 of 160 PF-SLAM and PS-SLAM runs took another path (a particle filter
amplifies rounding), one fig-3.7 run from 22.5 to 18.3 mm robot error."""


def cell_key(key: jax.Array, cell_id: str) -> jax.Array:
    """The key of a cell: ``fold_in(key, crc32(cell_id))`` (independent of the cells' order)."""
    return jax.random.fold_in(key, zlib.crc32(cell_id.encode()) & 0x7FFFFFFF)


def run_key(key: jax.Array, cell_id: str, r: int) -> jax.Array:
    """The key of run ``r`` of a cell."""
    return jax.random.fold_in(cell_key(key, cell_id), r)


class Progress:
    """A progress bar over chunks on stderr (tqdm when installed, a plain line otherwise)."""

    def __init__(self, total: int, desc: str, enabled: bool = True):
        self.total, self.desc, self.enabled, self.done = total, desc, enabled, 0
        self._bar = None
        if enabled:
            try:
                from tqdm.auto import tqdm
            except ImportError:
                tqdm = None
            if tqdm is not None:
                self._bar = tqdm(total=total, desc=desc, unit="run", leave=False, file=sys.stderr)

    def update(self, n: int) -> None:
        self.done += n
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.update(n)
        else:
            print(f"\r{self.desc}: {self.done}/{self.total} runs", end="", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
        elif self.enabled:
            print(file=sys.stderr)


def _load(path: str | None, meta: dict) -> dict:
    if path is None or not os.path.exists(path):
        return {"meta": meta, "cells": {}}
    with open(path) as f:
        data = json.load(f)
    if data.get("meta") != meta:
        raise ValueError(
            f"{path} holds a sweep with other settings ({data.get('meta')!r}, not {meta!r}); "
            "use another output directory, or start afresh (fresh=True; on the command line --fresh)"
        )
    return data


def _save(path: str | None, data: dict) -> None:
    if path is None:
        return
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(data, f)
    os.replace(tmp, path)


def default_workers() -> int:
    """Chunks evaluated at once by :func:`sweep` when ``workers`` is not given.

    On the CPU backend, up to 4 (at most the cores this process may use): one
    XLA:CPU execution of a vmapped filter keeps barely more than one core
    busy, and two executions at once nearly double the throughput on two
    cores (a Table 3.1 FastSLAM chunk: 11.6 s alone, 11.7 s for two at once).
    On an accelerator, 1: one device runs one wide chunk at a time.
    """
    if jax.default_backend() != "cpu":
        return 1
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(4, cores))


def _evaluate(compiled, keys, shared):
    """One chunk in a worker thread: wait for the cell's executable, run it, bring the result to the host."""
    exe = compiled.result()
    return jax.device_get(exe(keys, *shared))


def sweep(
    cells: Sequence[tuple[str, Callable[[jax.Array], Any]]],
    runs: int,
    key: jax.Array,
    path: str | None = None,
    chunk_size: int = 25,
    progress: bool = True,
    meta: dict | None = None,
    on_chunk: Callable[[str, int], None] | None = None,
    compiler_options: dict | None = None,
    batching: str = "vmap",
    workers: int | None = None,
    fresh: bool = False,
) -> dict[str, dict[str, np.ndarray]]:
    """Run ``runs`` seeded runs of every cell; resume from ``path`` if it holds finished chunks.

    Args:
        cells: ``(cell_id, fn)`` pairs or ``(cell_id, fn, shared)`` triples;
            ``fn(run_key, *shared)`` is pure and returns a flat NamedTuple (or dict)
            of scalars or arrays per run; ``shared`` is a tuple of pytrees of arrays
            given whole to every run of the cell. Cells passing the same ``fn``
            object and ``shared`` of the same shapes share one compilation
            (:func:`jaxnav.core.batch.compiled_vmap`).
        runs: R, runs per cell.
        key: master key.
        path: JSON checkpoint (``None``: keep nothing on disk).
        chunk_size: runs per vmapped call.
        progress: draw a progress bar over the runs.
        meta: anything that identifies the sweep (checked on resume with the
            cells' ids and the jaxnav version; R is not part of it: a longer sweep
            extends a shorter one).
        on_chunk: ``callback(cell_id, runs_done)`` after every saved chunk.
        compiler_options: XLA options for the cells' compilation (e.g. :data:`FAST_COMPILE`).
        batching: how a chunk's runs are evaluated, ``"vmap"`` (vectorised) or ``"map"``
            (one after the other in one compiled loop; see
            :func:`jaxnav.core.batch.compiled_vmap`).
        workers: chunks evaluated at once, in threads (default :func:`default_workers`).
            The cells compile one after the other in a thread of their own, and a cell's
            chunks run as soon as it is compiled. Peak memory
            grows with ``workers × chunk_size``. Results are saved in chunk order, so
            the checkpoint and the numbers do not depend on ``workers``.
        fresh: ignore (and overwrite) an existing checkpoint at ``path`` instead of resuming
            it: use it after changing the code, which the checkpoint cannot detect.

    Returns:
        ``{cell_id: {field: array [R, ...]}}`` (NumPy).
    """
    runs = int(runs)
    if runs < 1:
        raise ValueError(f"runs must be a positive integer, got {runs}")
    chunk = int(chunk_size)
    if chunk < 1:
        raise ValueError(f"chunk_size must be a positive integer, got {chunk_size}")
    if batching not in ("vmap", "map"):
        raise ValueError(f"batching must be 'vmap' or 'map', got {batching!r}")
    workers = default_workers() if workers is None else workers
    if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    # never pad a sweep of fewer runs than a chunk up to a whole chunk (the padding is computed)
    chunk = min(chunk, runs)
    cells = [(c[0], c[1], tuple(c[2]) if len(c) > 2 else ()) for c in cells]
    ids = [c for c, _, _ in cells]
    if len(set(ids)) != len(ids):
        raise ValueError(f"cell ids must be unique, got {ids}")
    from jaxnav import __version__

    header = {
        "cells": ids,
        "seed": np.asarray(jax.random.key_data(key)).tolist(),
        "jaxnav": __version__,
        **(meta or {}),
    }
    data = {"meta": header, "cells": {}} if fresh else _load(path, header)
    bar = Progress(runs * len(cells), "Monte Carlo", progress)

    # Every chunk still to run, in order: (cell_id, start, stop, keys padded to a full chunk: one compilation).
    work = []
    for cell_id, _fn, _shared in cells:
        stored = data["cells"].setdefault(cell_id, {})
        done = len(next(iter(stored.values()))) if stored else 0
        bar.update(min(done, runs))
        base = cell_key(key, cell_id)
        for start in range(done, runs, chunk):
            idx = np.arange(start, start + chunk)
            keys = jax.vmap(lambda r: jax.random.fold_in(base, r))(idx)
            work.append((cell_id, start, min(start + chunk, runs), keys))
    shared_of = {cell_id: (fn, shared) for cell_id, fn, shared in cells}
    pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="jaxnav-sweep")
    # The cells compile one after the other in their own thread, in the order of the chunks,
    # while the workers run the chunks of the cells already compiled: XLA:CPU's compiler keeps
    # about 1.5 cores busy by itself, and two compilations at once took longer than one after
    # the other (Table 3.1's four cells: 57 s against 45 s).
    compiler = ThreadPoolExecutor(max_workers=1, thread_name_prefix="jaxnav-compile")
    try:
        compiled = {}
        for cell_id, _, _, keys in work:
            if cell_id not in compiled:
                fn, shared = shared_of[cell_id]
                compiled[cell_id] = compiler.submit(
                    compiled_vmap, fn, keys, shared=shared, mode=batching, compiler_options=compiler_options
                )
        pending = [pool.submit(_evaluate, compiled[c], keys, shared_of[c][1]) for c, _, _, keys in work]
        for (cell_id, start, stop, _), future in zip(work, pending):
            result = future.result()
            fields = result._asdict() if hasattr(result, "_asdict") else dict(result)
            stored = data["cells"][cell_id]
            for name, value in fields.items():
                stored.setdefault(name, []).extend(np.asarray(value)[: stop - start].tolist())
            _save(path, data)
            bar.update(stop - start)
            if on_chunk is not None:
                on_chunk(cell_id, stop)
    finally:
        pool.shutdown(wait=False, cancel_futures=True)
        compiler.shutdown(wait=False, cancel_futures=True)
        bar.close()
    out: dict[str, dict[str, np.ndarray]] = {}
    for cell_id in ids:
        stored = data["cells"][cell_id]
        out[cell_id] = {name: np.asarray(values[:runs]) for name, values in stored.items()}
    return out
