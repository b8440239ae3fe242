"""The exact integer CDF of a weight vector: integer weights, strata without division, inverse CDF.

A float32 cumulative sum cannot resample large sets: near its top it moves in
steps of 6·10⁻⁸ while a particle's weight at N = 10⁶ is 10⁻⁶, so tens of
thousands of particles of positive weight can never be drawn, others are drawn
up to several times too often, and a blocked sum can even give a particle of
zero weight a sliver of the CDF. The resampling schemes of
:mod:`jaxnav.core.resampling` are exact, built on the pieces of this module:

1. **Integer weights.** The weights are scaled by a power of two (exact) so that
   their total lies in ``[2⁶⁰, 2⁶¹)`` and truncated to integers ``q_i``, held in
   64 bits (:mod:`jaxnav.core.u64`). A float32 weight above ``2⁻³⁷`` of the total
   (float64: ``2⁻⁸``) is represented exactly; a smaller one loses less than
   ``2⁻⁵⁹`` of the total. A weight of zero (log-weight ``-inf``, or NaN, treated
   as ``-inf``) is ``q_i = 0``. Subnormal weights (below ``2⁻¹²⁶`` in float32),
   which XLA:CPU flushes to zero in arithmetic, are read from their bits
   (:func:`integer_cdf`): weights that are all subnormal are resampled by their
   exact relative sizes.
2. **An exact CDF.** ``S_i = Σ_{j≤i} q_j`` is an integer sum, the same in any
   order (on one device or many); ``Q = S_{N−1}``.
3. **Exact decisions.** A point ``x ∈ [0, 1)`` has ancestor ``min{i : x·Q < S_i}``.
   The schemes' points are ``(s + f)/M`` (``s`` a stratum, ``f = F/2³²`` a 32-bit
   uniform fraction), and ``(s + f)·Q < S_i·M`` is decided without division:
   ``k_i = ⌊S_i·M/Q⌋`` and ``r_i = S_i·M − k_i·Q`` come from a precomputed
   reciprocal and one correction (:func:`stratum_and_remainder`), and the point of
   stratum ``k_i`` lies below ``S_i`` exactly when ``⌊F·Q/2³²⌋ < r_i``.

So a resampling is an exact function of its uniforms: a particle with ``q_i = 0``
has ``S_i = S_{i−1}`` and is never drawn, every ancestor is in ``[0, N)``, with
equal weights and ``M = N`` systematic and stratified copy every particle exactly
once at any N, and the expected number of offspring is ``M·q_i/Q``. The only
departures from real arithmetic on the given weights are the truncation of
weights below ``2⁻³⁷`` of the total and the 32-bit resolution of a uniform inside
its stratum. Per particle the work is a few 32-bit multiplications (no binary
search over N); the ancestors follow from the cumulative counts by one histogram
and one integer cumulative sum (:func:`ancestors_from_counts`). Cost O(N + M);
:func:`~jaxnav.core.resampling.systematic` counts its passes over memory.

:func:`inverse_cdf` gives the same guarantees for any points in ``[0, 1)``:
``min{i : u·Q < S_i}`` with ``⌊u·Q⌋`` computed exactly from the float's mantissa.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxnav.core import fastmath, u64
from jaxnav.core.u64 import U64

__all__ = [
    "IntegerCDF",
    "integer_cdf",
    "Scale",
    "scale",
    "stratum_and_remainder",
    "ancestors_from_counts",
    "inverse_cdf",
    "MAX_SAMPLES",
    "TOTAL_BITS",
]

TOTAL_BITS = 61
"""The integer weights of a resampling are scaled so that their total lies in ``[2^(TOTAL_BITS−1), 2^TOTAL_BITS)``
(up to the 1 % accuracy of the float estimate that chooses the power of two)."""

MAX_SAMPLES = 2**29 - 1
"""The largest number of samples (and of particles) one resampling accepts."""

_I32 = jnp.int32
_U32 = jnp.uint32
_SUM_BLOCK = 1024


# --------------------------------------------------------------------------- integer weights and CDF


class IntegerCDF(NamedTuple):
    """The exact CDF of a weight vector (see the module docstring).

    Attributes:
        weights: ``[N]`` integer weights ``q_i`` (:class:`~jaxnav.core.u64.U64`).
        cdf: ``[N]`` inclusive cumulative sums ``S_i``.
        total: scalar ``Q = S_{N−1}``, in ``[0.99·2⁶⁰, 1.01·2⁶¹)``.
    """

    weights: U64
    cdf: U64
    total: U64


def _two_level_sum(x: jax.Array) -> jax.Array:
    """``Σ x`` (x ≥ 0) as row sums of 1024, then their sum: relative error below (1024 + N/1024)·2⁻²⁴
    even where XLA accumulates each level in one float32 register."""
    n = x.shape[0]
    if n <= _SUM_BLOCK:
        return jnp.sum(x)
    rows = jnp.pad(x, (0, (-n) % _SUM_BLOCK)).reshape(-1, _SUM_BLOCK)
    return jnp.sum(jnp.sum(rows, axis=1))


def _power_of_two(exponent: jax.Array, dtype) -> jax.Array:
    """``2^exponent`` as a float of ``dtype`` for a scalar integer in the normal range, built from its bits
    (exact; ``jnp.ldexp`` costs more than a pass over the weights)."""
    info = jnp.finfo(dtype)
    bits_type = jnp.int32 if info.bits == 32 else jnp.int64
    biased = jnp.clip(exponent, info.minexp, info.maxexp - 1).astype(bits_type) - info.minexp + 1
    return jax.lax.bitcast_convert_type(biased << info.nmant, dtype)


def _scaled_to_top(p: jax.Array, axis_name: str | None = None) -> jax.Array:
    """``p_i·2^(−e)`` with ``2^(e−1) ≤ max p < 2^e``, exactly, read from the bits of ``p [N]``; NaN, ``±inf``
    and negative entries (and ``−0``) give 0. (In the top binade, ``max p ≥ 2^(e_max − 1)``, ``e`` is
    one less: the largest weight is scaled into ``[1, 2)``.)

    XLA:CPU flushes subnormal floats (below ``2⁻¹²⁶`` in float32, ``2⁻¹⁰²²`` in float64) to zero
    in arithmetic and comparisons, but not in a bitcast: a subnormal ``p_i = m_i·2^(e_min − t)``
    (``t`` mantissa bits) is scaled as the integer ``m_i`` times ``2^(e_min − t − e)``, a normal
    number when the largest weight is subnormal too. Non-negative floats are ordered as their
    bits, so ``e`` is found from the largest bits: by a float maximum (vectorised on XLA:CPU,
    where an integer one is not) of the bits moved up one binade, which makes every subnormal a
    normal number in the same order. A result below the smallest normal number is 0; it is below
    ``2^(e_min − 1)`` of the largest weight, which the integer weights truncate to 0 anyway.
    """
    info = jnp.finfo(p.dtype)
    bits_type = jnp.int32 if info.bits == 32 else jnp.int64
    bits = jax.lax.bitcast_convert_type(p, bits_type)
    inf_bits = ((1 << (info.bits - 1 - info.nmant)) - 1) << info.nmant  # the bits of +inf
    bits = jnp.where((bits > 0) & (bits < inf_bits), bits, 0)
    binade = 1 << info.nmant  # one step of the exponent field
    # the top binade is clamped into the one below it (never +inf): e is then one less, still exact
    key = jax.lax.bitcast_convert_type(jnp.minimum(bits, inf_bits - 1 - binade) + binade, p.dtype)
    largest = jnp.max(key) if axis_name is None else jax.lax.pmax(jnp.max(key), axis_name)  # exact either way
    top = jax.lax.bitcast_convert_type(largest, bits_type) - binade
    biased, normal_bits = top >> info.nmant, binade
    length = info.bits - jax.lax.clz(top)  # of the mantissa, when the largest weight is subnormal
    top_exp = jnp.where(biased > 0, biased + info.minexp, length + info.minexp - info.nmant)
    sub_exp = info.minexp - info.nmant - top_exp
    sub_scale = jnp.where(sub_exp >= info.minexp, _power_of_two(sub_exp, p.dtype), 0.0)
    normal = jax.lax.bitcast_convert_type(bits, p.dtype) * _power_of_two(-top_exp, p.dtype)
    # m as a float, exactly (m < 2^t): the bits of 2^t + m, minus 2^t (an integer conversion of
    # 64-bit words is not vectorised on x86 without AVX-512, and a select computes both sides)
    magic = _power_of_two(jnp.asarray(info.nmant), p.dtype)
    mantissa = jax.lax.bitcast_convert_type(bits | jax.lax.bitcast_convert_type(magic, bits_type), p.dtype) - magic
    return jnp.where(bits >= normal_bits, normal, mantissa * sub_scale)


def _global_two_level_sum(x: jax.Array, axis_name: str) -> jax.Array:
    """:func:`_two_level_sum` of the whole vector whose blocks ``x`` are, one per device of ``axis_name``
    (inside ``jax.shard_map``), bit for bit: the same rows of 1024 summed the same way, then their sums
    gathered in order. A block that is not whole rows gathers the vector itself."""
    size = x.shape[0] * jax.lax.axis_size(axis_name)
    if size > _SUM_BLOCK and x.shape[0] % _SUM_BLOCK == 0:
        rows = jnp.sum(x.reshape(-1, _SUM_BLOCK), axis=1)
        return jnp.sum(jax.lax.all_gather(rows, axis_name, tiled=True))
    return _two_level_sum(jax.lax.all_gather(x, axis_name, tiled=True))


def _global_cdf(cdf: U64, axis_name: str) -> tuple[U64, U64]:
    """The whole vector's CDF from each device's own (``cdf``, inside ``jax.shard_map``), and its total:
    the devices' totals gathered, their exclusive prefix added to each block (integer sums: exact)."""
    last = U64(cdf.hi[-1], cdf.lo[-1])
    totals = u64.cumsum(U64(*(jax.lax.all_gather(w, axis_name) for w in last)))  # [D], inclusive
    me = jax.lax.axis_index(axis_name)
    before = u64.where(me > 0, u64.take(totals, jnp.maximum(me - 1, 0)), u64.constant(0))
    total = U64(totals.hi[-1], totals.lo[-1])
    return u64.add(
        cdf, U64(jnp.broadcast_to(before.hi, cdf.hi.shape), jnp.broadcast_to(before.lo, cdf.lo.shape))
    ), total


