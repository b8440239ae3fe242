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

The schemes decide every ancestor exactly on an integer CDF of the weights
(:mod:`jaxnav.core.integer_cdf`, whose docstring gives the construction): a
particle of zero weight is never drawn, every ancestor is in ``[0, N)``, with
equal weights and ``M = N`` systematic and stratified copy every particle
exactly once at any N, and the expected number of offspring is ``M·q_i/Q``
for the integer weights ``q_i``. Cost O(N + M); :func:`systematic` counts its
passes over memory. :func:`~jaxnav.core.integer_cdf.inverse_cdf` gives the same
guarantees for any points in ``[0, 1)``.

:func:`conditional_resample` applies a scheme only when the ESS falls below a
fraction of N, decided independently for every run when vmapped; it can redraw
the resampled set with a refresh of :mod:`jaxnav.core.refresh`
(:func:`~jaxnav.core.refresh.gaussian_refresh`, the Gaussian approximation of
[A] §4.3.3, or :func:`~jaxnav.core.refresh.kernel_refresh`, the regularised
alternative that keeps several modes).

The integer CDF and the refreshes are re-exported here, under the names they
have always had in this module.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxnav.core import fastmath, rng, u64
from jaxnav.core import weights as _w
from jaxnav.core.gradients import check_gradient, selection_score, soft_carried_log_weights, soft_proposal
from jaxnav.core.integer_cdf import (
    MAX_SAMPLES,
    TOTAL_BITS,
    IntegerCDF,
    Scale,
    _prefix_count,
    ancestors_from_counts,
    integer_cdf,
    inverse_cdf,
    scale,
    stratum_and_remainder,
)
from jaxnav.core.refresh import REFRESHES, gaussian_draw, gaussian_refresh, kernel_refresh, silverman_bandwidth
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

Resampler = Callable[[jax.Array, jax.Array, int], jax.Array]

_I32 = jnp.int32
_U32 = jnp.uint32


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
    :func:`~jaxnav.core.integer_cdf.stratum_and_remainder`), ``R_i = (K_i − D_i) + r_i/Q``: the residual
    boundaries are exact with no arithmetic wider than the main CDF's, and the draws are uniform points
    of ``[0, M − Σd)``.
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
    uniform. Subnormal weights count with their exact values
    (:func:`~jaxnav.core.integer_cdf.integer_cdf`): ``[1e-45, 1e-45, 0]`` in float32 draws indices
    0 and 1 equally often, never 2.
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


# --------------------------------------------------------------------------- conditional resampling


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


def conditional_resample(
    key: jax.Array,
    particles: jax.Array,
    log_weights: jax.Array,
    threshold: float | jax.Array = 0.5,
    scheme: str | Resampler = "systematic",
    refresh: bool | str = False,
    angle_dims: tuple[int, ...] = (),
    normalized: bool = False,
    gradient: str = "score",
    soft_mixing: float = 0.5,
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
            from the Gaussian fitted to it ([A] §4.3.3, :func:`~jaxnav.core.refresh.gaussian_refresh`),
            ``"kernel"`` from its kernel density (:func:`~jaxnav.core.refresh.kernel_refresh`);
            ``False`` keeps the duplicates. Only for array particles ``[N, D]``.
        angle_dims: components averaged on the circle by the refresh.
        normalized: promise that ``log_weights`` are already normalised (as
            :func:`jaxnav.core.weights.normalize` returns them), which saves
            normalising again inside a filter step.
        gradient: how derivatives pass the resampling, a name in
            :data:`~jaxnav.core.gradients.GRADIENT_ESTIMATORS` (:mod:`jaxnav.core.gradients`):
            ``"score"`` (default; stop-gradient resampling, the forward pass unchanged),
            ``"soft"`` (ancestors drawn from ``α w̄ + (1 − α)/N``, importance weights carried)
            or ``"naive"`` (uniform weights after resampling, no derivative).
        soft_mixing: ``α`` in ``[0, 1]`` of ``"soft"``.

    The decision is a ``lax.cond``; under ``vmap`` over runs it becomes a
    per-run select, so every run decides for itself. A Python threshold
    ≥ 1 is decided when tracing: no branch at all.
    """
    if not (isinstance(refresh, bool) or refresh in REFRESHES):
        raise ValueError(f"refresh must be True, False or one of {REFRESHES}, got {refresh!r}")
    check_gradient(gradient, soft_mixing)
    if gradient == "soft" and refresh:  # a refresh redraws the set as if its weights were uniform
        raise ValueError("gradient 'soft' cannot be combined with a refresh")
    resampler = get_resampler(scheme) if isinstance(scheme, str) else scheme
    lw = log_weights if normalized else _w.normalize(log_weights).log_weights
    n = lw.shape[0]
    p = jnp.exp(lw)
    k_res, k_ref = jax.random.split(key)
    scheme_p = _ON_PROBABILITIES.get(resampler)
    uniform = jnp.full_like(lw, -jnp.log(jnp.asarray(n, lw.dtype)))

    def _resample():
        if gradient == "soft":
            log_q = soft_proposal(lw, soft_mixing)
            log_draw, p_draw = jax.lax.stop_gradient(log_q), jax.lax.stop_gradient(jnp.exp(log_q))
        else:
            log_draw, p_draw = lw, p
        idx = scheme_p(k_res, log_draw, p_draw, n) if scheme_p is not None else resampler(k_res, log_draw, n)
        new = jax.tree_util.tree_map(lambda x: jnp.take(x, idx, axis=0, mode="clip"), particles)
        if refresh == "kernel":
            new = kernel_refresh(k_ref, new, None, angle_dims)
        elif refresh:
            new = gaussian_refresh(k_ref, new, None, angle_dims)
        if gradient == "score":
            carried = uniform + selection_score(jnp.take(lw, idx, axis=0, mode="clip"))
        elif gradient == "soft":
            carried = soft_carried_log_weights(lw, log_q, idx)
        else:
            carried = uniform
        return new, carried, idx

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
