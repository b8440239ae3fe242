"""Resampling schemes on log-weights, exact at any particle count.

**Overview**

Every scheme has the signature ``(key, log_weights, num_samples) -> ancestors``:
it takes *unnormalised* log-weights ``[N]`` and returns ``num_samples`` int32
ancestor indices in ``[0, N)``, **in non-decreasing order**. All four are
unbiased: the expected number of offspring of particle ``i`` is ``M·w̄_i``
(Douc & Cappé 2005), ``M`` = ``num_samples``.

* ``systematic`` — one uniform ``u``, points ``(m + u)/M``: the low-variance
  sampler of [A] App. B, with no sequential loop.
* ``stratified`` — one uniform ``u_m`` per stratum, points ``(m + u_m)/M``.
* ``multinomial`` — ``M`` i.i.d. draws from the categorical distribution,
  generated as sorted uniforms (O(N + M), not an ``M × N`` block of draws).
  Like the others it returns its ancestors sorted.
* ``residual`` — ``⌊M w̄_i⌋`` deterministic copies, the remainder drawn
  multinomially from the residual weights.

**Exactness**

A float32 cumulative sum cannot resample large sets: near its top it moves in
steps of 6·10⁻⁸ while a particle's weight at N = 10⁶ is 10⁻⁶, so tens of
thousands of particles of positive weight can never be drawn, others are drawn
up to several times too often, and a blocked sum can even give a particle of
zero weight a sliver of the CDF. Here a resampling is exact:

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
:func:`systematic` counts its passes over memory.

:func:`inverse_cdf` gives the same guarantees for any points in ``[0, 1)``:
``min{i : u·Q < S_i}`` with ``⌊u·Q⌋`` computed exactly from the float's mantissa.

:func:`conditional_resample` applies a scheme only when the ESS falls below a
fraction of N, decided independently for every run when vmapped;
:func:`gaussian_refresh` is the Gaussian approximation of [A] §4.3.3;
:func:`kernel_refresh` is the regularised alternative that keeps several modes.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxnav.core import fastmath, rng, u64
from jaxnav.core import weights as _w
from jaxnav.core.u64 import U64

__all__ = [
    "Resampler",
    "multinomial",
    "systematic",
    "stratified",
    "residual",
    "resample_weights",
    "inverse_cdf",
    "IntegerCDF",
    "integer_cdf",
    "Scale",
    "scale",
    "stratum_and_remainder",
    "ancestors_from_counts",
    "SortedDraws",
    "sorted_uniform_draws",
    "MAX_SAMPLES",
    "SCHEMES",
    "get_resampler",
    "ResampleResult",
    "conditional_resample",
    "gaussian_refresh",
    "gaussian_draw",
    "kernel_refresh",
    "silverman_bandwidth",
    "REFRESHES",
    "copy_ancestors_in_place",
    "SORTED_SCHEMES",
    "TOTAL_BITS",
]

SORTED_SCHEMES = ("systematic", "stratified", "multinomial", "residual")
"""Schemes whose ancestor indices are non-decreasing, as ``copy_ancestors_in_place`` requires (all four)."""

TOTAL_BITS = 61
"""The integer weights of a resampling are scaled so that their total lies in ``[2^(TOTAL_BITS−1), 2^TOTAL_BITS)``
(up to the 1 % accuracy of the float estimate that chooses the power of two)."""

MAX_SAMPLES = 2**29 - 1
"""The largest number of samples (and of particles) one resampling accepts."""

Resampler = Callable[[jax.Array, jax.Array, int], jax.Array]

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


def _scaled_to_top(p: jax.Array) -> jax.Array:
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
    top = jax.lax.bitcast_convert_type(jnp.max(key), bits_type) - binade
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


def integer_cdf(probabilities: jax.Array) -> IntegerCDF:
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
    """
    p = _scaled_to_top(jax.lax.stop_gradient(probabilities))  # exact: the largest weight lies in [0.5, 2)
    n = p.shape[0]
    total = _two_level_sum(p)
    empty = ~(total > 0)
    p = jnp.where(empty, 1.0, p)
    total = jnp.where(empty, jnp.asarray(n, p.dtype), total)
    _, total_exp = jnp.frexp(total)
    q = u64.from_float(p * _power_of_two(TOTAL_BITS - total_exp, p.dtype))
    cdf = u64.cumsum(q)
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


