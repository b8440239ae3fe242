"""Host-side argument checks, run before anything is traced.

Each check raises ``ValueError`` naming the argument. Checks on *values* are
skipped for tracers (inside a user's ``jit``/``vmap`` the values are unknown);
checks on *shapes* always run, since shapes are static.
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "is_concrete",
    "check_positive_int",
    "check_nonnegative_int",
    "check_fraction",
    "check_shape",
    "check_positive",
    "check_nonnegative",
    "check_finite",
    "check_choice",
    "check_covariance",
    "check_slots",
    "MAX_MAGNITUDE",
    "check_magnitude",
    "check_covariances",
    "float_array",
    "check_bounds",
    "as_array",
    "check_type",
    "first_index",
    "check_real",
    "finite_within",
    "all_finite_within",
    "all_nonnegative",
    "all_positive",
    "any_negative",
]

MAX_MAGNITUDE = 1e6
"""The largest magnitude a control, a noise parameter or a coordinate may have, in SI units (m, s,
rad, m/s). The models square and multiply these values (``α₁v²``, ``dx² + dy²``, ``J Σ Jᵀ``);
past about 1e19 a square overflows single precision and a filter would return NaN. No indoor
robot moves a million metres per step, so anything larger is a unit or data error."""


def is_concrete(x: Any) -> bool:
    """True if ``x`` holds known values (not a tracer)."""
    if type(x) is np.ndarray or is_array_value(x):  # one array, the common case: no tree walk
        return True
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(x))


_ARRAY_VALUE_TYPES: dict[type, bool] = {}
"""Leaf type -> whether it is a JAX array holding values (not a tracer): a test the host checks make
on every array of every call, answered from this table after the first time a type is seen."""


def is_array_value(leaf: Any) -> bool:
    """``leaf`` is a concrete JAX array (immutable values in a buffer, which donation can delete)."""
    kind = type(leaf)
    known = _ARRAY_VALUE_TYPES.get(kind)
    if known is None:
        known = _ARRAY_VALUE_TYPES[kind] = issubclass(kind, jax.Array) and not issubclass(kind, jax.core.Tracer)
    return known


def dtype_of(x: Any) -> Any:
    """The dtype of an array, or the one NumPy reads ``x`` with (a Python number or list)."""
    dtype = getattr(x, "dtype", None)
    return dtype if dtype is not None else np.asarray(x).dtype


def check_positive_int(name: str, value: Any) -> int:
    """``value`` must be an integer ≥ 1."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def check_nonnegative_int(name: str, value: Any) -> int:
    """``value`` must be an integer ≥ 0 (a count that may be zero, e.g. a number of steps)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
        raise ValueError(f"{name} must be a non-negative integer, got {value!r}")
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
    actual = getattr(x, "shape", None)  # what np.shape reads first, without its dispatch
    if not isinstance(actual, tuple):
        actual = np.shape(x)
    if len(actual) != len(shape) or any(s is not None and s != a for s, a in zip(shape, actual)):
        want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        raise ValueError(f"{name} must have shape {want}, got {tuple(actual)}")


def _values(name: str, x: Any) -> np.ndarray | None:
    """The values of ``x`` on the host (``None`` for tracers); ``ValueError`` naming ``name`` if
    ``x`` is not a number or an array of numbers (``None``, a string, an object)."""
    if not is_concrete(x):
        check_real(name, x)
        return None
    v = np.asarray(x) if x is not None else None
    if v is not None and v.dtype.kind == "V" and jnp.issubdtype(v.dtype, jnp.floating):
        v = v.astype(np.float32)  # bfloat16 and other ml_dtypes floats: NumPy reads them as "void"
    if v is None or v.dtype.kind not in "biufc":
        raise ValueError(f"{name} must be a number or an array of numbers, got {type(x).__name__}")
    check_real(name, v)
    return v


def check_real(name: str, x: Any) -> None:
    """``x`` must not hold complex numbers (a noise level, a distance, a time step is real): a
    ``ValueError`` naming ``name`` and the dtype. Reads only the dtype, so it also runs for tracers."""
    dtype = getattr(x, "dtype", None)
    if dtype is None and isinstance(x, (list, tuple, complex)):
        try:
            dtype = np.asarray(x).dtype
        except (TypeError, ValueError):  # ragged: not numbers, for the caller's other checks to name
            return
    # A complex dtype is NumPy kind "c" (JAX has no complex type of its own), read without
    # jnp.issubdtype's dispatch; JAX's key dtypes have no kind, and are not complex.
    if getattr(dtype, "kind", None) == "c":
        raise ValueError(f"{name} must hold real numbers, got dtype {np.dtype(dtype).name}")


def check_type(name: str, x: Any, expected: type | tuple[type, ...]) -> None:
    """``x`` must be an instance of ``expected``; ``ValueError`` naming ``name`` and the type."""
    if not isinstance(x, expected):
        types = expected if isinstance(expected, tuple) else (expected,)
        raise ValueError(f"{name} must be {' or '.join(t.__name__ for t in types)}, got {type(x).__name__}")


def check_finite(name: str, x: Any) -> None:
    """No NaN or infinity in ``x`` (skipped for tracers)."""
    v = _values(name, x)
    if v is not None and not np.all(np.isfinite(v)):
        raise ValueError(f"{name} contains NaN or infinite values")


def check_positive(name: str, x: Any) -> None:
    """Every entry of ``x`` must be finite and > 0 (skipped for tracers)."""
    v = _values(name, x)
    if v is not None and not (np.all(np.isfinite(v)) and np.all(v > 0)):
        raise ValueError(f"{name} must be finite and strictly positive, got {v}")


def check_nonnegative(name: str, x: Any) -> None:
    """Every entry of ``x`` must be finite and ≥ 0 (skipped for tracers)."""
    v = _values(name, x)
    if v is not None and not (np.all(np.isfinite(v)) and np.all(v >= 0)):
        raise ValueError(f"{name} must be finite and non-negative, got {v}")


def first_index(bad: np.ndarray) -> tuple[int, ...]:
    """The index of the first True entry of ``bad`` (``()`` for a scalar), for error messages."""
    return tuple(int(i) for i in np.argwhere(bad)[0]) if np.ndim(bad) else ()


_FEW = 64
"""Arrays of at most this many values are compared in Python: one step's control or observation
slots, where NumPy's three calls (abs, compare, all) cost several times the comparisons."""


