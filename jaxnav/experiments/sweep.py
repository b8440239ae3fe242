"""Resumable batch Monte Carlo over the cells of an experiment.

A *cell* is one (setting, method) of a table or one point of a curve. All
``R`` seeded runs of a cell go through one jitted, ``vmap``-ed function in
chunks of ``chunk_size`` runs (the chunk bounds memory: every array of a
chunk's runs is alive at once). After every chunk the per-run results are
appended to a JSON checkpoint, written atomically (temporary file, then
rename), so an interrupted sweep keeps every finished chunk and
:func:`sweep` called again with the same arguments resumes where it stopped.

Keys and chunks: run ``r`` of cell ``c`` uses ``fold_in(fold_in(key, crc32(c)), r)``,
whatever the chunk size, ``R`` or the order of the cells, and chunk ``k`` of
a cell always holds runs ``k·w … k·w + w − 1`` (``w`` the chunk width). A
run's value is therefore bit for bit the same whenever its chunk has the same
width: a resumed sweep gives the numbers of one that ran through, and a longer
sweep extends a shorter one (its first 10 runs are the 10 runs of a 10-run
sweep) as long as both evaluate chunks of the same width. Between widths a
run agrees only to float32 rounding (XLA vectorises a chunk's runs in other
ways for another width; a particle filter may amplify the difference), so the
checkpoint records its width and a resume that would evaluate chunks of
another width is refused. The width is ``chunk_size``, or ``R`` when a new
sweep has fewer runs than a chunk (no padding is computed); a checkpoint
keeps its width when it is resumed with the same ``chunk_size``.

The checkpoint is a JSON object ``{"meta", "chunk_size", "cells", "sha256"}``:
``meta`` identifies the sweep (the cells' ids, the seed, the jaxnav version
and the caller's ``meta``), ``chunk_size`` is the width of its chunks,
``cells`` maps a cell's id to ``{field: [one value per run]}``, every field of
a cell holding the same number of runs, and ``sha256`` is the SHA-256 (hex) of
the other three in a canonical form: ``json.dumps({"meta", "chunk_size",
"cells"}, sort_keys=True, separators=(",", ":"), ensure_ascii=True,
allow_nan=False)`` of the values as read back, encoded as UTF-8, so it does not
depend on the file's layout (indentation, key order). A run's value is a number, ``true``
or ``false``, or a list of them for an array-valued field; a non-finite float
(NaN, ±inf: a run with nothing to score, or one that diverged) is written as
``null`` and read back as NaN (standard JSON has no NaN). A checkpoint
that does not record ``chunk_size`` is read when it holds every run asked
for; adding runs to it is refused. The checkpoint is
validated when it is loaded: an unreadable or truncated file, another
structure, fields of uneven lengths, values that are not numbers or ``null``
(strings, NaN or Infinity literals, numbers out of range), fields other than
those its cells return, another seed, other cells, another jaxnav version or
another chunk width are refused with a ``ValueError`` that names the file,
never mixed in. So is a checkpoint whose values no longer match its ``sha256``:
a value edited by hand or damaged on the disk (a run's error of 9.8 mm turned
into 12,509 mm would otherwise move a mean without a word). A checkpoint
without ``sha256`` (written by jaxnav before it recorded one, or with the key
removed) is read, since its values cannot be checked, with a warning
(:class:`UnverifiedCheckpointWarning`); adding runs to it rewrites it with its
checksum, and ``--fresh`` recomputes it. After changing the code between two
sweeps, start afresh (``fresh=True``, ``--fresh``): a checkpoint cannot tell
that its cells now compute something else with the same fields.

Files: the checkpoint must be a regular file. A folder, a named pipe (FIFO), a
device (``/dev/zero``, ``/dev/null``) or a socket at ``path`` is refused before
it is opened (reading a named pipe would wait forever, a device would read as
endless or empty data) with a ``ValueError`` naming it, ``fresh`` or not. The
checkpoint is written to a temporary file in its folder, flushed to the disk,
then renamed over the previous one: a full disk, an exceeded quota, a read-only
file system or a lost permission raise an ``OSError`` naming the file and the
cause in words (its ``errno`` is the original one), and leave the checkpoint as
it was after the last chunk saved, to resume from.

Devices: one call evaluates consecutive chunks of a cell, one per device
(every device by default: :func:`jaxnav.core.batch.run_devices`), each
with the program one device runs on one chunk, so the numbers and the
checkpoint are the same on any number of devices and a sweep interrupted on
one number resumes on another.

Many processes: under ``jax.distributed`` (:mod:`jaxnav.core.processes`) the devices are those of
every process, each process runs the same sweep, process 0 reads the checkpoint and tells the
others what it holds, and only process 0 writes it; every process returns the same results.

Parallelism: ``workers`` calls run at once in threads (XLA releases the
GIL; by default one per core on a CPU, up to 4: :func:`default_workers`), while the cells compile one after
the other in another thread: a cell's chunks start as soon as it is
compiled. Results are still saved in chunk order, so the numbers and the
checkpoint do not depend on ``workers``. On a CPU, the chunks of a cell whose program calls
LAPACK (FastSLAM 2.0's Cholesky factors, an EKF's solves) run one at a time
(:func:`jaxnav.core.batch.calls_lapack`: two at once can hang XLA:CPU, and so can one spread over several
devices: its chunks then run on one device, one after the other); other cells' chunks run beside them.

Summaries of the runs (means, intervals, runs left out and counted) are in
:mod:`jaxnav.experiments.stats`.
"""