def integer_cdf(probabilities: jax.Array, axis_name: str | None = None) -> IntegerCDF:
    """Integer weights ``q_i = ⌊p_i·2^k⌋`` and their exact CDF, for non-negative ``probabilities [N]``.

    ``p`` need not be normalised; NaN, ``±inf`` and negative entries count as zero.
    The power of two ``2^k`` puts the total in ``[2⁶⁰, 2⁶¹)`` up to the float
    estimate of the sum (within 1 %). It is applied in two exact steps: ``2^(−e)``
    puts the largest weight in ``[0.5, 1)`` (``[1, 2)`` from ``2¹²⁷`` in float32,
    ``2¹⁰²³`` in float64), with ``e`` read from the bits of ``p`` so that
    subnormal weights (below ``2⁻¹²⁶`` in float32, ``2⁻¹⁰²²`` in float64, which
    XLA:CPU flushes to zero in arithmetic) count with their exact values: weights
    that are all subnormal keep their relative sizes and a zero among them is never
    drawn. An input with no positive entry is treated as uniform. Exact for any N
    (the sums are integer sums).

    ``axis_name`` (inside ``jax.shard_map``): ``probabilities`` is this device's block of a vector
    spread over the devices of that mesh axis, in order; the weights, CDF values and total returned
    are this block's entries of the whole vector's, bit for bit (the largest weight and the float
    total are the whole vector's, the CDF offset by the totals of the blocks before).
    """
    p = _scaled_to_top(jax.lax.stop_gradient(probabilities), axis_name)  # exact: the largest weight in [0.5, 2)
    n = p.shape[0] if axis_name is None else p.shape[0] * jax.lax.axis_size(axis_name)
    total = _two_level_sum(p) if axis_name is None else _global_two_level_sum(p, axis_name)
    empty = ~(total > 0)
    p = jnp.where(empty, 1.0, p)
    total = jnp.where(empty, jnp.asarray(n, p.dtype), total)
    _, total_exp = jnp.frexp(total)
    q = u64.from_float(p * _power_of_two(TOTAL_BITS - total_exp, p.dtype))
    cdf = u64.cumsum(q)
    if axis_name is not None:
        cdf, whole = _global_cdf(cdf, axis_name)
        return IntegerCDF(q, cdf, whole)
    return IntegerCDF(q, cdf, U64(cdf.hi[-1], cdf.lo[-1]))