def _all_within(v: np.ndarray, limit: float) -> bool:
    """Every entry of ``v`` finite with ``|v| ≤ limit`` (NaN and ±inf compare False)."""
    if v.size <= _FEW:
        return all(-limit <= e <= limit for e in v.ravel().tolist())
    return bool((np.abs(v) <= limit).all())


def any_negative(v: np.ndarray) -> bool:
    """Whether an entry of the host array ``v`` is below zero (NaN is not), in Python for a few values."""
    if v.size <= _FEW:
        return any(e < 0 for e in v.ravel().tolist())
    return bool((v < 0).any())


def check_magnitude(name: str, x: Any, limit: float = MAX_MAGNITUDE) -> None:
    """Every entry of ``x`` must be finite with ``|x| ≤ limit`` (skipped for tracers).

    Raises ``ValueError`` naming ``name``, the first offending index and its value.
    """
    v = _values(name, x)
    if v is None or v.dtype.kind not in "fiuc":
        return
    if _all_within(v, limit):  # one pass for the common case: NaN and ±inf compare False
        return
    bad = ~np.isfinite(v) | (np.abs(v) > limit)
    if bad.any():
        where = first_index(bad)
        raise ValueError(
            f"{name} holds {int(bad.sum())} value(s) that are not finite or exceed {limit:g} in magnitude, "
            f"the first ({float(v[where]):g}) at index {where}; values are in SI units (m, s, rad)"
        )