from __future__ import annotations

import hashlib
import json
import os
import warnings
import zlib
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import jax
import numpy as np

from jaxnav.core import processes
from jaxnav.core.batch import LAPACK_LOCK, calls_lapack, compiled_vmap, run_devices
from jaxnav.core.filter import check_key
from jaxnav.core.progress import Progress
from jaxnav.io._files import open_regular, require_regular, write_atomic

__all__ = [
    "cell_key",
    "run_key",
    "sweep",
    "default_workers",
    "Progress",
    "UnverifiedCheckpointWarning",
    "FAST_COMPILE",
    "LIGHT_COMPILE",
]

FAST_COMPILE = {"xla_backend_optimization_level": 0, "xla_cpu_use_fusion_emitters": False}
"""XLA options for the quick variants, which trade run time for compile time.

The CPU backend's LLVM optimisation is off and it uses its older fusion code generator: a quick
PF-SLAM cell compiles several times faster and runs several times slower, which is the right trade
for runs that take a fraction of their compilation."""

LIGHT_COMPILE = {"xla_backend_optimization_level": 1}
"""XLA options for the full HF-RFID SLAM cells, which halve compilation at no cost in run time.

LLVM's optimisation level 1 instead of 3. The code rounds differently in places: a particle filter
amplifies rounding, so a few runs of a table take another path than under XLA's defaults, within
the runs' spread."""


def cell_key(key: jax.Array, cell_id: str) -> jax.Array:
    """The key of a cell: ``fold_in(key, crc32(cell_id))`` (independent of the cells' order)."""
    check_key(key)
    return jax.random.fold_in(key, zlib.crc32(cell_id.encode()) & 0x7FFFFFFF)


def run_key(key: jax.Array, cell_id: str, r: int) -> jax.Array:
    """The key of run ``r`` of a cell."""
    return jax.random.fold_in(cell_key(key, cell_id), r)


_KEYS = ("meta", "chunk_size", "cells")
"""The keys of a checkpoint's values, in the order they are written (its checksum, :data:`_CHECKSUM`, last)."""

_CHECKSUM = "sha256"
"""The key of a checkpoint's checksum: the SHA-256 of its values (:func:`_checksum`)."""

_FRESH = "pass --fresh (fresh=True) to discard it and start again"

_NOT_REGULAR = "remove it or use another output directory (a checkpoint is a regular JSON file)"


class UnverifiedCheckpointWarning(UserWarning):
    """A checkpoint without a checksum (written before checkpoints recorded one) is read unverified."""


class _Invalid(Exception):
    """Why a checkpoint cannot be used (turned into a ``ValueError`` naming its file)."""


class _OtherSweep(_Invalid):
    """The checkpoint is a valid one of another sweep (other seed, cells, version or ``meta``)."""


