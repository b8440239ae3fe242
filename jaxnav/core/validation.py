"""Host-side argument checks, run before anything is traced.

Each check raises ``ValueError`` naming the argument. Checks on *values* are
skipped for tracers (inside a user's ``jit``/``vmap`` the values are unknown);
checks on *shapes* always run, since shapes are static.
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np

__all__ = [
    "is_concrete",
    "check_positive_int",
    "check_fraction",
    "check_shape",
    "check_positive",
    "check_nonnegative",
    "check_finite",
    "check_choice",
    "check_covariance",
    "check_slots",
]


def is_concrete(x: Any) -> bool:
    """True if ``x`` holds known values (not a tracer)."""
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(x))


def check_positive_int(name: str, value: Any) -> int:
    """``value`` must be an integer ≥ 1."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def check_fraction(name: str, value: Any) -> float:
    """``value`` must be a real number in (0, 1]."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number in (0, 1], got {value!r}") from None
    if not (0.0 < v <= 1.0):
        raise ValueError(f"{name} must be in (0, 1], got {v}")
    return v


def check_shape(name: str, x: Any, shape: tuple[int | None, ...]) -> None:
    """``x`` must have ``shape``; ``None`` entries match any size."""
    actual = np.shape(x)
    if len(actual) != len(shape) or any(s is not None and s != a for s, a in zip(shape, actual)):
        want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        raise ValueError(f"{name} must have shape {want}, got {tuple(actual)}")


def _values(x: Any) -> np.ndarray | None:
    return np.asarray(x) if is_concrete(x) else None


def check_finite(name: str, x: Any) -> None:
    """No NaN or infinity in ``x`` (skipped for tracers)."""
    v = _values(x)
    if v is not None and not np.all(np.isfinite(v)):
        raise ValueError(f"{name} contains NaN or infinite values")


def check_positive(name: str, x: Any) -> None:
    """Every entry of ``x`` must be finite and > 0 (skipped for tracers)."""
    v = _values(x)
    if v is not None and not (np.all(np.isfinite(v)) and np.all(v > 0)):
        raise ValueError(f"{name} must be finite and strictly positive, got {v}")


def check_nonnegative(name: str, x: Any) -> None:
    """Every entry of ``x`` must be finite and ≥ 0 (skipped for tracers)."""
    v = _values(x)
    if v is not None and not (np.all(np.isfinite(v)) and np.all(v >= 0)):
        raise ValueError(f"{name} must be finite and non-negative, got {v}")


def check_choice(name: str, value: Any, choices: Any) -> None:
    """``value`` must be one of ``choices``."""
    if value not in choices:
        raise ValueError(f"{name} must be one of {sorted(choices)}, got {value!r}")


def check_covariance(name: str, cov: Any, dim: int | None = None) -> None:
    """``cov`` must be a ``[dim, dim]`` symmetric positive-definite matrix.

    Shape is always checked; symmetry (relative tolerance 1e-5) and positive
    definiteness (a Cholesky factorisation in float64) only for concrete values.
    """
    shape = np.shape(cov)
    if len(shape) != 2 or shape[0] != shape[1] or (dim is not None and shape[0] != dim):
        want = f"({dim}, {dim})" if dim is not None else "square (n, n)"
        raise ValueError(f"{name} must have shape {want}, got {tuple(shape)}")
    v = _values(cov)
    if v is None:
        return
    v = v.astype(np.float64)
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{name} contains NaN or infinite values")
    scale = max(float(np.max(np.abs(v))), np.finfo(np.float64).tiny)
    if np.max(np.abs(v - v.T)) > 1e-5 * scale:
        raise ValueError(f"{name} must be symmetric, got {v.tolist()}")
    try:
        np.linalg.cholesky(v)
    except np.linalg.LinAlgError:
        eig = np.linalg.eigvalsh(0.5 * (v + v.T))
        raise ValueError(f"{name} must be positive definite; its smallest eigenvalue is {eig.min():.3g}") from None


def check_slots(
    name: str, ids: Any, mask: Any, values: Any = None, ids_field: str = "ids", num_ids: int | None = None
) -> None:
    """Fixed observation slots: integer ``ids``, a boolean (or integer, nonzero = valid) ``mask``,
    and, where ``mask`` is set, finite ``values [..., D]`` (the latter skipped for tracers). With
    ``num_ids`` only the slots whose id is in ``[0, num_ids)`` must be finite: the filters drop and
    count the others without reading them.

    A float mask or float ids are refused (``0.5`` is neither valid nor invalid); a NaN or an
    infinity in a valid slot is refused with the first place it occurs, since a filter would
    carry it into every later estimate: mask such a slot out instead.
    """
    for field, x in ((ids_field, ids), ("mask", mask)):
        dtype = np.result_type(getattr(x, "dtype", None) or np.asarray(x).dtype)
        allowed = "biu" if field == "mask" else "iu"
        if dtype.kind not in allowed:
            what = "a boolean array (or integers, nonzero = valid)" if field == "mask" else "an integer array"
            raise ValueError(f"{name}.{field} must be {what}, got dtype {dtype}")
    if values is None or not is_concrete((mask, values)):
        return
    v = np.asarray(values)
    valid = np.broadcast_to(np.asarray(mask).astype(bool), v.shape[: np.ndim(mask)])
    if num_ids is not None:
        i = np.asarray(ids)
        valid = valid & (i >= 0) & (i < num_ids)
    bad = valid & ~np.all(np.isfinite(v.reshape(v.shape[: np.ndim(mask)] + (-1,))), axis=-1)
    if bad.any():
        where = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ValueError(
            f"{name}.z holds NaN or infinite values in {int(bad.sum())} valid slot(s), the first at index "
            f"{where}: mask such slots out ({name}.mask False) instead of passing them"
        )