# --------------------------------------------------------------------------- strata without division


class Scale(NamedTuple):
    """``M`` equal strata of ``[0, Q)``, with the reciprocal ``R = ⌊M·2⁶²/Q⌋`` that replaces division by ``Q``."""

    total: U64
    count: jax.Array  # M, uint32, may be traced
    reciprocal: jax.Array  # R, uint32 (< 2^31.1 for M ≤ MAX_SAMPLES and Q ≥ 0.99·2⁶⁰)
    size: int  # the static number of sample slots (M ≤ size)


def _u96_to_float(w2, w1, w0) -> jax.Array:
    f32 = jnp.float32
    return (w2.astype(f32) * 2.0**32 + w1.astype(f32)) * 2.0**32 + w0.astype(f32)


def scale(total: U64, count: int | jax.Array, size: int) -> Scale:
    """The :class:`Scale` of ``count`` (≤ ``size``, static) strata of ``[0, total)`` (``R`` computed exactly, once)."""
    if not 1 <= size <= MAX_SAMPLES:
        raise ValueError(f"the number of samples must be in [1, {MAX_SAMPLES}], got {size}")
    m = jnp.asarray(count).astype(_U32)
    q = u64.where((total.hi > 0) | (total.lo > 0), total, u64.constant(1))
    # M·2⁶² as three words, and a float estimate of its quotient by Q (off by at most 2¹⁰).
    n2, n1 = m >> 2, (m & 3) << 30
    est = jnp.floor(_u96_to_float(n2, n1, jnp.zeros_like(m)) / u64.to_float(q))
    r = jnp.clip(est - 2.0**10, 0, 2.0**32 - 1).astype(_U32)  # a lower bound
    # Exact remainder M·2⁶² − r·Q (< 2¹¹·Q < 2⁷³, so two words and a bit: keep three).
    p2, p1, p0 = u64.mul_u32(q, r)
    d0 = jnp.zeros_like(m) - p0
    b0 = (p0 > 0).astype(_U32)
    d1 = n1 - p1 - b0
    b1 = ((n1 < p1) | ((n1 == p1) & (b0 > 0))).astype(_U32)
    d2 = n2 - p2 - b1
    step = jnp.floor(_u96_to_float(d2, d1, d0) * (1.0 - 2.0**-20) / u64.to_float(q)).astype(_U32)
    r = r + step
    rem = u64.sub(U64(d1, d0), u64.mul_low(q, step))  # < 3Q, fits 64 bits
    for _ in range(2):
        over = ~u64.less(rem, q)
        r = jnp.where(over, r + 1, r)
        rem = u64.where(over, u64.sub(rem, q), rem)
    return Scale(q, m, r, size)