# --------------------------------------------------------------------------- the schemes, on probabilities


def _systematic_counts(key: jax.Array, cdf: IntegerCDF, sc: Scale) -> jax.Array:
    """``#{s : (s + u)/M·Q < S_i}`` with one 32-bit uniform ``u = U/2³²``: ``k + [k < M and ⌊U·Q/2³²⌋ < r]``."""
    offset = u64.mul_high(sc.total, rng.bits(key, (), _U32))
    k, r = stratum_and_remainder(sc, cdf.cdf)
    return k + ((k < sc.count.astype(_I32)) & u64.less(offset, r)).astype(_I32)


def _stratified_counts(key: jax.Array, cdf: IntegerCDF, sc: Scale) -> jax.Array:
    """As :func:`_systematic_counts` with one uniform ``U_s`` per stratum."""
    u = rng.bits(key, (sc.size,), _U32)
    k, r = stratum_and_remainder(sc, cdf.cdf)
    offset = u64.mul_high(sc.total, jnp.take(u, k, mode="clip"))
    return k + ((k < sc.count.astype(_I32)) & u64.less(offset, r)).astype(_I32)


_SPACING_BITS = 20  # exponential spacings as integers: resolution 2⁻²⁰ of their mean


def _spacings(key: jax.Array, size: int) -> jax.Array:
    """``⌊E·2²⁰⌋ + 1`` for i.i.d. ``E ~ Exp(1)`` (from float32 uniforms in ``[2⁻²⁴, 1)``, so ``E ≤ 16.7``)."""
    e = -jnp.log(rng.uniform(key, (size,), jnp.float32, minval=2.0**-24, maxval=1.0))
    return (e * 2.0**_SPACING_BITS).astype(_U32) + 1


class SortedDraws(NamedTuple):
    """``size`` slots; the first ``count`` hold i.i.d. uniform points ``(s + f)/M`` of ``[0, 1)``, in order.

    Attributes:
        stratum: ``[size]`` int32 stratum ``s`` of each slot (non-decreasing).
        fraction: ``[size]`` uint32 position ``f = F/2³²`` inside the stratum (increasing inside a stratum).
        first: ``[size + 1]`` int32 first slot of each stratum.
        occupancy: ``[size]`` int32 number of points in each stratum.
    """

    stratum: jax.Array
    fraction: jax.Array
    first: jax.Array
    occupancy: jax.Array


def sorted_uniform_draws(key: jax.Array, count: jax.Array, num_strata: jax.Array, size: int) -> SortedDraws:
    """``count`` (≤ ``size``) i.i.d. uniform points of ``[0, 1)`` in increasing order, in O(size).

    Each point's stratum ``s`` (of ``num_strata``) is drawn uniformly from 64 random
    bits; one histogram and two integer cumulative sums group the points by stratum,
    in order. Inside a stratum holding ``K`` points the fractions are the order
    statistics of ``K`` uniforms: ``K + 1`` exponential spacings (integers, resolution
    2⁻²⁰ of their mean), partial sums over their total, to 32 bits. The strata are
    equally likely to 2⁻⁶⁴ and a fraction is exact to about 2⁻²⁴ of its stratum.
    """
    k_stratum, k_space, k_gap = jax.random.split(key, 3)
    bits = rng.bits(k_stratum, (2, size), _U32)
    stratum_of_draw = u64.mul_u32(U64(bits[0], bits[1]), jnp.asarray(num_strata).astype(_U32))[0].astype(_I32)
    active = jnp.arange(size, dtype=_I32) < count
    occupancy = jnp.zeros((size,), _I32).at[stratum_of_draw].add(active.astype(_I32), mode="drop")
    last = fastmath.int_cumsum(occupancy)  # one past the last slot of each stratum
    first = jnp.concatenate([jnp.zeros((1,), _I32), last])
    stratum = ancestors_from_counts(last, size)  # the stratum of every slot, non-decreasing
    run = fastmath.int_cumsum(_spacings(k_space, size))  # wrapping: differences inside a stratum are exact
    start = jnp.take(first, stratum)
    before = jnp.where(start > 0, jnp.take(run, start - 1, mode="clip"), 0)
    end = jnp.take(run, jnp.take(last, stratum) - 1, mode="clip")
    gap = jnp.take(_spacings(k_gap, size), stratum)
    fraction = (run - before).astype(jnp.float32) / (end - before + gap).astype(jnp.float32)
    fraction = jnp.minimum(fraction * 2.0**32, 2.0**32 - 256).astype(_U32)
    return SortedDraws(stratum, fraction, first, occupancy)


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


