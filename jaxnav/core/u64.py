"""Unsigned 64-bit integers as pairs of ``uint32`` words, for exact resampling arithmetic.

**Why this module exists**

JAX computes in float32 and int32 unless ``jax_enable_x64`` is set, and then has
no 64-bit integer at all. Resampling needs more than that: at a million particles
a particle's weight is about 1e-6 of the total, while float32 moves in steps of
6e-8 near the top of a cumulative sum, so a float32 CDF cannot tell neighbouring
particles apart (:mod:`jaxnav.core.integer_cdf` explains the consequences). Integer
sums are exact and associative, so a CDF held as 64-bit integers is the same
however it is summed (blocked, on one device or several), and a particle of zero
weight adds exactly nothing to it.

A :class:`U64` holds the words ``hi`` and ``lo`` (both ``uint32``, same shape) of
``v = hi·2³² + lo``. Every operation is exact modulo 2⁶⁴ and written with 32-bit
integer arithmetic only (products through 16-bit halves), so it runs the same on
every backend and under ``jax_enable_x64`` or not. Functions that take a Python
``int`` take it as a static constant.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from jaxnav.core import fastmath

__all__ = [
    "U64",
    "constant",
    "add",
    "sub",
    "add_u32",
    "less",
    "less_equal",
    "where",
    "take",
    "mul32",
    "mul_u32",
    "mul_high",
    "mul_low",
    "cumsum",
    "to_float",
    "from_float",
    "divmod_u32",
]

_U32 = jnp.uint32
_LOW16 = 0xFFFF


class U64(NamedTuple):
    """``hi·2³² + lo`` with ``hi``, ``lo`` ``uint32`` arrays of one shape."""

    hi: jax.Array
    lo: jax.Array


def constant(value: int, shape: tuple[int, ...] = ()) -> U64:
    """The Python integer ``value`` (``0 ≤ value < 2⁶⁴``) as a :class:`U64` of ``shape``."""
    if not 0 <= value < 2**64:
        raise ValueError(f"a U64 holds integers in [0, 2**64), got {value}")
    return U64(jnp.full(shape, value >> 32, _U32), jnp.full(shape, value & 0xFFFFFFFF, _U32))


def add(a: U64, b: U64) -> U64:
    """``a + b`` mod 2⁶⁴."""
    lo = a.lo + b.lo
    return U64(a.hi + b.hi + (lo < a.lo).astype(_U32), lo)


def add_u32(a: U64, x: jax.Array) -> U64:
    """``a + x`` mod 2⁶⁴ for a ``uint32`` ``x``."""
    lo = a.lo + x
    return U64(a.hi + (lo < a.lo).astype(_U32), lo)


def sub(a: U64, b: U64) -> U64:
    """``a − b`` mod 2⁶⁴."""
    return U64(a.hi - b.hi - (a.lo < b.lo).astype(_U32), a.lo - b.lo)


def less(a: U64, b: U64) -> jax.Array:
    """``a < b`` (unsigned)."""
    return (a.hi < b.hi) | ((a.hi == b.hi) & (a.lo < b.lo))


def less_equal(a: U64, b: U64) -> jax.Array:
    """``a ≤ b`` (unsigned)."""
    return (a.hi < b.hi) | ((a.hi == b.hi) & (a.lo <= b.lo))


def where(cond: jax.Array, a: U64, b: U64) -> U64:
    """Elementwise ``a if cond else b``."""
    return U64(jnp.where(cond, a.hi, b.hi), jnp.where(cond, a.lo, b.lo))


def take(a: U64, index: jax.Array) -> U64:
    """``a[index]`` along the leading axis (``index`` in range)."""
    return U64(jnp.take(a.hi, index, axis=0, mode="clip"), jnp.take(a.lo, index, axis=0, mode="clip"))


def mul32(x: jax.Array, y: jax.Array) -> U64:
    """The full 64-bit product of two ``uint32`` arrays (schoolbook on 16-bit halves)."""
    x, y = jnp.asarray(x).astype(_U32), jnp.asarray(y).astype(_U32)
    x1, x0 = x >> 16, x & _LOW16
    y1, y0 = y >> 16, y & _LOW16
    p00, p01, p10, p11 = x0 * y0, x0 * y1, x1 * y0, x1 * y1  # each < 2³²
    mid = p01 + p10
    mid_carry = (mid < p01).astype(_U32)  # mid wrapped: 2³² · 2¹⁶ goes to the high word
    lo = p00 + (mid << 16)
    lo_carry = (lo < p00).astype(_U32)
    hi = p11 + (mid >> 16) + (mid_carry << 16) + lo_carry
    return U64(hi, lo)


def mul_u32(a: U64, x: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The 96-bit product ``a·x`` of a :class:`U64` and a ``uint32``, as words ``(w2, w1, w0)``."""
    low = mul32(a.lo, x)
    high = mul32(a.hi, x)
    w1 = low.hi + high.lo
    w2 = high.hi + (w1 < low.hi).astype(_U32)
    return w2, w1, low.lo