def stratum_and_remainder(sc: Scale, x: U64) -> tuple[jax.Array, U64]:
    """``k = ⌊x·M/Q⌋`` (int32) and ``r = x·M − k·Q ∈ [0, Q)`` for integers ``0 ≤ x ≤ Q``, exactly.

    ``k̃ = ⌊x·R/2⁶²⌋`` is ``k`` or ``k − 1`` (``R`` underestimates ``M·2⁶²/Q`` by less
    than one, and ``x/2⁶² < 1/2``), so ``x·M − k̃·Q`` lies in ``[0, 2Q)`` and one comparison
    finishes. The remainder is computed modulo 2⁶⁴ (it is below 2⁶³): five 32-bit
    multiplications for ``x·M``, five for ``k̃·Q``, four for ``x·R``. Every step is
    elementwise, so XLA keeps a whole resampling stage in one loop.

    A point ``(k + f)/M`` of the total, ``f ∈ [0, 1)``, lies below ``x`` exactly when
    ``f·Q < r``: the strata's points are compared through ``r``, with no division.
    """
    w2, w1, _ = u64.mul_u32(x, sc.reciprocal)
    k = (w2 << 2) | (w1 >> 30)
    r = u64.sub(u64.mul_low(x, sc.count), u64.mul_low(sc.total, k))
    over = ~u64.less(r, sc.total)
    return (k + over.astype(_U32)).astype(_I32), u64.where(over, u64.sub(r, sc.total), r)