def _counts_below(key: jax.Array, stratum: jax.Array, remainder: U64, total: U64, num_draws: jax.Array, size: int):
    """``#{p : (s_p + F_p/2³²) < k_i + r_i/Q}`` for :func:`sorted_uniform_draws` of ``num_draws`` points in as many
    unit strata, against boundaries given as a stratum ``k_i`` (int32) and a remainder ``r_i ∈ [0, Q)``.

    The points of strata below ``k_i`` all count; a point of stratum ``k_i`` counts exactly when
    ``⌊F·Q/2³²⌋ < r_i``, found by a binary search among that stratum's points.
    """
    draws = sorted_uniform_draws(key, num_draws, num_draws, size)
    inside = stratum < num_draws
    lo = jnp.where(inside, jnp.take(draws.first, stratum, mode="clip"), num_draws)
    hi = jnp.where(inside, lo + jnp.take(draws.occupancy, stratum, mode="clip"), lo)
    return _prefix_count(
        lo, hi, lambda p: u64.less(u64.mul_high(total, jnp.take(draws.fraction, p, mode="clip")), remainder)
    )


def _multinomial_counts(key: jax.Array, cdf: IntegerCDF, sc: Scale) -> jax.Array:
    """``M`` i.i.d. uniform points of ``[0, M)`` (in units of ``Q/M``) against ``S_i·M/Q = k_i + r_i/Q``."""
    k, r = stratum_and_remainder(sc, cdf.cdf)
    return _counts_below(key, k, r, sc.total, sc.count.astype(_I32), sc.size)


def _residual_counts(key: jax.Array, cdf: IntegerCDF, sc: Scale) -> jax.Array:
    """``d_i = ⌊M·q_i/Q⌋`` copies of particle ``i``, then ``M − Σd`` multinomial draws on the residuals.

    In units of one expected offspring, particle ``i`` owns ``[R_{i−1}, R_i)`` of the residual mass, with
    ``R_i = M·S_i/Q − D_i`` and ``D_i = Σ_{j≤i} d_j``. With ``M·S_i = K_i·Q + r_i`` (the strata of
    :func:`stratum_and_remainder`), ``R_i = (K_i − D_i) + r_i/Q``: the residual boundaries are exact with no
    arithmetic wider than the main CDF's, and the draws are uniform points of ``[0, M − Σd)``.
    """
    copies, _ = stratum_and_remainder(sc, cdf.weights)
    fixed = fastmath.int_cumsum(copies)
    k, r = stratum_and_remainder(sc, cdf.cdf)
    num_draws = sc.count.astype(_I32) - fixed[-1]
    return fixed + _counts_below(key, k - fixed, r, sc.total, num_draws, sc.size)


_COUNTS = {
    "systematic": _systematic_counts,
    "stratified": _stratified_counts,
    "multinomial": _multinomial_counts,
    "residual": _residual_counts,
}


