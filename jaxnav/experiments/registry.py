"""The registry of [W]'s reproduced tables and figures, and the machinery they share.

An :class:`Experiment` names a result of [W] ("table-3.1", "fig-4.4", …) and
knows its *cells* (one ``(setting, method)`` per table row or curve point),
how to summarise the per-run errors of its cells into a JSON-ready result
(mean and 95 % interval of every column, [W]'s value beside it), and how to
render that result (terminal table, Markdown, PNG). :func:`run` is the one
entry point: it sweeps the cells with :func:`jaxnav.experiments.sweep.sweep`
(chunked, vmapped, resumable) and writes ``NAME.json``, ``NAME.md`` and
``NAME.png`` into an output directory.

Every experiment has a *quick* variant (short trajectories, few particles)
that the test suite runs in seconds; the full variant is the thesis
setting. Register a new one with :func:`register`.
"""

from __future__ import annotations

import functools
import json
import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import jax
import numpy as np

from jaxnav.experiments import hf_slam as hf
from jaxnav.experiments import sweep as sw

__all__ = [
    "Cell",
    "Experiment",
    "EXPERIMENTS",
    "register",
    "get",
    "run",
    "ERROR_COLUMNS",
    "error_cell",
    "summarize_column",
]

ERROR_COLUMNS = ("x_mm", "y_mm", "theta_rad", "dr_mm", "tx_mm", "ty_mm", "dt_mm")
"""[W]'s table columns: robot x, y, θ, distance; tag x, y, distance (mm, rad)."""


@dataclass(frozen=True)
class Cell:
    """One table row or curve point: a ``setting`` run by ``method``, grouped under ``row``.

    Attributes:
        id: unique id (it seeds the cell's runs: see :func:`jaxnav.experiments.sweep.run_key`).
        row: the result row the cell's runs are pooled into (Table 4.1 pools five rectangles).
        method: the method's name (:data:`jaxnav.experiments.hf_slam.METHODS` for the
            HF-RFID cells).
        setting: what the runs simulate (an :class:`~jaxnav.experiments.hf_slam.HFSetting`,
            an :class:`~jaxnav.experiments.ir_positioning.IRSetting`).
        fn: ``(run_key, *args) -> per-run result`` (default: [W]'s errors of
            :func:`hf_slam.run_once` for an HF setting).
        args: arrays given to every run of the cell after its key. Cells with
            the same ``fn`` and ``args`` of the same shapes share one compilation.
    """

    id: str
    row: str
    method: str
    setting: Any
    fn: Callable[..., Any] | None = None
    args: tuple = ()

    def run_fn(self) -> Callable[[jax.Array], Any]:
        return self.fn if self.fn is not None else error_cell(self.method, self.setting)


@functools.lru_cache(maxsize=256)
def error_cell(method: str, setting: hf.HFSetting) -> Callable[[jax.Array], hf.Errors]:
    """``key -> Errors`` of one seeded run of ``method`` on ``setting``.

    Cached: experiments sharing a (method, setting) cell get the same function, so
    they share its compilation (:func:`jaxnav.core.batch.compiled_vmap`).
    """

    def fn(key):
        return hf.run_once(key, method, setting)[0]

    return fn


@dataclass(frozen=True)
class Experiment:
    """A reproduced result of [W].

    Attributes:
        name: registry name, e.g. "table-3.1".
        title: one line.
        cells: ``quick -> [Cell]``.
        summarize: ``(runs {cell_id: {field: [R]}}, cells, quick) -> result`` (a JSON-ready dict).
        render: ``result -> str`` for the terminal.
        markdown: ``result -> str``.
        plot: ``(result, path) -> None`` writes a PNG.
        notes: printed under the result.
        batching: how a chunk of runs is evaluated, ``"vmap"`` or ``"map"``
            (:func:`jaxnav.experiments.sweep.sweep`).
        compiler_options: XLA options of the full variant's compilation (``None``: XLA's
            defaults), e.g. :data:`jaxnav.experiments.sweep.LIGHT_COMPILE`.
    """

    name: str
    title: str
    cells: Callable[[bool], list[Cell]]
    summarize: Callable[..., dict]
    render: Callable[[dict], str]
    markdown: Callable[[dict], str]
    plot: Callable[[dict, str], None]
    notes: str = ""
    batching: str = "vmap"
    compiler_options: dict | None = None


EXPERIMENTS: dict[str, Experiment] = {}


def register(experiment: Experiment) -> Experiment:
    """Add ``experiment`` to :data:`EXPERIMENTS` under its name."""
    EXPERIMENTS[experiment.name] = experiment
    return experiment


def get(name: str) -> Experiment:
    """The registered experiment ``name`` (a clear error listing the names otherwise)."""
    from jaxnav.experiments import _all  # noqa: F401  (registers the built-in experiments)

    if name not in EXPERIMENTS:
        raise ValueError(f"unknown experiment {name!r}; choose from {', '.join(sorted(EXPERIMENTS))}")
    return EXPERIMENTS[name]


def summarize_column(values: np.ndarray, paper: float | None) -> dict:
    """``{"mean", "ci95": [lo, hi], "paper"}`` of one column's per-run values."""
    m, lo, hi = sw.mean_ci(values)
    return {"mean": m, "ci95": [lo, hi], "paper": paper}


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
) -> dict:
    """Run experiment ``name`` with ``runs`` seeded runs per cell; write ``NAME.json/.md/.png`` to ``out_dir``.

    ``compiler_options`` are XLA options for the cells' compilation; by default the quick
    variant uses :data:`jaxnav.experiments.sweep.FAST_COMPILE` (its runs are short, its
    compilations are not) and the full one the experiment's own (``Experiment.compiler_options``:
    :data:`jaxnav.experiments.sweep.LIGHT_COMPILE` for the HF-RFID SLAM tables and figures,
    XLA's defaults for the others).

    The per-run results are checkpointed in ``out_dir/NAME.runs.json`` after every
    chunk: calling :func:`run` again with the same arguments resumes an interrupted
    sweep and gives the same result as an uninterrupted one; ``fresh=True`` discards it
    and starts again. ``workers`` chunks run at once (default
    :func:`jaxnav.experiments.sweep.default_workers`).
    """
    exp = get(name)
    cells = exp.cells(quick)
    checkpoint = None if out_dir is None else os.path.join(out_dir, f"{name}.{'quick.' if quick else ''}runs.json")
    raw = sw.sweep(
        [(c.id, c.run_fn(), c.args) for c in cells],
        runs,
        key,
        checkpoint,
        chunk_size,
        progress,
        meta={"experiment": name, "quick": quick},
        compiler_options=(sw.FAST_COMPILE if quick else exp.compiler_options)
        if compiler_options is None
        else compiler_options,
        batching=exp.batching,
        workers=workers,
        fresh=fresh,
    )
    result = exp.summarize(raw, cells, quick)
    result = {"experiment": name, "title": exp.title, "runs": int(runs), "quick": bool(quick), **result}
    if out_dir is not None:
        stem = os.path.join(out_dir, name + (".quick" if quick else ""))
        with open(stem + ".json", "w") as f:
            json.dump(result, f, indent=1)
        with open(stem + ".md", "w") as f:
            f.write(exp.markdown(result) + "\n")
        try:
            exp.plot(result, stem + ".png")
        except ImportError:
            pass
    return result