# --------------------------------------------------------------------------- counts -> ancestors


def ancestors_from_counts(cumulative: jax.Array, num_samples: int, single_reader: bool = False) -> jax.Array:
    """Ancestors ``a_m = #{i : C_i ≤ m}`` from the cumulative offspring counts ``C [N]`` (``C_{N−1} = M``).

    Particle ``i`` has ``C_i − C_{i−1}`` offspring, placed in order; one histogram of
    ``C`` and one integer cumulative sum. Slots ``m ≥ C_{N−1}`` (when fewer samples
    are active than ``num_samples``) get ``N − 1``. ``single_reader``: see
    :func:`jaxnav.core.fastmath.int_cumsum`.
    """
    n = cumulative.shape[0]
    at = jnp.clip(cumulative, 0, num_samples)
    # Updates computed from the indices fuse with them; a constant 1 would be written out as an array.
    hist = jnp.zeros((num_samples + 1,), _I32).at[at].add((at >= 0).astype(_I32), indices_are_sorted=True)
    return jnp.minimum(fastmath.int_cumsum(hist[:num_samples], single_reader=single_reader), n - 1)


# --------------------------------------------------------------------------- binary search inside a range


def _prefix_count(lo: jax.Array, hi: jax.Array, holds) -> jax.Array:
    """``lo + #{p ∈ [lo, hi) : holds(p)}`` for a predicate that holds on a prefix of every range: a binary
    search whose trip count, ``⌈log₂(max(hi − lo) + 1)⌉``, is that of the widest range."""

    def body(_, bounds):
        lo, hi = bounds
        mid = (lo + hi) // 2
        right = (lo < hi) & holds(mid)
        return jnp.where(right, mid + 1, lo), jnp.where((lo < hi) & ~right, mid, hi)

    widest = jnp.max(hi - lo).astype(_I32)
    lo, _ = jax.lax.fori_loop(0, 32 - jax.lax.clz(widest), body, (lo, hi))
    return lo


# --------------------------------------------------------------------------- inverse CDF of given points