class _OtherWidth(_Invalid):
    """The checkpoint's chunks have another width than those this sweep would compute (``stored``)."""

    def __init__(self, reason: str, stored: int):
        super().__init__(reason)
        self.stored = stored


def _refused(path: str | None, reason: str, advice: str = _FRESH) -> ValueError:
    """The one-line error of a checkpoint that cannot be used."""
    where = "the sweep's runs" if path is None else path
    return ValueError(f"{where}: {reason}; {advice}")


_JSON_TYPES = {dict: "an object", list: "an array", str: "a string", bool: "true/false", type(None): "null"}


def _json_type(value: Any) -> str:
    """What ``value`` read from JSON is, in JSON's words ("an object", "a string", "a number", …)."""
    return _JSON_TYPES.get(type(value), "a number")


def _short(value: Any, limit: int = 60) -> str:
    """``repr(value)``, cut to ``limit`` characters (one line)."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _literal(name: str) -> float:
    raise _Invalid(f"it holds the non-standard JSON literal {name} (a non-finite run is written as null)")


def _unique_keys(pairs: list) -> dict:
    keys = [k for k, _ in pairs]
    if len(set(keys)) != len(keys):
        twice = next(k for k in keys if keys.count(k) > 1)
        raise _Invalid(f"an object holds the key {_short(twice)} twice")
    return dict(pairs)


def _read(path: str) -> Any:
    """The JSON in ``path`` (standard JSON only: no NaN or Infinity literals, no key given twice)."""
    try:
        with open_regular(path, _NOT_REGULAR, encoding="utf-8") as f:
            text = f.read()
    except UnicodeDecodeError:
        raise _Invalid("it is not UTF-8 text, so not a sweep checkpoint") from None
    if not text.strip():
        raise _Invalid("the file is empty")
    try:
        return json.loads(text, parse_constant=_literal, object_pairs_hook=_unique_keys)
    except json.JSONDecodeError as err:
        raise _Invalid(
            f"it is not valid JSON ({err.msg}: line {err.lineno}, column {err.colno}): a truncated or damaged file"
        ) from None
    except RecursionError:
        raise _Invalid("it nests lists or objects too deeply to be a sweep checkpoint") from None


_KINDS = {type(None): "null", bool: "bool", int: "int", float: "float"}
"""What a run's value (or an entry of it) read from JSON may be."""


def _decode(values: Any) -> np.ndarray:
    """The array ``[R, ...]`` of one field's runs as stored: numbers, booleans or ``null`` (NaN), nested evenly."""
    if not isinstance(values, list):
        raise _Invalid(f"is {_json_type(values)}, not an array of runs")
    try:
        arr = np.array(values, dtype=object)
    except ValueError:
        raise _Invalid("holds runs of uneven shapes") from None
    kinds = np.frompyfunc(lambda v: _KINDS.get(type(v), "?"), 1, 1)(arr) if arr.size else np.empty(arr.shape, object)
    null, flag, whole = kinds == "null", kinds == "bool", kinds == "int"
    odd = kinds == "?"
    if odd.any():
        first = arr[odd].flat[0]
        if isinstance(first, list):
            raise _Invalid("holds runs of uneven shapes")
        raise _Invalid(f"holds {_short(first)}, {_json_type(first)}, where a number or null was expected")
    if flag.any():
        if not flag.all():
            raise _Invalid("mixes true/false with numbers or null")
        return arr.astype(bool)
    try:
        if whole.all():
            return arr.astype(np.int64)
        out = np.where(null, np.nan, arr).astype(np.float64)
    except OverflowError:
        raise _Invalid("holds a number out of range") from None
    if not np.all(np.isfinite(out[~null])):
        raise _Invalid("holds a number out of the float range (such as 1e999)")
    return out


def _encode(value: Any) -> list:
    """One chunk's values of a field as JSON lists: a non-finite float becomes ``null``."""
    a = np.asarray(value)
    if a.dtype.kind == "f":
        bad = ~np.isfinite(a)
        if bad.any():
            a = a.astype(object)
            a[bad] = None
    return a.tolist()


