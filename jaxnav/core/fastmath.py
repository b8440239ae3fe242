"""Vectorisable float32 ``sin``, ``cos`` and ``atan2`` for the particle hot paths.

Why this module exists
----------------------
XLA:CPU lowers ``sin``/``cos``/``atan2`` to scalar routines that do not
vectorise: on the 2-core Xeon this project is benchmarked on, ``jnp.arctan2``
over 8·10⁶ float32 values took 280 ms against NumPy's 10 ms, and ``jnp.sin``
70 ms against 8.6 ms, while ``exp``/``log``/``sqrt`` ran at NumPy's speed
(``benchmarks/profile_w2.py``; the MCL step evaluates 8 bearings per particle).
The functions below are the Cephes single-precision algorithms (S. L.
Moshier, *Methods and Programs for Mathematical Functions*, 1989) written
with ``jnp`` arithmetic, which XLA fuses into one vectorised loop.

Accuracy and range (float32): ``sincos`` and ``atan2`` are within a few ulp
of the correctly rounded value (tests compare against NumPy in float64);
``sincos`` is accurate for ``|x| ≤ 8192`` rad (Cody–Waite reduction), far
beyond any heading or bearing. float64 inputs fall back to ``jnp`` so that x64
runs keep full precision. Derivatives are defined analytically
(``custom_jvp``): ``d sin = cos``, ``d atan2(y, x) = (x dy − y dx)/(x² + y²)``.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

__all__ = ["sincos", "sin", "cos", "atan2", "cumsum", "count_cumsum", "matmul", "small_sum"]

# Cody–Waite split of π/2: PIO2_1 has 8 significant bits, so k·PIO2_1 is exact for |k| < 2^16.
_PIO2_1 = 1.5703125
_PIO2_2 = 4.837512969970703125e-4
_PIO2_3 = 7.54978995489188216e-8
_TWO_OVER_PI = 2.0 / math.pi


def _is_f32(x: jax.Array) -> bool:
    return jnp.result_type(x) != jnp.float64


def _sincos_f32(x: jax.Array) -> tuple[jax.Array, jax.Array]:
    k = jnp.round(x * _TWO_OVER_PI)
    r = ((x - k * _PIO2_1) - k * _PIO2_2) - k * _PIO2_3  # |r| ≤ π/4
    z = r * r
    # Cephes sinf / cosf minimax polynomials on [-π/4, π/4].
    s = ((-1.9515295891e-4 * z + 8.3321608736e-3) * z - 1.6666654611e-1) * z * r + r
    c = ((2.443315711809948e-5 * z - 1.388731625493765e-3) * z + 4.166664568298827e-2) * z * z - 0.5 * z + 1.0
    q = k.astype(jnp.int32) & 3
    sin_x = jnp.where(q == 0, s, jnp.where(q == 1, c, jnp.where(q == 2, -s, -c)))
    cos_x = jnp.where(q == 0, c, jnp.where(q == 1, -s, jnp.where(q == 2, -c, s)))
    return sin_x, cos_x


@jax.custom_jvp
def sincos(x: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(sin x, cos x)`` sharing one range reduction (x in rad, ``|x| ≤ 8192`` for float32)."""
    if not _is_f32(x):
        return jnp.sin(x), jnp.cos(x)
    return _sincos_f32(x)


@sincos.defjvp
def _sincos_jvp(primals, tangents):
    (x,), (dx,) = primals, tangents
    s, c = sincos(x)
    return (s, c), (c * dx, -s * dx)


def sin(x: jax.Array) -> jax.Array:
    """``sin x`` (rad); see :func:`sincos`."""
    return sincos(x)[0]


def cos(x: jax.Array) -> jax.Array:
    """``cos x`` (rad); see :func:`sincos`."""
    return sincos(x)[1]


_TAN_PI_8 = 0.4142135623730950
_PI = math.pi


def _atan2_f32(y: jax.Array, x: jax.Array) -> jax.Array:
    ax, ay = jnp.abs(x), jnp.abs(y)
    swap = ay > ax
    num = jnp.where(swap, ax, ay)
    den = jnp.where(swap, ay, ax)
    t = num / jnp.where(den == 0, 1.0, den)  # t in [0, 1]; atan2(0, 0) = 0
    big = t > _TAN_PI_8
    t = jnp.where(big, (t - 1.0) / (t + 1.0), t)  # |t| ≤ tan(π/8)
    z = t * t
    # Cephes atanf polynomial.
    p = (((8.05374449538e-2 * z - 1.38776856032e-1) * z + 1.99777106478e-1) * z - 3.33329491539e-1) * z * t + t
    a = jnp.where(big, 0.25 * _PI + p, p)
    a = jnp.where(swap, 0.5 * _PI - a, a)
    a = jnp.where(x < 0, _PI - a, a)
    return jnp.where(y < 0, -a, a)


@jax.custom_jvp
def atan2(y: jax.Array, x: jax.Array) -> jax.Array:
    """``atan2(y, x)`` in ``[-π, π]`` (rad) for finite inputs; ``atan2(0, 0) = 0``."""
    y, x = jnp.broadcast_arrays(y, x)
    if not (_is_f32(x) and _is_f32(y)):
        return jnp.arctan2(y, x)
    return _atan2_f32(y, x)


@atan2.defjvp
def _atan2_jvp(primals, tangents):
    (y, x), (dy, dx) = primals, tangents
    out = atan2(y, x)
    r2 = x * x + y * y
    safe = jnp.where(r2 == 0, 1.0, r2)
    return out, jnp.where(r2 == 0, 0.0, (x * dy - y * dx) / safe)