def finite_within(x: Any, limit: float = MAX_MAGNITUDE) -> jax.Array:
    """Elementwise and traceable: ``x`` finite with ``|x| ≤ limit`` (NaN and ±inf give False).

    The twin of :func:`check_magnitude` for use inside a ``jit``, where the host cannot read values.
    """
    return jnp.isfinite(x) & (jnp.abs(x) <= limit)


def all_finite_within(x: Any, limit: float = MAX_MAGNITUDE) -> jax.Array:
    """``bool[]``, traceable: every entry of ``x`` finite with ``|x| ≤ limit`` (:func:`finite_within`)."""
    return jnp.all(finite_within(x, limit))


def all_nonnegative(x: Any, limit: float = MAX_MAGNITUDE) -> jax.Array:
    """``bool[]``, traceable: every entry of ``x`` satisfies ``0 ≤ x ≤ limit`` (NaN gives False); the
    twin of :func:`check_nonnegative` with :func:`check_magnitude`."""
    return jnp.all(finite_within(x, limit) & (x >= 0))


def all_positive(x: Any, limit: float = MAX_MAGNITUDE) -> jax.Array:
    """``bool[]``, traceable: every entry of ``x`` satisfies ``0 < x ≤ limit`` (NaN gives False); the
    twin of :func:`check_positive` with :func:`check_magnitude`."""
    return jnp.all(finite_within(x, limit) & (x > 0))


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
    v = _values(name, cov)
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


def check_covariances(name: str, covs: Any, dim: int | None = None) -> None:
    """``covs [..., dim, dim]``: each a symmetric positive-definite matrix (:func:`check_covariance`),
    the first bad one named by its index (values skipped for tracers)."""
    shape = np.shape(covs)
    if len(shape) < 2 or shape[-1] != shape[-2] or (dim is not None and shape[-1] != dim):
        want = f"(..., {dim}, {dim})" if dim is not None else "(..., n, n)"
        raise ValueError(f"{name} must have shape {want}, got {tuple(shape)}")
    v = _values(name, covs)
    if v is None:
        return
    for i in np.ndindex(shape[:-2]):
        check_covariance(f"{name}[{', '.join(map(str, i))}]" if i else name, v[i], dim)


def check_bounds(name: str, bounds: Any) -> tuple[float, float, float, float]:
    """``bounds = (x_min, x_max, y_min, y_max)`` (m): four finite numbers of at most
    :data:`MAX_MAGNITUDE`, with ``x_min < x_max`` and ``y_min < y_max``. Returns them as floats."""
    v = np.asarray(as_array(name, bounds), dtype=np.float64)
    if v.shape != (4,):
        raise ValueError(f"{name} must be four numbers (x_min, x_max, y_min, y_max), got shape {v.shape}")
    check_magnitude(name, v)
    x0, x1, y0, y1 = (float(b) for b in v)
    if not (x1 > x0 and y1 > y0):
        raise ValueError(f"{name} must satisfy x_min < x_max and y_min < y_max, got {tuple(v.tolist())}")
    return x0, x1, y0, y1


def as_array(name: str, x: Any) -> Any:
    """``x`` itself if it is an array (JAX, NumPy or a tracer), else ``np.asarray(x)``: a Python
    list or tuple of numbers is accepted wherever an array is. Anything NumPy cannot read as
    numbers, and complex numbers, raise ``ValueError`` naming ``name``."""
    if isinstance(x, (jax.Array, np.ndarray, np.generic)):
        check_real(name, x)
        return x
    try:
        a = np.asarray(x)
    except (TypeError, ValueError):
        a = None
    if a is not None and a.dtype.kind == "c":
        raise ValueError(f"{name} must hold real numbers, got complex values (dtype {a.dtype.name})")
    if a is None or a.dtype.kind not in "biuf":
        raise ValueError(f"{name} must be an array of numbers, got {type(x).__name__}: {x!r:.80}")
    return a


