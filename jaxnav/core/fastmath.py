"""Vectorisable float32 ``sin``, ``cos`` and ``atan2``, and an exact integer cumulative sum, for the hot paths.

**Why this module exists**

XLA:CPU lowers ``sin``/``cos``/``atan2`` to scalar routines that do not
vectorise: ``jnp.arctan2`` and ``jnp.sin`` over large float32 arrays run many
times slower than NumPy's vectorised versions, while ``exp``/``log``/``sqrt`` run
at NumPy's speed (``benchmarks/profile_w2.py`` measures this; the MCL step
evaluates 8 bearings per particle).
The functions below are the Cephes single-precision algorithms (S. L.
Moshier, *Methods and Programs for Mathematical Functions*, 1989) written
with ``jnp`` arithmetic, which XLA fuses into one vectorised loop.

Accuracy and range (float32): ``sincos`` and ``atan2`` are within a few ulp
of the correctly rounded value (tests compare against NumPy in float64);
``sincos`` is accurate for ``|x| ≤ 8192`` rad (Cody–Waite reduction), far
beyond any heading or bearing. float64 inputs fall back to ``jnp`` so that x64
runs keep full precision. Derivatives are defined analytically
(``custom_jvp``): ``d sin = cos``, ``d atan2(y, x) = (x dy − y dx)/(x² + y²)``.

**Checking that a fast path still pays**

These functions, and the random draws of :mod:`jaxnav.core.rng`, exist because of how
XLA:CPU compiles the plain forms today. :func:`use_plain_forms` switches every one of them
back to its plain JAX form, and the benchmarks' ``jaxnav-plain`` rows time the MCL step
that way beside the ``jaxnav`` rows: on a machine or JAX version where the plain form wins,
those rows show it.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

__all__ = [
    "sincos",
    "sin",
    "cos",
    "atan2",
    "int_cumsum",
    "INT_SCAN_BLOCK",
    "INT_SCAN_DIRECT",
    "matmul",
    "small_sum",
    "blocked_int_cumsum",
    "use_plain_forms",
]

_plain = {"on": False}


def use_plain_forms(on: bool | None = None) -> bool:
    """Whether the CPU fast paths give way to their plain JAX forms; ``on`` sets it.

    The fast paths are this module's ``sincos``, ``atan2`` and ``int_cumsum`` and the draws of
    :mod:`jaxnav.core.rng`; their plain forms are ``jnp.sin``/``jnp.cos``, ``jnp.arctan2``,
    ``jnp.cumsum`` and ``jax.random``. The switch exists to measure what each fast path buys
    on a given machine (the benchmarks' ``jaxnav-plain`` rows). It is read when a function is
    traced: call ``jax.clear_caches()`` after changing it so that compiled filters are traced
    again. Results agree to rounding (the draws are identical).
    """
    if on is not None:
        _plain["on"] = bool(on)
    return _plain["on"]


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
    if not _is_f32(x) or _plain["on"]:
        return jnp.sin(x), jnp.cos(x)
    return _sincos_f32(x)


@sincos.defjvp
def _sincos_jvp(primals, tangents):
    (x,), (dx,) = primals, tangents
    s, c = sincos(x)
    return (s, c), (c * dx, -s * dx)


def sin(x: jax.Array) -> jax.Array:
    """``sin x`` (rad); see ``sincos``."""
    return sincos(x)[0]


def cos(x: jax.Array) -> jax.Array:
    """``cos x`` (rad); see ``sincos``."""
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
    if not (_is_f32(x) and _is_f32(y)) or _plain["on"]:
        return jnp.arctan2(y, x)
    return _atan2_f32(y, x)


@atan2.defjvp
def _atan2_jvp(primals, tangents):
    (y, x), (dy, dx) = primals, tangents
    out = atan2(y, x)
    r2 = x * x + y * y
    safe = jnp.where(r2 == 0, 1.0, r2)
    return out, jnp.where(r2 == 0, 0.0, (x * dy - y * dx) / safe)


INT_SCAN_BLOCK = 8
"""Block length of :func:`~jaxnav.core.fastmath.int_cumsum` on the CPU (8 and 16 perform alike; 8 compiles smaller)."""


INT_SCAN_DIRECT = 256
"""Up to this length :func:`~jaxnav.core.fastmath.int_cumsum` and its blocked levels use ``jnp.cumsum``,
one kernel, which XLA:CPU fuses into its consumer. Inside a ``lax.scan`` it is the faster form for
short arrays and the blocked form for long ones: ``jnp.cumsum``'s passes grow as N log N, the
blocked form's as N, and they cross near this length."""


def int_cumsum(x: jax.Array, single_reader: bool = False) -> jax.Array:
    """Inclusive cumulative sum of a 1-D 32-bit integer array, wrapping like the integer type.

    Integer sums are exact in any order (modulo 2³² for ``uint32``/``int32``), so the
    result is the same on every backend. ``jnp.cumsum`` lowers to an associative scan,
    which XLA:CPU runs as about log₂N strided passes, several times slower than NumPy.
    On the CPU the array is cut into rows of :data:`~jaxnav.core.fastmath.INT_SCAN_BLOCK`;
    the row totals are summed (a reduction) and their exclusive cumulative sum computed
    recursively; one integer product of each row, its offset prepended, with an
    upper-triangular matrix of ones gives the result, in a single pass over the data.
    Other backends use ``jnp.cumsum``.

    ``single_reader=True`` (CPU): the last level is the rows' product plus their offsets,
    an addition that XLA fuses into the consumer instead of a pass that writes the
    augmented rows; right when one fused computation reads the result once (with several
    readers, each would repeat the addition's index arithmetic).
    """
    if x.ndim != 1 or not jnp.issubdtype(x.dtype, jnp.integer) or jnp.dtype(x.dtype).itemsize != 4:
        raise TypeError(f"int_cumsum takes a 1-D int32 or uint32 array, got {x.dtype}{list(x.shape)}")
    if x.shape[0] <= INT_SCAN_DIRECT or _plain["on"]:
        return jnp.cumsum(x, dtype=x.dtype)
    cpu = _blocked_int_cumsum_added if single_reader else blocked_int_cumsum
    return jax.lax.platform_dependent(x, cpu=cpu, default=lambda v: jnp.cumsum(v, dtype=v.dtype))


def _rows_and_offsets(x: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``x`` as rows of :data:`INT_SCAN_BLOCK` and each row's exclusive offset (the sums of the rows before)."""
    rows = jnp.pad(x, (0, (-x.shape[0]) % INT_SCAN_BLOCK)).reshape(-1, INT_SCAN_BLOCK)
    totals = jnp.sum(rows, axis=1, dtype=x.dtype)
    return rows, blocked_int_cumsum(totals) - totals


def _blocked_int_cumsum_added(x: jax.Array) -> jax.Array:
    n = x.shape[0]
    if n <= INT_SCAN_DIRECT:
        return jnp.cumsum(x, dtype=x.dtype)
    rows, offsets = _rows_and_offsets(x)
    upper = jnp.triu(jnp.ones((INT_SCAN_BLOCK, INT_SCAN_BLOCK), x.dtype))
    return (jnp.dot(rows, upper, preferred_element_type=x.dtype) + offsets[:, None]).reshape(-1)[:n]


def blocked_int_cumsum(x: jax.Array) -> jax.Array:
    """The XLA:CPU path of :func:`int_cumsum`: rows of :data:`INT_SCAN_BLOCK` summed by one integer product each."""
    n, block = x.shape[0], INT_SCAN_BLOCK
    if n <= INT_SCAN_DIRECT:
        return jnp.cumsum(x, dtype=x.dtype)
    rows, offsets = _rows_and_offsets(x)
    # [offset, x_0, …, x_{B−1}] · [[1 … 1], triu(1)]: each row's running sums plus its offset, as one
    # integer product, whose output XLA keeps (an addition of the offsets would be fused into every
    # consumer of the result, and the recursion recomputed by each).
    upper = jnp.concatenate([jnp.ones((1, block), x.dtype), jnp.triu(jnp.ones((block, block), x.dtype))])
    augmented = jnp.concatenate([offsets[:, None], rows], axis=1)
    return jnp.dot(augmented, upper, preferred_element_type=x.dtype).reshape(-1)[:n]


SMALL_CONTRACTION = 4
"""Largest contraction :func:`matmul` and :func:`small_sum` write out as multiply-adds."""


def matmul(a: jax.Array, b: jax.Array) -> jax.Array:
    """``a @ b`` for ``a [n, k]`` or ``[k]`` and ``b [k, m]`` or ``[k]``, written out as
    ``Σ_i a[:, i] ⊗ b[i]`` when ``k ≤ SMALL_CONTRACTION`` (4).

    Under ``vmap`` a tiny matrix product becomes a batched ``dot_general`` that XLA:CPU
    hands to YNNPACK or its thread pool per batch element (a fixed overhead for each,
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
    """Sum of a vector ``x [k]``, written out as additions when ``k ≤ SMALL_CONTRACTION``
    (a tiny reduction under ``vmap`` is a slow YNNPACK call on XLA:CPU; see :func:`~jaxnav.core.fastmath.matmul`)."""
    if x.ndim != 1 or x.shape[0] > SMALL_CONTRACTION:
        return jnp.sum(x)
    out = x[0]
    for i in range(1, x.shape[0]):
        out = out + x[i]
    return out
