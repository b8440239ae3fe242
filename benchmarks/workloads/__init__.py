"""Registry of benchmark workloads.

A workload is a module in this package that calls :func:`register` at import
time with a :class:`Workload`. :func:`discover` imports every module of the
package, so adding W3, W4, W5, S1 or S2 is a new file here and nothing else:
the runner (``benchmarks/run.py``) is never edited.

A workload's ``run(ctx, size)`` returns the rows of one size (see
:func:`benchmarks.harness.make_row`), each implementation and mode one row,
and a :func:`benchmarks.harness.skipped_row` for what it could not measure.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass

__all__ = ["Workload", "register", "discover", "REGISTRY"]


@dataclass(frozen=True)
class Workload:
    """One benchmark workload.

    Attributes:
        name: ``"W1"``, ``"W2"``, … (the ``workload`` field of its rows).
        title: one line for logs and plot titles.
        sizes: full-run sizes, in increasing order (``{"N": 1000}``, …).
        run: ``run(ctx, size) -> list[dict]`` rows for one size.
        x_key: the size key drawn on the plot's x axis.
        quick_sizes: sizes for ``--quick`` (default: the two smallest).
        floor_doc: how ``floor_s`` is computed (bytes formula), copied to the JSON.
        series_key: optional extra row key that splits plot lines (e.g. ``"method"``).
    """

    name: str
    title: str
    sizes: Sequence[dict]
    run: Callable[..., list]
    x_key: str
    quick_sizes: Sequence[dict] | None = None
    floor_doc: str = ""
    series_key: str | None = None

    def sizes_for(self, quick: bool) -> list[dict]:
        if not quick:
            return list(self.sizes)
        return list(self.quick_sizes) if self.quick_sizes is not None else list(self.sizes)[:2]


REGISTRY: dict[str, Workload] = {}


def register(workload: Workload) -> Workload:
    if workload.name in REGISTRY and REGISTRY[workload.name] is not workload:
        raise ValueError(f"workload {workload.name!r} registered twice")
    REGISTRY[workload.name] = workload
    return workload


def _order(name: str) -> tuple:
    # Engine workloads (W*) first, then seed curves (S*), numerically within each.
    digits = "".join(c for c in name if c.isdigit())
    return (0 if name.startswith("W") else 1, int(digits) if digits else 0, name)


def discover() -> dict[str, Workload]:
    """Import every module of this package and return the registry in run order."""
    for info in pkgutil.iter_modules(__path__):
        if not info.name.startswith("_"):
            importlib.import_module(f"{__name__}.{info.name}")
    return {k: REGISTRY[k] for k in sorted(REGISTRY, key=_order)}