def resample_weights(
    key: jax.Array,
    weights: jax.Array,
    num_samples: int,
    scheme: str = "systematic",
    num_active: jax.Array | None = None,
) -> jax.Array:
    """Ancestors ``[num_samples]`` (int32, non-decreasing) drawn from non-negative ``weights [N]`` (not logs).

    The scheme functions (:func:`systematic`, …) take log-weights and call this with
    ``exp(ℓ − max ℓ)``. ``weights`` need not be normalised; NaN, ``±inf`` and negative
    entries count as zero, and a vector with no positive entry is resampled as if
    uniform. Subnormal weights count with their exact values (:func:`integer_cdf`):
    ``[1e-45, 1e-45, 0]`` in float32 draws indices 0 and 1 equally often, never 2.
    ``num_active`` (optional, may be traced, ``1 ≤ num_active ≤ num_samples``): draw
    that many samples into the first slots (``M = num_active``); the remaining slots
    hold ``N − 1`` and are for the caller to mask.

    The uniforms each scheme draws from ``key`` (a reference implementation can
    reproduce them): systematic ``U = jax.random.bits(key, (), uint32)``; stratified
    ``U = jax.random.bits(key, (num_samples,), uint32)``, ``U_s`` for stratum ``s``;
    multinomial :func:`sorted_uniform_draws` ``(key, M, M, num_samples)`` (points
    ``s + F/2³²`` of ``[0, M)``, in units of ``Q/M``); residual the same with
    ``M − Σ⌊M·q_i/Q⌋`` draws and strata.
    """
    if scheme not in _COUNTS:
        raise ValueError(f"resampling scheme {scheme!r} is unknown; choose one of {sorted(_COUNTS)}")
    if num_active is not None and scheme != "systematic":
        raise ValueError(f"num_active is supported by the systematic scheme only, not {scheme!r}")
    cdf = integer_cdf(weights)
    sc = scale(cdf.total, num_samples if num_active is None else num_active, num_samples)
    return ancestors_from_counts(_COUNTS[scheme](key, cdf, sc), num_samples, single_reader=True)


def _on_log_weights(scheme: str, key, log_weights, num_samples, num_active=None):
    # exp(ℓ − max ℓ) suffices: the integer weights are normalised exactly (an all −inf set gives NaN,
    # which integer_cdf treats as uniform).
    lw = _w.sanitize_log_weights(jax.lax.stop_gradient(log_weights))
    return resample_weights(key, jnp.exp(lw - jnp.max(lw)), num_samples, scheme, num_active)


def systematic(
    key: jax.Array, log_weights: jax.Array, num_samples: int, num_active: jax.Array | None = None
) -> jax.Array:
    """Systematic (low-variance) resampling, [A] App. B: one uniform ``u``, points ``(s + u)/M``.

    ``u = U/2³²`` with ``U = jax.random.bits(key, (), uint32)``; the ancestors are exactly
    those of real arithmetic on the integer weights (module docstring). Particle ``i``
    gets ``⌊M w̄_i⌋`` or ``⌈M w̄_i⌉`` offspring. ``num_active``: see :func:`resample_weights`.

    Memory passes (float32 weights, N = M): the log-weights are read three times (their
    maximum, the sum of the weights, the two integer words of each weight, fused into the
    first cumulative sum); the two integer cumulative sums read and write their words about
    three times each; one fused pass finds each particle's stratum and compares it with
    the stratum's point; the ancestors take a histogram and one more cumulative sum. About
    fifteen passes in all, against the two of the memory floor (read the weights, write the
    indices).
    """
    return _on_log_weights("systematic", key, log_weights, num_samples, num_active)


def stratified(key: jax.Array, log_weights: jax.Array, num_samples: int) -> jax.Array:
    """Stratified resampling: one uniform ``u_s = U_s/2³²`` per stratum, points ``(s + u_s)/M``.

    ``U = jax.random.bits(key, (num_samples,), uint32)``. Exact as :func:`systematic`;
    a particle's count is within two of ``M w̄_i``.
    """
    return _on_log_weights("stratified", key, log_weights, num_samples)


def multinomial(key: jax.Array, log_weights: jax.Array, num_samples: int) -> jax.Array:
    """Multinomial resampling: ``num_samples`` i.i.d. categorical draws, returned sorted.

    The draws are the sorted i.i.d. uniforms of :func:`sorted_uniform_draws`, merged with
    the exact CDF in O(N + M) instead of the ``M × N`` Gumbel block of
    ``jax.random.categorical``. The binary search inside a
    stratum takes ``⌈log₂(K_max + 1)⌉`` steps, ``K_max`` the most draws one stratum
    received (about 10 at M = 10⁸). The ancestors are sorted; their order carries no
    information.
    """
    return _on_log_weights("multinomial", key, log_weights, num_samples)


def residual(key: jax.Array, log_weights: jax.Array, num_samples: int) -> jax.Array:
    """Residual resampling: ``⌊M w̄_i⌋`` copies, the rest multinomial on the residuals.

    ``d_i = ⌊M·q_i/Q⌋`` copies; the ``M − Σd`` remaining samples are i.i.d. draws with
    probabilities proportional to the residuals ``M·q_i/Q − d_i``, whose cumulative sums
    are exact (see ``_residual_counts``). Ancestors are sorted.
    """
    return _on_log_weights("residual", key, log_weights, num_samples)


