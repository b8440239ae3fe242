"""Run the reproduced tables and figures by name: the one entry point shared by every study.

:func:`run` looks an :class:`~jaxnav.experiments.experiment.Experiment` up by
name (:func:`get`), sweeps its cells with :func:`jaxnav.experiments.sweep.sweep`
(chunked, vmapped, resumable), summarises the runs and writes ``NAME.json``,
``NAME.md`` and ``NAME.png`` into an output directory. :func:`experiments`
and :func:`names` list what can be run.

Every experiment has a *quick* variant (short trajectories, few particles)
that the test suite runs in seconds; the full variant is the thesis
setting.

This module knows no study: the experiments come from the explicit list of
:mod:`jaxnav.experiments.catalog`, loaded the first time a name is looked
up, so importing the registry loads no study. A new experiment is added to
that list.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from typing import Any

import jax

from jaxnav.core import processes
from jaxnav.core.filter import check_key
from jaxnav.experiments import sweep as sw
from jaxnav.experiments.experiment import Cell, Experiment
from jaxnav.io._files import require_regular, write_atomic, write_atomic_path

__all__ = ["Cell", "Experiment", "experiments", "names", "get", "output_stem", "run"]

_NOT_REGULAR = "remove it or use another output directory (the results are written as regular files)"


def experiments() -> Mapping[str, Experiment]:
    """Every experiment by name (read-only; :func:`jaxnav.experiments.catalog.experiments`)."""
    from jaxnav.experiments import catalog  # the studies, imported when first needed

    return catalog.experiments()


def names() -> tuple[str, ...]:
    """The names of :func:`experiments`, sorted."""
    return tuple(sorted(experiments()))


def get(name: str) -> Experiment:
    """The experiment ``name`` (a clear error listing the names otherwise)."""
    known = experiments()
    if name not in known:
        raise ValueError(f"unknown experiment {name!r}; choose from {', '.join(sorted(known))}")
    return known[name]


def output_stem(out_dir: str, name: str, quick: bool = False) -> str:
    """Where :func:`run` writes experiment ``name``: ``STEM.json``, ``STEM.md``, ``STEM.png`` and
    ``STEM.runs.json``, ``STEM`` being ``out_dir/NAME`` (``out_dir/NAME.quick`` for the quick variant)."""
    return os.path.join(out_dir, name + (".quick" if quick else ""))


def run(
    name: str,
    runs: int,
    key: jax.Array,
    out_dir: str | None = None,
    quick: bool = False,
    chunk_size: int = 25,
    progress: bool = True,
    compiler_options: dict | None = None,
    workers: int | None = None,
    fresh: bool = False,
    plot: bool = True,
    devices: Any = None,
) -> dict:
    """Run experiment ``name`` with ``runs`` seeded runs per cell; write ``NAME.json/.md/.png`` to ``out_dir``.

    ``key`` is the master key, one PRNG key (``jax.random.key(seed)`` or ``jax.random.PRNGKey(seed)``):
    anything else is refused with a ``ValueError`` naming it before the experiment is loaded.

    ``compiler_options`` are XLA options for the cells' compilation; by default the quick
    variant uses :data:`jaxnav.experiments.sweep.FAST_COMPILE` (its runs are short, its
    compilations are not) and the full one the experiment's own (``Experiment.compiler_options``:
    :data:`jaxnav.experiments.sweep.LIGHT_COMPILE` for the HF-RFID SLAM tables and figures,
    XLA's defaults for the others).

    The quick variant evaluates a chunk's runs one after the other in a compiled ``lax.map``
    (``batching="map"`` of :func:`jaxnav.experiments.sweep.sweep`), the full one as the experiment
    says (``Experiment.batching``, mostly ``"vmap"``). Tracing a filter under ``vmap`` costs over
    twice what tracing it once does (a quick ``ps-slam-readings`` cell: 6.5 s against 2.8 s, its
    compilation and its runs about as long either way), and cells that run the same filter share its
    trace only unbatched; the quick variant's few, short runs gain nothing from being vectorised.
    The runs' numbers are the same either way, up to rounding.

    The per-run results are checkpointed in ``out_dir/NAME.runs.json`` after every
    chunk: calling :func:`run` again with the same arguments resumes an interrupted
    sweep and gives the same result as an uninterrupted one; ``fresh=True`` discards it
    and starts again. A checkpoint that cannot be resumed (damaged, of another sweep, of
    another chunk size: :mod:`jaxnav.experiments.sweep`) raises a one-line ``ValueError``
    naming it. ``workers`` chunks run at once (default
    :func:`jaxnav.experiments.sweep.default_workers`), each a chunk per device of ``devices``
    (:func:`jaxnav.core.batch.run_devices`: every device by default; the numbers do not
    depend on it). Runs that diverged are left out of
    the summaries and counted in the result (``diverged_runs``) and its tables.

    Every file is written atomically (a temporary file in ``out_dir``, then renamed): a file that
    cannot be written (disk full, quota exceeded, read-only, permission denied) raises an
    ``OSError`` naming it and its cause, and leaves the file there as it was; the checkpoint keeps
    the runs, so the same call writes the results again without computing them. A folder, a named
    pipe or a device at one of these paths is refused with a ``ValueError`` naming it, before
    anything is computed.

    The PNG needs matplotlib: without it none is written, silently. ``plot=False`` writes
    none; the caller can then draw it with ``get(name).plot(result, output_stem(...) + ".png")``
    and tell its user when matplotlib is missing (as ``jaxnav experiments run`` does).
    """
    check_key(key)  # one PRNG key, refused by name before any study is loaded
    exp = get(name)
    cells = exp.cells(quick)
    checkpoint = None if out_dir is None else output_stem(out_dir, name, quick) + ".runs.json"
    if out_dir is not None:  # refused now, not after the sweep
        for ext in (".json", ".md", ".png"):
            require_regular(output_stem(out_dir, name, quick) + ext, _NOT_REGULAR, missing_ok=True)
    raw = sw.sweep(
        [(c.id, c.fn, c.args) for c in cells],
        runs,
        key,
        checkpoint,
        chunk_size,
        progress,
        meta={"experiment": name, "quick": quick},
        compiler_options=(sw.FAST_COMPILE if quick else exp.compiler_options)
        if compiler_options is None
        else compiler_options,
        batching="map" if quick else exp.batching,
        workers=workers,
        fresh=fresh,
        devices=devices,
    )
    result = exp.summarize(raw, cells, quick)
    result = {"experiment": name, "title": exp.title, "runs": int(runs), "quick": bool(quick), **result}
    if out_dir is not None and processes.is_first():  # under jax.distributed, process 0 writes
        stem = output_stem(out_dir, name, quick)
        kept = f"the runs are kept in {checkpoint}: running this again writes the results without computing them"
        markdown = exp.markdown(result) + "\n"
        write_atomic(stem + ".json", lambda f: json.dump(result, f, indent=1), make_folder=True, note=kept)
        write_atomic(stem + ".md", lambda f: f.write(markdown), note=kept)
        if plot:
            try:
                write_atomic_path(stem + ".png", lambda path: exp.plot(result, path), note=kept)
            except ImportError:  # matplotlib is not installed
                pass
    return result