def _check_cells(cells: Any, ids: Sequence[str]) -> None:
    """``cells`` maps known cell ids to ``{field: runs}`` with the same number of runs in every field."""
    if not isinstance(cells, dict):
        raise _Invalid(f"its cells are {_json_type(cells)}, not an object")
    for cell_id, fields in cells.items():
        if cell_id not in ids:
            raise _Invalid(f"it holds runs of the cell {_short(cell_id)}, which this sweep does not have")
        if not isinstance(fields, dict):
            raise _Invalid(f"cell {_short(cell_id)} is {_json_type(fields)}, not an object of fields")
        counts = {}
        for name, values in fields.items():
            try:
                counts[name] = len(_decode(values))
            except _Invalid as err:
                raise _Invalid(f"field {_short(name)} of cell {_short(cell_id)} {err}") from None
        if len(set(counts.values())) > 1:
            listed = ", ".join(f"{n} {_short(k)}" for k, n in counts.items())
            raise _Invalid(f"the fields of cell {_short(cell_id)} hold different numbers of runs ({listed})")


def _meta_difference(stored: dict, header: dict) -> str:
    """What differs between a checkpoint's ``meta`` and this sweep's: ``key X in the file, Y here`` per key."""
    missing = object()

    def show(d: dict, k: str) -> str:
        return _short(d[k]) if k in d else "none"

    keys = [*header, *(k for k in stored if k not in header)]
    diffs = [
        f"{k} {show(stored, k)} in the file, {show(header, k)} here"
        for k in keys
        if stored.get(k, missing) != header.get(k, missing)
    ]
    return "; ".join(diffs)


def _check(data: Any, header: dict) -> None:
    """Refuse (``_Invalid``) a checkpoint that is not one of this sweep (module docstring)."""
    if not isinstance(data, dict):
        raise _Invalid(f"it holds {_json_type(data)}, not an object with the keys meta, chunk_size, cells")
    missing = [k for k in _KEYS if k not in data and k != "chunk_size"]  # chunk_size may be absent (module docstring)
    if missing:
        raise _Invalid(f"it lacks the key{'s' if len(missing) > 1 else ''} {', '.join(missing)}")
    extra = [k for k in data if k not in (*_KEYS, _CHECKSUM)]
    if extra:
        raise _Invalid(f"it holds the unknown key{'s' if len(extra) > 1 else ''} {', '.join(map(_short, extra))}")
    if not isinstance(data["meta"], dict):
        raise _Invalid(f"its meta is {_json_type(data['meta'])}, not an object")
    if data["meta"] != header:
        raise _OtherSweep(f"it holds a sweep with other settings ({_meta_difference(data['meta'], header)})")
    width = data.get("chunk_size", 1)
    if isinstance(width, bool) or not isinstance(width, int) or width < 1:
        raise _Invalid(f"its chunk_size is {_short(width)}, not a positive integer")
    digest = data.get(_CHECKSUM, "0" * 64)
    if not (isinstance(digest, str) and len(digest) == 64 and all(c in "0123456789abcdef" for c in digest)):
        raise _Invalid(f"its {_CHECKSUM} is {_short(digest)}, not a SHA-256 digest (64 hexadecimal digits)")
    _check_cells(data["cells"], header["cells"])