def float_array(name: str, x: Any, dtype: Any = None) -> jax.Array:
    """``x`` (an array, list or tuple of numbers) as a JAX floating-point array.

    ``dtype`` fixes the precision; without it a floating input keeps its own (float32 or
    float64), integers become the default float, and float16/bfloat16 are promoted to float32
    (the filters' arithmetic — log-weights, squared distances — is not meaningful in half
    precision). Raises ``ValueError`` naming ``name`` for anything else.
    """
    a = as_array(name, x)
    if dtype is None:
        if not jnp.issubdtype(a.dtype, jnp.floating):
            dtype = jax.dtypes.canonicalize_dtype(float)
        else:
            dtype = jax.dtypes.canonicalize_dtype(a.dtype if jnp.finfo(a.dtype).bits >= 32 else np.float32)
    return jnp.asarray(a, dtype)


def check_slots(
    name: str, ids: Any, mask: Any, values: Any = None, ids_field: str = "ids", num_ids: int | None = None
) -> None:
    """Fixed observation slots: integer ``ids``, a boolean (or integer 0/1) ``mask``,
    and, where ``mask`` is set, finite ``values [..., D]`` (the latter skipped for tracers). With
    ``num_ids`` only the slots whose id is in ``[0, num_ids)`` must be finite: the filters drop and
    count the others without reading them.

    A float mask or float ids are refused (``0.5`` is neither valid nor invalid), and so is an
    integer mask holding anything but 0 and 1 (a 0/2 mask is more likely a bug than a choice;
    inside a caller's ``jit`` the filters read nonzero as set); a NaN or an
    infinity in a valid slot is refused with the first place it occurs, since a filter would
    carry it into every later estimate: mask such a slot out instead.
    """
    if values is not None:
        check_real(f"{name}.z", values)
    for field, x in ((ids_field, ids), ("mask", mask)):
        dtype = np.result_type(getattr(x, "dtype", None) or np.asarray(x).dtype)
        allowed = "biu" if field == "mask" else "iu"
        if dtype.kind not in allowed:
            what = "a boolean array (or integers 0 and 1)" if field == "mask" else "an integer array"
            raise ValueError(f"{name}.{field} must be {what}, got dtype {dtype}")
    mask_dtype = np.result_type(getattr(mask, "dtype", None) or np.asarray(mask).dtype)
    if mask_dtype.kind in "iu" and is_concrete(mask):
        m = np.asarray(mask)
        odd = (m != 0) & (m != 1)
        if odd.any():
            where = first_index(odd)
            raise ValueError(
                f"{name}.mask must be boolean or integers 0 and 1, got {int(m[where])} at index {where} "
                f"({int(odd.sum())} such value(s))"
            )
    if values is None or not is_concrete((mask, values)):
        return
    v = np.asarray(values)
    if _all_within(v, MAX_MAGNITUDE):
        return  # the common case, in one pass: every value usable, valid slot or not (NaN and ±inf compare False)
    lead = v.shape[: np.ndim(mask)]
    valid = np.broadcast_to(np.asarray(mask).astype(bool), lead)
    if num_ids is not None:
        i = np.asarray(ids)
        valid = valid & (i >= 0) & (i < num_ids)
    # Not reshape(..., -1): that fails on zero slots or zero steps, where there is nothing to check.
    rows = v.reshape(lead + (math.prod(v.shape[len(lead) :]),))
    bad = valid & ~np.all(np.isfinite(rows), axis=-1)
    if bad.any():
        where = first_index(bad)
        raise ValueError(
            f"{name}.z holds NaN or infinite values in {int(bad.sum())} valid slot(s), the first at index "
            f"{where}: mask such slots out ({name}.mask False) instead of passing them"
        )
    huge = valid & np.any(np.abs(rows) > MAX_MAGNITUDE, axis=-1)
    if huge.any():
        where = first_index(huge)
        raise ValueError(
            f"{name}.z holds values larger than {MAX_MAGNITUDE:g} in magnitude in {int(huge.sum())} valid "
            f"slot(s), the first at index {where}: values are in SI units (m, rad)"
        )