# The schemes on normalised probabilities ``p`` (and the matching normalised log-weights), so that a
# filter that has already normalised its weights does not pay for it again.
_ON_PROBABILITIES = {
    scheme: (lambda name: lambda key, log_p, p, num_samples: resample_weights(key, p, num_samples, name))(name)
    for name, scheme in (
        ("multinomial", multinomial),
        ("systematic", systematic),
        ("stratified", stratified),
        ("residual", residual),
    )
}


SCHEMES: dict[str, Resampler] = {
    "multinomial": multinomial,
    "systematic": systematic,
    "stratified": stratified,
    "residual": residual,
}
"""The resampling schemes by name (``"multinomial"``, ``"systematic"``, ``"stratified"``, ``"residual"``)."""


def get_resampler(name: str) -> Resampler:
    """The resampling scheme called ``name`` (one of :data:`SCHEMES`)."""
    try:
        return SCHEMES[name]
    except KeyError:
        raise ValueError(f"resampling scheme {name!r} is unknown; choose one of {sorted(SCHEMES)}") from None


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


class ResampleResult(NamedTuple):
    """Output of :func:`conditional_resample`.

    Attributes:
        particles: ``[N, ...]`` the (possibly) resampled particles.
        log_weights: ``[N]`` normalised log-weights (uniform after resampling).
        ancestors: ``[N]`` int32 ancestor indices (``arange(N)`` when not resampled).
        resampled: scalar bool.
    """

    particles: jax.Array
    log_weights: jax.Array
    ancestors: jax.Array
    resampled: jax.Array


REFRESHES = ("gaussian", "kernel")
"""What :func:`conditional_resample` may redraw the resampled set from (``refresh=``)."""


def _moments(particles, log_weights, angle_dims):
    """Mean and covariance of ``particles [N, D]`` under ``log_weights`` (uniform if None)."""
    n = particles.shape[0]
    if log_weights is None:
        probs = jnp.full((n,), 1.0 / n, particles.dtype)
    else:
        probs = jnp.exp(_w.normalize(log_weights).log_weights)
    mean = _w.mean_from_probabilities(particles, probs, angle_dims)
    return mean, _w.cov_from_probabilities(particles, probs, mean, angle_dims)


def _cholesky_with_fallback(cov, jitter):
    d = cov.shape[-1]
    cov = 0.5 * (cov + cov.T) + jitter * jnp.eye(d, dtype=cov.dtype)
    chol = jnp.linalg.cholesky(cov)
    # A failed factorisation (NaN) falls back to the diagonal standard deviations.
    diag_chol = jnp.diag(jnp.sqrt(jnp.clip(jnp.diag(cov), 0.0)))
    return jnp.where(jnp.all(jnp.isfinite(chol)), chol, diag_chol)


def gaussian_draw(
    key: jax.Array,
    mean: jax.Array,
    cov: jax.Array,
    num_samples: int,
    angle_dims: tuple[int, ...] = (),
    jitter: float = 1e-9,
) -> jax.Array:
    """``[num_samples, D]`` draws ``μ + L ε`` from ``N(μ, Σ)``, ``L Lᵀ = Σ + jitter·I``, ``angle_dims`` wrapped to ``[-π, π)``.

    The draw of :func:`gaussian_refresh` for a filter that already holds the moments
    (:func:`jaxnav.core.weights.mean_from_probabilities`, :func:`~jaxnav.core.weights.cov_from_probabilities`).
    If ``Σ`` has no Cholesky factor the draw uses its diagonal.
    """
    eps = rng.normal(key, (num_samples, mean.shape[-1]), mean.dtype)
    return _w.wrap_columns(mean + eps @ _cholesky_with_fallback(cov, jitter).T, angle_dims)