def cumsum(x: jax.Array, block: int = 16) -> jax.Array:
    """Inclusive cumulative sum of a 1-D array, blocked for XLA:CPU, monotone for x ≥ 0.

    ``jnp.cumsum`` lowers to an associative scan on CPU (about log₂N passes
    over the data: 11.7 ms for 10⁶ float32 here, NumPy 3.5 ms). Here each
    block of ``block`` elements is summed left to right (vectorised across
    blocks), the block totals are summed the same way recursively, and each
    block's offset is added. Every partial sum inside a block is the previous
    one plus a non-negative term, and each block is clamped below by the
    running maximum of the previous blocks' ends, so for non-negative input
    the result never decreases — inverse-CDF resampling relies on that, and
    an associative scan does not guarantee it. Integer arrays use ``jnp.cumsum``.
    """
    if not jnp.issubdtype(x.dtype, jnp.floating):
        return jnp.cumsum(x)
    if x.shape[0] <= block:
        return _sequential_columns(x[None, :])[0]
    out = _blocked(x, block)
    ends = jax.lax.cummax(out[:, -1])
    floor = jnp.concatenate([jnp.full((1,), -jnp.inf, x.dtype), ends[:-1]])
    return jnp.maximum(out, floor[:, None]).reshape(-1)[: x.shape[0]]


def _blocked(x: jax.Array, block: int) -> jax.Array:
    """``[ceil(n/block), block]`` cumulative sums (not clamped at block joins)."""
    n = x.shape[0]
    rows = jnp.pad(x, (0, (-n) % block)).reshape(-1, block)
    within = _sequential_columns(rows)
    if within.shape[0] == 1:
        return within
    ends = _blocked(within[:, -1], block).reshape(-1)[: within.shape[0]]
    offsets = jnp.concatenate([jnp.zeros((1,), x.dtype), ends[:-1]])
    return within + offsets[:, None]


def count_cumsum(counts: jax.Array, block: int = 16) -> jax.Array:
    """Exact inclusive cumulative sum of non-negative integer counts ``[M]`` (int32 out).

    Integer-valued float32 sums below 2²⁴ are exact in any order, so blocks
    are summed by a triangular matrix product (the fastest form on XLA:CPU,
    4.4 ms for 10⁶ here against 11.7 ms for ``jnp.cumsum``); larger totals use
    ``jnp.cumsum`` on int32.
    """
    m = counts.shape[0]
    if m >= 2**24 or m <= block:
        return jnp.cumsum(counts.astype(jnp.int32))
    x = counts.astype(jnp.float32)
    rows = jnp.pad(x, (0, (-m) % block)).reshape(-1, block)
    upper = jnp.triu(jnp.ones((block, block), jnp.float32))
    within = jnp.matmul(rows, upper, precision=jax.lax.Precision.HIGHEST)
    ends = count_cumsum(within[:, -1], block).astype(jnp.float32)
    offsets = jnp.concatenate([jnp.zeros((1,), jnp.float32), ends[:-1]])
    return (within + offsets[:, None]).reshape(-1)[:m].astype(jnp.int32)


def _sequential_columns(rows: jax.Array) -> jax.Array:
    """Cumulative sum along axis 1 (short), left to right, vectorised over rows."""
    acc = rows[:, 0]
    cols = [acc]
    for j in range(1, rows.shape[1]):
        acc = acc + rows[:, j]
        cols.append(acc)
    return jnp.stack(cols, axis=1)


SMALL_CONTRACTION = 4
"""Largest contraction :func:`matmul` and :func:`small_sum` write out as multiply-adds."""


def matmul(a: jax.Array, b: jax.Array) -> jax.Array:
    """``a @ b`` for ``a [n, k]`` or ``[k]`` and ``b [k, m]`` or ``[k]``, written out as
    ``Σ_i a[:, i] ⊗ b[i]`` when ``k ≤`` :data:`SMALL_CONTRACTION`.

    Under ``vmap`` a tiny matrix product becomes a batched ``dot_general`` that XLA:CPU
    hands to YNNPACK or its thread pool per batch element (about a microsecond each,
    benchmark W4; the 2 × 2 products of FastSLAM's landmark EKFs cost more than its map
    copy). Multiply-adds fuse with their neighbours into one vectorised loop. Larger
    contractions, and operands of more than two dimensions, use ``@``.
    """
    k = a.shape[-1]
    if k > SMALL_CONTRACTION or a.ndim > 2 or b.ndim > 2 or b.shape[0] != k:
        return a @ b

    def term(i: int) -> jax.Array:
        ai, bi = a[..., i], b[i]
        return ai[:, None] * bi[None, :] if a.ndim == 2 and b.ndim == 2 else ai * bi

    out = term(0)
    for i in range(1, k):
        out = out + term(i)
    return out


def small_sum(x: jax.Array) -> jax.Array:
    """Sum of a vector ``x [k]``, written out as additions when ``k ≤`` :data:`SMALL_CONTRACTION`
    (a tiny reduction under ``vmap`` is a slow YNNPACK call on XLA:CPU; see :func:`matmul`)."""
    if x.ndim != 1 or x.shape[0] > SMALL_CONTRACTION:
        return jnp.sum(x)
    out = x[0]
    for i in range(1, x.shape[0]):
        out = out + x[i]
    return out