def _checksum(data: dict) -> str:
    """The SHA-256 (hex) of a checkpoint's values in their canonical JSON form (module docstring)."""
    values = {k: data[k] for k in _KEYS if k in data}
    text = json.dumps(values, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def _load(path: str | None, header: dict) -> dict | None:
    """The checkpoint at ``path``, validated against this sweep's ``header``; ``None`` when there is none."""
    if path is None or not require_regular(path, _NOT_REGULAR, missing_ok=True):
        return None
    try:
        data = _read(path)
        _check(data, header)
    except _OtherSweep as err:
        raise _refused(path, str(err), "use another output directory, or " + _FRESH) from None
    except _Invalid as err:
        raise _refused(path, str(err)) from None
    return data


def _load_shared(path: str | None, header: dict) -> dict | None:
    """:func:`_load` in process 0, its outcome (the checkpoint, none, or the error) in every process of a
    ``jax.distributed`` job (:mod:`jaxnav.core.processes`): the others need not see the file."""
    if jax.process_count() == 1:
        return _load(path, header)
    outcome: dict = {}
    if processes.is_first():
        try:
            outcome["data"] = _load(path, header)
        except ValueError as err:
            outcome["error"] = str(err)
    outcome = json.loads(processes.share_text(json.dumps(outcome)))
    if "error" in outcome:
        raise ValueError(outcome["error"])
    return outcome["data"]


def _kind(dtype: Any) -> str:
    """``"b"`` booleans, ``"i"`` integers, ``"f"`` anything else (floats)."""
    kind = np.dtype(dtype).kind
    return "b" if kind == "b" else "i" if kind in "iu" else "f"


def _check_fields(cell_id: str, stored: dict, expected: Any) -> None:
    """The stored runs of a cell have the fields, per-run shapes and kinds its function returns (``expected``:
    ``jax.eval_shape`` of one run)."""
    want = expected._asdict() if hasattr(expected, "_asdict") else dict(expected)
    if set(want) != set(stored):
        raise _Invalid(
            f"the runs of cell {_short(cell_id)} hold the fields {', '.join(map(_short, stored))}, but the cell "
            f"returns {', '.join(map(_short, want))}: the checkpoint was written by other code"
        )
    for name, spec in want.items():
        values = _decode(stored[name])
        if values.shape[1:] != tuple(spec.shape):
            raise _Invalid(
                f"field {_short(name)} of cell {_short(cell_id)} holds runs of shape {values.shape[1:]}, but the cell "
                f"returns shape {tuple(spec.shape)}: the checkpoint was written by other code"
            )
        have, need = _kind(values.dtype), _kind(spec.dtype)
        if have != need and not (have == "i" and need == "f"):
            text = {"b": "true/false", "i": "integers", "f": "numbers with fractions or null"}
            raise _Invalid(f"field {_short(name)} of cell {_short(cell_id)} holds {text[have]}, not {text[need]}")


def _chunk_width(requested: int, runs: int, stored: int | None) -> int:
    """The width of the chunks still to run: this sweep's own, or the checkpoint's (``stored``) if it was
    made with the same ``chunk_size``; another width is refused (``_OtherWidth``)."""
    own = min(requested, runs)
    if stored is None or stored in (own, requested):
        return own if stored is None else stored
    asked = f"{own}" if own == requested else f"{own} (--chunk {requested} with --runs {runs})"
    raise _OtherWidth(
        f"it holds runs computed in chunks of {stored} and this sweep would compute chunks of {asked}: "
        "a run's float32 rounding depends on the chunk size, so its runs would not match",
        stored,
    )


def _save(path: str | None, data: dict) -> None:
    """Write the checkpoint with its checksum, atomically (module docstring)."""
    if path is None or not processes.is_first():  # under jax.distributed, process 0 writes
        return
    record = {k: data[k] for k in _KEYS}
    record[_CHECKSUM] = _checksum(record)
    write_atomic(
        path,
        lambda f: json.dump(record, f, allow_nan=False),
        make_folder=True,
        not_regular_advice=_NOT_REGULAR,
        note="the checkpoint keeps the chunks saved before: run the same command again to resume from them",
    )


def default_workers(devices: int = 1) -> int:
    """Calls evaluated at once by :func:`sweep` when ``workers`` is not given, for a sweep over
    ``devices`` devices (one chunk each per call).

    On the CPU backend with one device, up to 4 (at most the cores this process may use): one
    XLA:CPU execution of a vmapped filter keeps barely more than one core
    busy, and two executions at once on two cores take about as long as one,
    nearly doubling the throughput.
    On an accelerator, or over several devices, 1: each device runs one wide chunk at a time.
    """
    if jax.default_backend() != "cpu" or devices > 1:
        return 1
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(4, cores))


def _compile_cell(fn, keys, shared, mode, compiler_options, devices):
    """The cell's executable, and whether its chunks must run one at a time (:func:`calls_lapack` on a CPU)."""
    exe = compiled_vmap(fn, keys, shared=shared, mode=mode, compiler_options=compiler_options, devices=devices)
    return exe, jax.default_backend() == "cpu" and calls_lapack(exe)