def gaussian_refresh(
    key: jax.Array,
    particles: jax.Array,
    log_weights: jax.Array | None = None,
    angle_dims: tuple[int, ...] = (),
    jitter: float = 1e-9,
) -> jax.Array:
    """Redraw ``particles [N, D]`` from the Gaussian fitted to them, [A] §4.3.3.

    For a static target, resampled duplicates stay duplicates forever; [A]
    draws the new set from ``N(μ, Σ)`` of the resampled set instead (Alg. 6
    lines 21–22). ``angle_dims`` are averaged on the circle and wrapped back
    to ``[-π, π)``. ``jitter`` (in the particles' squared units) is added to
    the diagonal so that a collapsed cloud still has a Cholesky factor.
    One Gaussian keeps one mode: see :func:`kernel_refresh` for a set with several.
    """
    mean, cov = _moments(particles, log_weights, angle_dims)
    return gaussian_draw(key, mean, cov, particles.shape[0], angle_dims, jitter)


def silverman_bandwidth(n: int, d: int) -> float:
    """``h = (4 / (N (d + 2)))^{1/(d+4)}``: the kernel width (in units of the set's spread) that minimises the
    mean integrated squared error for a Gaussian density (Silverman 1986, eq. 4.14; Musso, Oudjane & Le Gland
    2001, the regularised particle filter). 0.37 for N = 2000, d = 4."""
    return float((4.0 / (n * (d + 2.0))) ** (1.0 / (d + 4.0)))


def kernel_refresh(
    key: jax.Array,
    particles: jax.Array,
    log_weights: jax.Array | None = None,
    angle_dims: tuple[int, ...] = (),
    bandwidth: float | None = None,
    jitter: float = 1e-9,
) -> jax.Array:
    """Move every particle by ``h · L ε``, ``ε ~ N(0, I)``, ``L Lᵀ = Σ`` of the set: the regularised particle filter.

    Like :func:`gaussian_refresh` it breaks up the duplicates of a static
    target, but it draws from a Gaussian *kernel density* of the resampled set
    (each particle a kernel of covariance ``h² Σ``) instead of one Gaussian, so
    a posterior with several modes keeps them until the reads decide between
    them. [A] §4.3.3 lowers the resampling threshold because its one Gaussian
    cannot hold the early multimodal posterior; this removes that failure.
    ``bandwidth`` ``h`` defaults to :func:`silverman_bandwidth`. Not [A]'s method.
    """
    n, d = particles.shape
    h = silverman_bandwidth(n, d) if bandwidth is None else bandwidth
    chol = _cholesky_with_fallback(_moments(particles, log_weights, angle_dims)[1], jitter)
    eps = rng.normal(key, (n, d), particles.dtype)
    return _w.wrap_columns(particles + h * (eps @ chol.T), angle_dims)


def conditional_resample(
    key: jax.Array,
    particles: jax.Array,
    log_weights: jax.Array,
    threshold: float | jax.Array = 0.5,
    scheme: str | Resampler = "systematic",
    refresh: bool | str = False,
    angle_dims: tuple[int, ...] = (),
    normalized: bool = False,
) -> ResampleResult:
    """Resample when ``ESS < threshold · N``; otherwise pass the particles through.

    Args:
        key: PRNG key.
        particles: pytree whose leaves have leading axis ``N``.
        log_weights: ``[N]`` log-weights.
        threshold: fraction of ``N`` in ``(0, 1]``; ``1.0`` resamples every step
            (ESS ≤ N always, and a uniform set is resampled too). [A] §4.3.3
            advises a low value for static targets refreshed by a Gaussian.
        scheme: a name in :data:`SCHEMES` or a resampler function.
        refresh: after resampling, redraw the set: ``True`` or ``"gaussian"``
            from the Gaussian fitted to it ([A] §4.3.3, :func:`gaussian_refresh`),
            ``"kernel"`` from its kernel density (:func:`kernel_refresh`);
            ``False`` keeps the duplicates. Only for array particles ``[N, D]``.
        angle_dims: components averaged on the circle by the refresh.
        normalized: promise that ``log_weights`` are already normalised (as
            :func:`jaxnav.core.weights.normalize` returns them), which saves
            normalising again inside a filter step.

    The decision is a ``lax.cond``; under ``vmap`` over runs it becomes a
    per-run select, so every run decides for itself. A Python threshold
    ≥ 1 is decided when tracing: no branch at all.
    """
    if not (isinstance(refresh, bool) or refresh in REFRESHES):
        raise ValueError(f"refresh must be True, False or one of {REFRESHES}, got {refresh!r}")
    resampler = get_resampler(scheme) if isinstance(scheme, str) else scheme
    lw = log_weights if normalized else _w.normalize(log_weights).log_weights
    n = lw.shape[0]
    p = jnp.exp(lw)
    k_res, k_ref = jax.random.split(key)
    scheme_p = _ON_PROBABILITIES.get(resampler)
    uniform = jnp.full_like(lw, -jnp.log(jnp.asarray(n, lw.dtype)))

    def _resample():
        idx = scheme_p(k_res, lw, p, n) if scheme_p is not None else resampler(k_res, lw, n)
        new = jax.tree_util.tree_map(lambda x: jnp.take(x, idx, axis=0, mode="clip"), particles)
        if refresh == "kernel":
            new = kernel_refresh(k_ref, new, None, angle_dims)
        elif refresh:
            new = gaussian_refresh(k_ref, new, None, angle_dims)
        return new, uniform, idx

    if isinstance(threshold, (int, float)) and threshold >= 1.0:
        new_particles, new_lw, ancestors = _resample()
        return ResampleResult(new_particles, new_lw, ancestors, jnp.asarray(True))

    ess_value = _w.ess_from_probabilities(p)
    # `<=` at threshold 1 would be wrong for a perfectly uniform set only by
    # round-off; resample-always is requested explicitly with threshold >= 1.
    do_resample = (ess_value < threshold * n) | (jnp.asarray(threshold) >= 1.0)

    def _keep():
        return particles, lw, jnp.arange(n, dtype=jnp.int32)

    new_particles, new_lw, ancestors = jax.lax.cond(do_resample, _resample, _keep)
    return ResampleResult(new_particles, new_lw, ancestors, do_resample)