def _mantissa_times(total: U64, u: jax.Array) -> U64:
    """``⌊u·Q⌋`` exactly, for floats ``u`` in ``[0, 1)`` (float32: 24-bit, float64: 53-bit mantissas)."""
    frac, exp = jnp.frexp(u)  # u = frac·2^exp, frac ∈ [0.5, 1)
    digits = jnp.finfo(u.dtype).nmant + 1
    mant = jnp.ldexp(frac, digits)  # an integer < 2^digits, exact
    m_hi = jnp.floor(jnp.ldexp(mant, -32))
    m_lo = (mant - jnp.ldexp(m_hi, 32)).astype(_U32)
    m_hi = m_hi.astype(_U32)
    # 128-bit product total·mant as four words w0..w3
    p_lo = u64.mul_u32(total, m_lo)  # (w2, w1, w0)
    p_hi = u64.mul_u32(total, m_hi)  # shifted by one word
    w0 = p_lo[2]
    w1 = p_lo[1] + p_hi[2]
    c1 = (w1 < p_lo[1]).astype(_U32)
    w2 = p_lo[0] + p_hi[1]
    c2 = (w2 < p_lo[0]).astype(_U32)
    w2c = w2 + c1
    c2 = c2 + (w2c < w2).astype(_U32)
    w3 = p_hi[0] + c2
    words = jnp.stack([w0, w1, w2c, w3, jnp.zeros_like(w0), jnp.zeros_like(w0)])
    shift = (digits - exp).astype(_I32)  # ≥ digits, since u < 1
    word, bit = shift // 32, (shift % 32).astype(_U32)

    def pick(i):
        return jnp.take_along_axis(words, jnp.clip(word + i, 0, 5)[None], axis=0)[0]

    def shifted(i):
        low, high = pick(i), pick(i + 1)
        spill = jnp.where(bit == 0, 0, high << (32 - jnp.maximum(bit, 1)))
        return (low >> bit) | spill

    value = U64(jnp.where(word >= 4, 0, shifted(1)), jnp.where(word >= 4, 0, shifted(0)))
    return u64.where(u > 0, value, U64(jnp.zeros_like(w0), jnp.zeros_like(w0)))


def _points_of_uniforms(total: U64, u: jax.Array) -> U64:
    """Integer points ``⌊u·Q⌋`` of uniforms ``u``; ``u ≥ 1`` maps to ``Q − 1`` and NaN or ``u < 0`` to 0."""
    u = jax.lax.stop_gradient(u)
    top = u >= 1
    u = jnp.where((u >= 0) & ~top, u, jnp.zeros_like(u))
    y = _mantissa_times(total, u)
    return u64.where(top, u64.sub(total, U64(jnp.zeros_like(y.hi), jnp.ones_like(y.lo))), y)


def inverse_cdf(uniforms: jax.Array, weights: jax.Array) -> jax.Array:
    """Ancestors ``A_m = min{j : u_m·Q < S_j}`` of points ``u_m ∈ [0, 1)``, exactly (any order of the points).

    ``weights [N]`` are non-negative (un-normalised allowed; see :func:`integer_cdf`).
    ``S`` is the exact integer CDF of the module docstring and ``⌊u·Q⌋`` is computed
    exactly from the float's mantissa, so a particle of zero weight is never returned
    and every index is in ``[0, N)``; ``u ≥ 1`` returns the last particle of positive
    weight. This is [A] App. B's inverse CDF: it selects the same indices as
    ``filterpy``'s ``systematic_resample`` for the same uniform draw whenever float64
    arithmetic decides them correctly.

    Cost O(N + P·log(B + 1)) for P points, ``B`` the most CDF values ``S_i`` in one of
    ``N`` equal strata of ``[0, Q)`` (1–3 for ordinary weights): each point's stratum
    comes from :func:`stratum_and_remainder`, then a binary search runs among the
    particles whose CDF values fall in that stratum.
    """
    cdf = integer_cdf(weights)
    n = weights.shape[0]
    sc = scale(cdf.total, n, n)
    k, r = stratum_and_remainder(sc, cdf.cdf)
    ceiling = k + ((r.hi > 0) | (r.lo > 0)).astype(_I32)  # ⌈S_i·N/Q⌉
    # left[s] = #{i : S_i·N ≤ s·Q}: the particles left of stratum s
    left = fastmath.int_cumsum(jnp.zeros((n + 1,), _I32).at[ceiling].add(1, indices_are_sorted=True))
    points = _points_of_uniforms(cdf.total, uniforms)
    s, _ = stratum_and_remainder(sc, points)
    lo, hi = jnp.take(left, s, mode="clip"), jnp.take(left, jnp.minimum(s + 1, n), mode="clip")
    return jnp.minimum(_prefix_count(lo, hi, lambda i: u64.less_equal(u64.take(cdf.cdf, i), points)), n - 1)