def _evaluate(compiled, keys, shared):
    """One chunk in a worker thread: wait for the cell's executable, run it, bring the result to the host.
    A program that calls LAPACK runs while no other such program does (:func:`calls_lapack`)."""
    exe, exclusive = compiled.result()
    if not exclusive:
        return jax.device_get(exe(keys, *shared))
    with LAPACK_LOCK:
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
    devices: Any = None,
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
        key: master key, one PRNG key (``ValueError`` naming it otherwise).
        path: JSON checkpoint (``None``: keep nothing on disk).
        chunk_size: runs per vmapped call (fewer for a new sweep of fewer runs). The checkpoint
            records it, and resuming it with another chunk size that would compute chunks of
            another width is refused (the runs would differ in float32 rounding; module docstring).
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
        devices: the devices one call spreads a cell's consecutive chunks over, one chunk per
            device (:func:`jaxnav.core.batch.run_devices`: every device by default).
            Each device runs the program of one chunk, so the numbers and the checkpoint are
            the same on any number of devices, and a sweep resumes on another number.

    Raises:
        ValueError: bad arguments, or a checkpoint at ``path`` that cannot be resumed (module
            docstring): damaged, edited by hand (its values do not match its checksum), of another
            sweep; the message, one line, names the file and says to pass ``--fresh``. Also a
            ``path`` that is a folder, a named pipe, a device or a socket, ``fresh`` or not.
        OSError: the checkpoint cannot be written (disk full, quota exceeded, read-only file
            system, permission denied): the message names the file and the cause; the file keeps
            the chunks saved before.

    Warns:
        UnverifiedCheckpointWarning: the checkpoint at ``path`` has no checksum (written before
            checkpoints recorded one): its values are read unverified.

    Returns:
        ``{cell_id: {field: array [R, ...]}}`` (NumPy; a non-finite float is NaN).
    """
    check_key(key)
    runs = int(runs)
    if runs < 1:
        raise ValueError(f"runs must be a positive integer, got {runs}")
    chunk = int(chunk_size)
    if chunk < 1:
        raise ValueError(f"chunk_size must be a positive integer, got {chunk_size}")
    if batching not in ("vmap", "map"):
        raise ValueError(f"batching must be 'vmap' or 'map', got {batching!r}")
    devices = run_devices(devices)
    workers = default_workers(len(devices)) if workers is None else workers
    if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    if jax.process_count() > 1:  # every process must make the calls in one order (each is a collective)
        workers, progress = 1, progress and processes.is_first()
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
    header = json.loads(json.dumps(header))  # as it reads back from the file (tuples are lists)
    if path is not None:  # refused before anything is computed, even when it would be written over
        require_regular(path, _NOT_REGULAR, missing_ok=True)
    data = None if fresh else _load_shared(path, header)
    # whether the values read match the checksum they were written with (checked once the fields are, so a
    # checkpoint of other code is named as such); computed before the cells not yet run are added below
    intact = data is None or _CHECKSUM not in data or data[_CHECKSUM] == _checksum(data)
    if data is not None and _CHECKSUM not in data:
        warnings.warn(
            f"{path}: the checkpoint has no {_CHECKSUM} checksum (it was written before checkpoints recorded "
            f"one), so its values are read unverified; {_FRESH} if it may have been edited",
            UnverifiedCheckpointWarning,
            stacklevel=2,
        )
    data = data or {"meta": header, "chunk_size": None, "cells": {}}
    done = {cell_id: _runs_stored(data["cells"].setdefault(cell_id, {})) for cell_id in ids}
    try:
        for cell_id, fn, shared in cells:
            if done[cell_id]:
                _check_fields(cell_id, data["cells"][cell_id], _one_run_shape(fn, cell_key(key, cell_id), shared))
        if not intact:
            raise _Invalid(
                f"its values do not match its {_CHECKSUM} checksum: the file was edited or damaged after it was "
                "written, so its runs cannot be trusted"
            )
        todo = any(n < runs for n in done.values())
        stored = data.get("chunk_size") if any(done.values()) and todo else None
        if any(done.values()) and todo and "chunk_size" not in data:
            raise _Invalid(
                "it does not record its chunk size, so runs added to it could round differently from its own "
                "(it is read as it is when it holds every run asked for)"
            )
        width = _chunk_width(chunk, runs, stored)
    except _OtherWidth as err:
        advice = f"resume with --chunk {err.stored} (chunk_size={err.stored}), or {_FRESH}"
        raise _refused(path, str(err), advice) from None
    except _Invalid as err:
        raise _refused(path, str(err)) from None
    if todo:
        data["chunk_size"] = width

    # Every call still to make, in order: (cell_id, start, stop, keys of full chunks, one per device: one
    # compilation; runs already stored). Chunk k holds runs k·width … k·width + width − 1 whatever was
    # stored; a call evaluates consecutive chunks, the last call of a cell padded with runs past R.
    first = {cell_id: done[cell_id] // width * width for cell_id in ids}
    chunks_left = max([-(-(runs - first[c]) // width) for c in ids if first[c] < runs], default=1)
    if not processes.spans_processes(devices):  # every process must hold a block of every call
        devices = devices[:chunks_left]  # no device without a chunk of its own
    group = width * len(devices)
    work = []
    for cell_id, _fn, _shared in cells:
        base = cell_key(key, cell_id)
        for start in range(first[cell_id], runs, group):
            idx = np.arange(start, start + group)
            keys = jax.vmap(lambda r: jax.random.fold_in(base, r))(idx)
            work.append((cell_id, start, min(start + group, runs), keys, max(done[cell_id] - start, 0)))
    shared_of = {cell_id: (fn, shared) for cell_id, fn, shared in cells}
    to_compile = len({cell_id for cell_id, *_ in work})
    bar = Progress(
        runs * len(cells),
        "Monte Carlo",
        progress,
        note=_compiling_note(to_compile) if to_compile else None,
        initial=sum(min(n, runs) for n in done.values()),
    )
    pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="jaxnav-sweep")
    # The cells compile one after the other in their own thread, in the order of the chunks,
    # while the workers run the chunks of the cells already compiled: XLA:CPU's compiler keeps
    # about 1.5 cores busy by itself, and two compilations at once take longer than one after
    # the other.
    compiler = ThreadPoolExecutor(max_workers=1, thread_name_prefix="jaxnav-compile")
    try:
        compiled = {}
        for cell_id, _, _, keys, _ in work:
            if cell_id not in compiled:
                fn, shared = shared_of[cell_id]
                compiled[cell_id] = compiler.submit(
                    _compile_cell, fn, keys, shared, batching, compiler_options, devices
                )
        pending = [pool.submit(_evaluate, compiled[c], keys, shared_of[c][1]) for c, _, _, keys, _ in work]
        for (cell_id, start, stop, _, skip), future in zip(work, pending):
            result = future.result()
            fields = result._asdict() if hasattr(result, "_asdict") else dict(result)
            stored = data["cells"][cell_id]
            for name, value in fields.items():
                stored.setdefault(name, []).extend(_encode(np.asarray(value)[skip : stop - start]))
            _save(path, data)
            bar.update(stop - start - skip)
            if on_chunk is not None:
                on_chunk(cell_id, stop)
    finally:
        pool.shutdown(wait=False, cancel_futures=True)
        compiler.shutdown(wait=False, cancel_futures=True)
        bar.close()
    out: dict[str, dict[str, np.ndarray]] = {}
    for cell_id in ids:
        out[cell_id] = {}
        for name, values in data["cells"][cell_id].items():
            try:
                out[cell_id][name] = _decode(values[:runs])
            except _Invalid as err:
                raise _refused(path, f"field {_short(name)} of cell {_short(cell_id)} {err}") from None
    return out


def _compiling_note(cells: int) -> str:
    """The line printed before the progress display: the first runs wait for their compilation."""
    what = "the runs of 1 setting" if cells == 1 else f"the runs of {cells} settings, one after the other,"
    return f"compiling {what} with XLA (the count starts once the first is compiled)…"


def _runs_stored(fields: dict) -> int:
    """The number of runs a validated cell of a checkpoint holds."""
    return len(next(iter(fields.values()))) if fields else 0


def _one_run_shape(fn: Callable, key: jax.Array, shared: tuple) -> Any:
    """What ``fn`` returns for one run (``jax.eval_shape``: traced, not compiled or run)."""
    return jax.eval_shape(lambda k: fn(k, *shared), key)