@jax.custom_jvp
def copy_ancestors_in_place(arrays: tuple, ancestors: jax.Array) -> tuple:
    """``tuple(a[ancestors] for a in arrays)`` computed in place, for *sorted* ``ancestors``.

    With ``a`` non-decreasing, slots ``i`` with ``a_i > i`` are filled in
    increasing ``i`` (each reads a row ``a_i > i`` that no earlier write
    touched), then slots with ``a_i < i`` in decreasing ``i`` (row ``a_i``
    satisfies ``a_{a_i} ≤ a_i``, so no write of either pass touched it);
    slots with ``a_i = i`` are not copied. The copies are
    ``dynamic_slice``/``dynamic_update_slice`` pairs in one ``while`` loop that
    XLA runs in place on the (donated) buffers: no map-sized temporary.

    ``jnp.take`` must write a fresh output as large as its input; for the
    FastSLAM maps (tens of MB) that costs new, zeroed pages every step, as much
    as the rest of a W3 step at M = 4000, N = 1000. The loop has a fixed cost
    per copied row, so use it only for large rows. Ancestors of
    :data:`SORTED_SCHEMES` are sorted; other schemes' are not (the result
    would then be wrong). Differentiable in ``arrays``, forward and reverse mode (a custom
    JVP: the gathered tangents), although the loop itself could not be transposed.
    """
    m = ancestors.shape[0]
    a = ancestors.astype(jnp.int32)
    i = jnp.arange(m, dtype=jnp.int32)
    key = jnp.where(a > i, i, jnp.where(a < i, 2 * m - i, 3 * m))
    order = jnp.argsort(key).astype(jnp.int32)
    count = jnp.sum(a != i)

    def body(r, arrs):
        dst = order[r]
        src = a[dst]
        return tuple(
            jax.lax.dynamic_update_index_in_dim(x, jax.lax.dynamic_index_in_dim(x, src, 0, keepdims=True), dst, 0)
            for x in arrs
        )

    return jax.lax.fori_loop(0, count, body, tuple(arrays))


@copy_ancestors_in_place.defjvp
def _copy_ancestors_in_place_jvp(primals, tangents):
    # The loop's trip count is data-dependent, which reverse mode cannot transpose; the copy is
    # the gather ``a[ancestors]``, so its tangent is the gathered tangent (a gather transposes
    # to a scatter-add).
    arrays, ancestors = primals
    out = copy_ancestors_in_place(arrays, ancestors)
    return out, tuple(jnp.take(t, ancestors, axis=0) for t in tangents[0])
