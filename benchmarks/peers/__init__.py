"""Non-jaxnav implementations timed beside jaxnav (optional extras, ``pip install -e ".[bench]"``).

:func:`optional_import` returns ``None`` for a peer that is not installed, and
the workloads then write a ``skipped`` row with the reason.
"""

from __future__ import annotations

import importlib
from types import ModuleType


def optional_import(name: str) -> tuple[ModuleType | None, str | None]:
    """``(module, None)`` or ``(None, reason)`` when ``name`` cannot be imported."""
    try:
        return importlib.import_module(name), None
    except Exception as exc:  # ImportError, or a broken install (e.g. numba mismatch)
        return None, f"{name} not importable ({type(exc).__name__}: {exc}); install with pip install -e '.[bench]'"