def mul_high(a: U64, x: jax.Array) -> U64:
    """``⌊a·x / 2³²⌋`` for a :class:`U64` ``a`` and a ``uint32`` ``x`` (exact; the result fits 64 bits)."""
    w2, w1, _ = mul_u32(a, x)
    return U64(w2, w1)


def mul_low(a: U64, x: jax.Array) -> U64:
    """``a·x mod 2⁶⁴`` for a :class:`U64` ``a`` and a ``uint32`` ``x``."""
    low = mul32(a.lo, x)
    return U64(low.hi + a.hi * jnp.asarray(x).astype(_U32), low.lo)


def cumsum(a: U64) -> U64:
    """Inclusive cumulative sum along the leading axis, exact modulo 2⁶⁴.

    The low words are summed modulo 2³². Adding ``lo_i < 2³²`` wraps the running low
    word exactly when the new running word is below ``lo_i``, and those carries join
    the high words in a second sum. Both sums are :func:`jaxnav.core.fastmath.int_cumsum`.
    """
    lo = fastmath.int_cumsum(a.lo)
    carry = (lo < a.lo).astype(_U32)
    return U64(fastmath.int_cumsum(a.hi + carry), lo)


def to_float(a: U64, dtype: Any = jnp.float32) -> jax.Array:
    """``hi·2³² + lo`` rounded to ``dtype`` (an estimate: two roundings)."""
    return a.hi.astype(dtype) * jnp.asarray(2.0**32, dtype) + a.lo.astype(dtype)


def from_float(x: jax.Array) -> U64:
    """``⌊x⌋`` for a float array with ``0 ≤ x < 2⁶⁴``, exactly (float32 or float64).

    ``⌊x / 2³²⌋`` is exact (scaling by a power of two, then the integer part of a
    float); so is ``x − hi·2³²`` (both share ``x``'s exponent grid), whose floor is the
    low word. Values outside ``[0, 2⁶⁴)`` and NaN give 0.
    """
    x = jnp.where((x >= 0) & (x < 2.0**64), x, 0)
    hi = jnp.floor(x * (2.0**-32))
    lo = jnp.floor(x - hi * 2.0**32)
    return U64(hi.astype(_U32), lo.astype(_U32))


def divmod_u32(a: U64, d: jax.Array) -> tuple[U64, jax.Array]:
    """``(a // d, a % d)`` for a :class:`U64` ``a`` and a ``uint32`` divisor ``1 ≤ d < 2³⁰``, exactly.

    The high word is divided by the hardware; the rest, ``r·2³² + lo`` with
    ``r < d``, has a quotient below 2³², found by ``_divmod_small_quotient``
    without any 64-bit division.
    """
    d = jnp.asarray(d).astype(_U32)
    q_hi = a.hi // d
    r = a.hi - q_hi * d
    q_lo, rem = _divmod_small_quotient(U64(r, a.lo), d)
    return U64(q_hi, q_lo), rem


_SHRINK = 1.0 - 2.0**-20  # makes a float32 quotient estimate a lower bound (its relative error is < 2⁻²¹)


def _quotient_lower_bound(n: U64, d: jax.Array) -> jax.Array:
    """A ``uint32`` ``q ≤ ⌊n/d⌋`` within ``2⁻¹⁹·n/d + 2`` of it (float32 estimate, shrunk, minus one)."""
    est = jnp.floor(to_float(n, jnp.float32) * _SHRINK / d.astype(jnp.float32)) - 1.0
    return jnp.clip(est, 0.0, 2.0**32 - 1).astype(_U32)


def _divmod_small_quotient(n: U64, d: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(n // d, n % d)`` as ``uint32`` when ``n < d·2³²`` and ``1 ≤ d < 2³⁰``.

    A float32 estimate that never exceeds the quotient leaves an exact remainder
    ``n − q·d ≥ 0`` below ``2¹³·d``; a second such estimate on the remainder leaves
    less than ``3d``, and two comparisons finish the division.
    """
    q = _quotient_lower_bound(n, d)
    r = sub(n, mul32(q, d))
    step = _quotient_lower_bound(r, d)
    q = q + step
    r = sub(r, mul32(step, d)).lo  # < 3d < 2³²
    for _ in range(2):
        over = r >= d
        q = jnp.where(over, q + 1, q)
        r = jnp.where(over, r - d, r)
    return q, r
