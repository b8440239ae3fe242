"""Resampling schemes on log-weights.

Overview
--------
Every scheme has the signature ``(key, log_weights, num_samples) -> indices``:
it takes *unnormalised* log-weights ``[N]`` and returns ``num_samples`` int32
ancestor indices in ``[0, N)``. All four are unbiased: the expected number of
offspring of particle ``i`` is ``M·w̄_i`` (Douc & Cappé 2005).

* ``multinomial`` — i.i.d. draws from the categorical distribution.
* ``systematic`` — one uniform ``u``, points ``(u + m)/M``; this is the
  low-variance sampler of [A] App. B, O(N + M) here as there, but with no
  sequential loop (:func:`stratified_inverse_cdf`).
* ``stratified`` — one uniform per stratum ``[(m)/M, (m+1)/M)``.
* ``residual`` — ``⌊M w̄_i⌋`` deterministic copies, the remainder drawn
  multinomially from the residual weights.

Numerical guards (float32): the cumulative sum is normalised by its last
entry, queries are clamped below 1, and indices are clipped to ``[0, N)``, so
extreme weights (one particle holding all the mass, entries of ``-inf``) never
yield an out-of-range index. A degenerate set (all ``-inf``/NaN) is resampled
uniformly.

:func:`conditional_resample` applies a scheme only when the ESS falls below a
fraction of N, decided independently for every run when vmapped;
:func:`gaussian_refresh` is the Gaussian approximation of [A] §4.3.3;
:func:`kernel_refresh` is the regularised alternative that keeps several modes.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
from jax import custom_batching

from jaxnav.core import fastmath
from jaxnav.core import weights as _w

__all__ = [
    "Resampler",
    "multinomial",
    "systematic",
    "stratified",
    "residual",
    "inverse_cdf",
    "stratified_inverse_cdf",
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
]

SORTED_SCHEMES = ("systematic", "stratified")
"""Schemes whose ancestor indices are non-decreasing (required by :func:`copy_ancestors_in_place`)."""

Resampler = Callable[[jax.Array, jax.Array, int], jax.Array]


def _cdf(weights: jax.Array) -> jax.Array:
    cdf = fastmath.cumsum(weights)
    # An explicit reciprocal: XLA may turn a division by a scalar into this
    # product inside some fusions and not others, and the two resampling
    # paths must see bit-identical CDFs.
    return cdf * (1.0 / cdf[-1])


def _clamp_below_one(u: jax.Array, dtype) -> jax.Array:
    # Guard float32 round-off: no query may reach the total mass.
    return jnp.minimum(u, jnp.nextafter(jnp.asarray(1.0, dtype), 0.0))


def inverse_cdf(sorted_uniforms: jax.Array, weights: jax.Array) -> jax.Array:
    """Indices ``A_m = min{j : u_m < Σ_{i≤j} w_i}`` for sorted uniforms in ``[0, 1)``.

    ``weights`` are non-negative probabilities ``[N]`` (they need not sum to 1
    exactly: the cumulative sum is rescaled by its last entry). This is the
    inner loop of [A] App. B's low-variance sampler written as one
    ``searchsorted`` (O(M log N)); it selects the same indices as
    ``filterpy``'s ``systematic_resample`` for the same uniform draw. The
    systematic and stratified schemes use :func:`stratified_inverse_cdf`,
    which returns the same indices in O(N + M).
    """
    cdf = _cdf(weights)
    u = _clamp_below_one(sorted_uniforms, cdf.dtype)
    idx = jnp.searchsorted(cdf, u, side="right")
    return jnp.clip(idx, 0, weights.shape[0] - 1).astype(jnp.int32)


_SMALL = 2048 * 2048  # below this N·M the searchsorted path is faster on XLA:CPU (W1), unbatched


def stratified_inverse_cdf(points: jax.Array, weights: jax.Array) -> jax.Array:
    """:func:`inverse_cdf` for points with ``points[m] ∈ [m/M, (m+1)/M]``, in O(N + M).

    Systematic and stratified points have one point per stratum, so the
    number of points below ``cdf_i`` is ``⌊M·cdf_i⌋`` up to one or two (round-off
    and the point inside the stratum). Counting ``c_i = #{m : p_m < cdf_i}``
    exactly takes four comparisons around that estimate; then the index of
    point ``m`` is ``#{i : c_i ≤ m}``, a histogram and a cumulative sum. No
    binary search: this is the merge of [A] App. B's low-variance sampler
    without its sequential loop. Returns exactly what :func:`inverse_cdf`
    returns for the same points (a test checks it).

    Which of the two computes it: unbatched, the binary search for small sets
    (``N·M ≤ 2048²``, fewer operations to dispatch) and the merge above; under
    ``vmap`` (many runs, or many tags' sets at once) always the merge, because a
    batched binary search is a ``while`` loop of gathers that costs more than the
    merge at every size we measured (PF-SLAM's 24 × 100-particle tag sets: a
    third of the step). Indices carry no gradient, so the inputs are
    ``stop_gradient``-ed (differentiating a filter through its resampling works).
    """
    return _stratified_inverse_cdf(jax.lax.stop_gradient(points), jax.lax.stop_gradient(weights))


def _merge_inverse_cdf(points: jax.Array, weights: jax.Array) -> jax.Array:
    n, m = weights.shape[0], points.shape[0]
    cdf = _cdf(weights)
    p = _clamp_below_one(points, cdf.dtype)
    est = jnp.floor(cdf * m).astype(jnp.int32)

    def below(j):  # [p_j < cdf_i] with p_{<0} = -inf and p_{≥M} = +inf
        inside = (j >= 0) & (j < m)
        return jnp.where(inside, jnp.take(p, jnp.clip(j, 0, m - 1)) < cdf, j < 0)

    counts = est - 2 + sum(below(est + d).astype(jnp.int32) for d in (-2, -1, 0, 1))
    counts = jnp.clip(counts, 0, m)
    hist = jnp.zeros((m + 1,), jnp.int32).at[counts].add(1, indices_are_sorted=True)
    return jnp.clip(fastmath.count_cumsum(hist[:m]), 0, n - 1)


@custom_batching.custom_vmap
def _stratified_inverse_cdf(points: jax.Array, weights: jax.Array) -> jax.Array:
    if weights.shape[0] * points.shape[0] <= _SMALL:  # tiny sets: the binary search has fewer ops to dispatch
        return inverse_cdf(points, weights)
    return _merge_inverse_cdf(points, weights)


@_stratified_inverse_cdf.def_vmap
def _stratified_inverse_cdf_batched(axis_size, in_batched, points, weights):
    points = points if in_batched[0] else jnp.broadcast_to(points, (axis_size,) + points.shape)
    weights = weights if in_batched[1] else jnp.broadcast_to(weights, (axis_size,) + weights.shape)
    return jax.vmap(_merge_inverse_cdf)(points, weights), True


# Each scheme is written on normalised probabilities ``p`` (and the matching
# normalised log-weights, which multinomial draws from), so that a filter that
# has already normalised its weights does not pay for it again.


def _multinomial_p(key: jax.Array, log_p: jax.Array, p: jax.Array, num_samples: int) -> jax.Array:
    return jax.random.categorical(key, log_p, shape=(num_samples,)).astype(jnp.int32)


def _systematic_p(key: jax.Array, log_p: jax.Array, p: jax.Array, num_samples: int) -> jax.Array:
    dtype = jnp.result_type(p.dtype, jnp.float32)
    u = jax.random.uniform(key, (), dtype)
    points = (u + jnp.arange(num_samples, dtype=dtype)) / num_samples
    return stratified_inverse_cdf(points, p)


def _stratified_p(key: jax.Array, log_p: jax.Array, p: jax.Array, num_samples: int) -> jax.Array:
    dtype = jnp.result_type(p.dtype, jnp.float32)
    u = jax.random.uniform(key, (num_samples,), dtype)
    points = (u + jnp.arange(num_samples, dtype=dtype)) / num_samples
    return stratified_inverse_cdf(points, p)


def _residual_p(key: jax.Array, log_p: jax.Array, p: jax.Array, num_samples: int) -> jax.Array:
    n = p.shape[0]
    counts = jnp.floor(num_samples * p)
    counts_int = counts.astype(jnp.int32)
    n_det = jnp.sum(counts_int)
    # Deterministic copies: slot m belongs to the particle whose cumulative count exceeds m.
    cum = jnp.cumsum(counts_int)
    slots = jnp.arange(num_samples, dtype=jnp.int32)
    det_idx = jnp.clip(jnp.searchsorted(cum, slots, side="right"), 0, n - 1)
    resid = num_samples * p - counts
    resid_total = jnp.sum(resid)
    log_resid = jnp.where(resid > 0, jnp.log(jnp.where(resid > 0, resid, 1.0)), -jnp.inf)
    # When nothing is left over every slot is deterministic; any finite logits do.
    log_resid = jnp.where(resid_total > 0, log_resid, jnp.zeros_like(log_resid))
    rand_idx = jax.random.categorical(key, log_resid, shape=(num_samples,))
    return jnp.where(slots < n_det, det_idx, rand_idx).astype(jnp.int32)


def _on_log_weights(scheme_p):
    def resampler(key: jax.Array, log_weights: jax.Array, num_samples: int) -> jax.Array:
        log_p = _w.normalize(log_weights).log_weights
        return scheme_p(key, log_p, jnp.exp(log_p), num_samples)

    return resampler


def multinomial(key: jax.Array, log_weights: jax.Array, num_samples: int) -> jax.Array:
    """Multinomial resampling: ``num_samples`` i.i.d. categorical draws."""
    return _on_log_weights(_multinomial_p)(key, log_weights, num_samples)


def systematic(key: jax.Array, log_weights: jax.Array, num_samples: int) -> jax.Array:
    """Systematic (low-variance) resampling, [A] App. B: points ``(u + m)/M``, one ``u``."""
    return _on_log_weights(_systematic_p)(key, log_weights, num_samples)


def stratified(key: jax.Array, log_weights: jax.Array, num_samples: int) -> jax.Array:
    """Stratified resampling: one uniform in each stratum ``[m/M, (m+1)/M)``."""
    return _on_log_weights(_stratified_p)(key, log_weights, num_samples)


def residual(key: jax.Array, log_weights: jax.Array, num_samples: int) -> jax.Array:
    """Residual resampling: ``⌊M w̄_i⌋`` copies, the rest multinomial on the residuals.

    Shapes are static: the deterministic part fills the first
    ``Σ⌊M w̄_i⌋`` slots (found with an inverse CDF on the integer counts), the
    remaining slots take multinomial draws from ``M w̄_i − ⌊M w̄_i⌋``.
    """
    return _on_log_weights(_residual_p)(key, log_weights, num_samples)


_ON_PROBABILITIES = {
    multinomial: _multinomial_p,
    systematic: _systematic_p,
    stratified: _stratified_p,
    residual: _residual_p,
}


SCHEMES: dict[str, Resampler] = {
    "multinomial": multinomial,
    "systematic": systematic,
    "stratified": stratified,
    "residual": residual,
}


def get_resampler(name: str) -> Resampler:
    """The resampling scheme called ``name`` (one of :data:`SCHEMES`)."""
    try:
        return SCHEMES[name]
    except KeyError:
        raise ValueError(
            f"resampling scheme {name!r} is unknown; choose one of {sorted(SCHEMES)}"
        ) from None


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
    eps = jax.random.normal(key, (num_samples, mean.shape[-1]), mean.dtype)
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
    eps = jax.random.normal(key, (n, d), particles.dtype)
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
        new = jax.tree_util.tree_map(lambda x: jnp.take(x, idx, axis=0), particles)
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
    FastSLAM maps (tens of MB) that costs new, zeroed pages every step and
    doubled the time of a W3 step at M = 4000, N = 1000. The loop costs about
    a microsecond per copied row, so use it only for large rows. Ancestors of
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
