"""What an experiment is: its cells, how it summarises their runs and how it renders the result.

An :class:`Experiment` names a reproduced result ("table-3.1", "fig-5.5", …)
and knows its *cells* (one ``(setting, method)`` per table row or curve
point, each a pure function of a run's key), how to summarise the per-run
results of its cells into a JSON-ready result, and how to render that result
(terminal table, Markdown, PNG). The studies build their experiments from
these two types; :mod:`jaxnav.experiments.registry` runs them and
:mod:`jaxnav.experiments.catalog` lists them. This module knows no study.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

__all__ = ["Cell", "Experiment"]


@dataclass(frozen=True)
class Cell:
    """One table row or curve point: a ``setting`` run by ``method``, grouped under ``row``.

    Attributes:
        id: unique id within its experiment (it seeds the cell's runs: see
            :func:`jaxnav.experiments.sweep.run_key`).
        row: the result row the cell's runs are pooled into (a table row may pool several cells).
        method: the method's name.
        setting: what the runs simulate (the study's setting type, hashable).
        fn: ``(run_key, *args) -> per-run result`` (a flat NamedTuple or dict of arrays), pure.
        args: arrays given to every run of the cell after its key. Cells with
            the same ``fn`` and ``args`` of the same shapes share one compilation.
    """

    id: str
    row: str
    method: str
    setting: Any
    fn: Callable[..., Any]
    args: tuple = ()


@dataclass(frozen=True)
class Experiment:
    """A reproduced result.

    Attributes:
        name: the name it is run by, e.g. "table-3.1".
        title: one line.
        cells: ``quick -> [Cell]`` (``quick``: the seconds-long variant the tests run).
        summarize: ``(runs {cell_id: {field: [R, ...]}}, cells, quick) -> result`` (a JSON-ready dict).
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
