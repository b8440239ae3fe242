"""Log-weight utilities for particle filters.

**Overview**

Every weight in jaxnav lives on the log scale, from the likelihood to the
resampler. [A] Alg. 6 multiplies raw likelihoods over time, which
underflows within tens of steps in float32; here a particle's unnormalised
log-weight is a sum of log-likelihoods and is normalised with ``logsumexp``.

**Conventions**

* ``log_weights`` has shape ``[N]``; the normalised form satisfies
  ``logsumexp(log_weights) == 0``.
* A particle that must never be chosen has log-weight ``-inf``; NaN is treated
  as ``-inf`` (see :func:`sanitize_log_weights`). When *every* entry is
  ``-inf`` or NaN the set is *degenerate*: the weights are reset to uniform and
  the caller records the event in its step ``info``.

**Effective sample size of a step**

Every filter's ``info.ess`` is :func:`step_ess`: ``1 / Σ w̄_i²`` of the step's
normalised weights, in ``[1, N]``, and **0 on a degenerate step**. A degenerate
step's uniform weights are a reset, not N equally good particles: no particle
explained the observation, so none counts as an effective sample (and
:func:`ess` gives 0 for the same log-weights). Whether the step resamples is
decided on the weights the filter carries on (the uniform ones after a reset),
so a reset is not resampled for its ESS of 0.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax.scipy.special import logsumexp

from jaxnav.core import fastmath

_TWO_PI = 2.0 * math.pi

__all__ = [
    "Normalized",
    "sanitize_log_weights",
    "normalize",
    "log_ess",
    "ess",
    "log_marginal_increment",
    "weighted_mean",
    "weighted_cov",
    "cov_from_probabilities",
    "circular_mean",
    "wrap_angle",
    "wrap_columns",
    "particle_mean",
    "mean_from_probabilities",
    "ess_from_probabilities",
    "step_ess",
]


class Normalized(NamedTuple):
    """Result of :func:`normalize`.

    Attributes:
        log_weights: ``[N]`` normalised log-weights (``logsumexp == 0``).
        log_norm: scalar ``logsumexp`` of the sanitised input; ``-inf`` when
            degenerate.
        degenerate: scalar bool, True when every input entry was ``-inf``/NaN
            and the weights were reset to uniform.
    """

    log_weights: jax.Array
    log_norm: jax.Array
    degenerate: jax.Array


def sanitize_log_weights(log_weights: jax.Array) -> jax.Array:
    """Replace NaN and ``+inf`` log-weights by ``-inf``.

    A NaN likelihood means "this particle cannot explain the data", so it gets
    zero weight rather than poisoning the whole set; ``+inf`` is no density a
    proper model can return, so it is treated the same way.
    """
    bad = jnp.isnan(log_weights) | (log_weights == jnp.inf)
    return jnp.where(bad, -jnp.inf, log_weights)


def normalize(log_weights: jax.Array, axis_name: str | None = None) -> Normalized:
    """Normalise log-weights with ``logsumexp``, guarding degenerate sets.

    ``w̄_i = exp(ℓ_i − logsumexp(ℓ))``. If every ``ℓ_i`` is ``-inf`` or NaN the
    set is reset to uniform (``-log N`` each) and ``degenerate`` is True; the
    result never contains NaN.

    ``axis_name`` (inside ``jax.shard_map``): ``log_weights`` is this device's block of a vector
    spread over that mesh axis, normalised as the whole vector: ``m + log Σ_devices Σ exp(ℓ_i − m)``
    with ``m`` the whole vector's maximum (``pmax``, exact) and the devices' sums added (``psum``),
    which equals the one-device ``logsumexp`` up to the order of the additions.
    """
    lw = sanitize_log_weights(log_weights)
    # Subtract the max *before* the normaliser: with |ℓ| large (e.g. -1e30 as a
    # "masked" value) ``ℓ − logsumexp(ℓ)`` would lose the O(log N) term to
    # round-off (N equal weights of -1e30 would each get weight 1).
    top = jnp.max(jax.lax.stop_gradient(lw))  # a constant shift: no derivative (pmax has none)
    if axis_name is not None:
        top = jax.lax.pmax(top, axis_name)
    shift = jnp.where(jnp.isfinite(top), top, 0.0)
    lw = lw - shift
    if axis_name is None:
        log_norm = logsumexp(lw)
    else:
        log_norm = jnp.log(jax.lax.psum(jnp.sum(jnp.exp(lw)), axis_name))
    degenerate = ~jnp.isfinite(log_norm)
    n = lw.shape[-1] * (1 if axis_name is None else jax.lax.axis_size(axis_name))
    uniform = jnp.full_like(lw, -jnp.log(jnp.asarray(n, lw.dtype)))
    safe_norm = jnp.where(degenerate, 0.0, log_norm)
    normalized = jnp.where(degenerate, uniform, lw - safe_norm)
    return Normalized(normalized, jnp.where(degenerate, -jnp.inf, log_norm + shift), degenerate)


def log_ess(log_weights: jax.Array) -> jax.Array:
    """Log effective sample size, ``log ESS = 2·lse(ℓ) − lse(2ℓ)``.

    ESS = 1 / Σ w̄² ([A] App. B). Works on unnormalised log-weights; a set
    with a single finite entry has ESS 1, a uniform set has ESS N. A fully
    degenerate set returns ``-inf`` (ESS 0), never NaN.
    """
    # On normalised weights log ESS = −lse(2ℓ̄); computing 2·lse(ℓ) − lse(2ℓ) on the
    # raw input instead loses log N to round-off (or overflows) when |ℓ| is large.
    norm = normalize(log_weights)
    return jnp.where(norm.degenerate, -jnp.inf, -logsumexp(2.0 * norm.log_weights))


def ess(log_weights: jax.Array) -> jax.Array:
    """Effective sample size ``1 / Σ w̄²`` ([A] App. B), in ``[1, N]`` (0 if degenerate)."""
    return jnp.exp(log_ess(log_weights))


def log_marginal_increment(prev_log_weights: jax.Array, log_likelihoods: jax.Array) -> jax.Array:
    """Log of the incremental marginal likelihood ``p(z_t | z_{1:t-1})``.

    ``log Σ_i w̄_{t-1,i} · p(z_t | x_t^i)`` with ``w̄_{t-1}`` the *normalised*
    weights carried into the step. Using the previous weights (and not a plain
    mean of the likelihoods) keeps the estimate unbiased when resampling is
    conditional on the ESS: after a step without resampling the weights are not
    uniform.
    """
    prev = normalize(prev_log_weights).log_weights
    return logsumexp(prev + sanitize_log_weights(log_likelihoods))


def _weights(log_weights: jax.Array) -> jax.Array:
    return jnp.exp(normalize(log_weights).log_weights)


def weighted_mean(particles: jax.Array, log_weights: jax.Array) -> jax.Array:
    """Weighted mean ``Σ w̄_i x_i`` of ``particles [N, D]`` (Euclidean components)."""
    w = _weights(log_weights)
    return jnp.einsum("n,nd->d", w, particles)


def wrap_angle(angle: jax.Array) -> jax.Array:
    """Wrap angles to ``[-π, π)`` (rad): ``a − 2π·⌊(a + π)/2π⌋``, moved by ``2π`` where rounding put
    it just outside the interval.

    An angle already in ``[-π, π)`` is returned unchanged (``k = 0``, barring the last float below π).
    The floor form is used instead of ``(a + π) % 2π − π``: ``%`` lowers to a scalar ``fmod`` call on
    XLA:CPU, several times slower, and it moves in-range angles by a rounding of ``+π − π``.
    """
    wrapped = _wrap_angle_floor(angle)
    wrapped = jnp.where(wrapped >= jnp.pi, wrapped - _TWO_PI, wrapped)
    return jnp.where(wrapped < -jnp.pi, wrapped + _TWO_PI, wrapped)


def _wrap_angle_floor(angle: jax.Array) -> jax.Array:
    """``a − 2π·⌊(a + π)/2π⌋``: at the two ends the result may fall one rounding outside
    ``[-π, π)``. :func:`wrap_angle` corrects that; particle moments and draws, where it cannot
    matter, use this form directly."""
    return angle - _TWO_PI * jnp.floor((angle + jnp.pi) * (1.0 / _TWO_PI))


def circular_mean(angles: jax.Array, log_weights: jax.Array | None = None) -> jax.Array:
    """Weighted circular mean ``atan2(Σ w̄ sin a, Σ w̄ cos a)`` of ``angles [N, ...]`` (rad)."""
    if log_weights is None:
        w = jnp.full(angles.shape[:1], 1.0 / angles.shape[0], angles.dtype)
    else:
        w = _weights(log_weights)
    return _circular_mean_from_probabilities(angles, w)


def _circular_mean_from_probabilities(angles: jax.Array, probs: jax.Array, total=lambda x: x) -> jax.Array:
    """``atan2(Σ p sin a, Σ p cos a)`` over the leading axis of ``angles [N, ...]``; ``total`` completes
    each sum (a ``psum`` over devices when the particles are spread)."""
    s, c = fastmath.sincos(angles)
    return fastmath.atan2(total(jnp.tensordot(probs, s, 1)), total(jnp.tensordot(probs, c, 1)))


def particle_mean(particles: jax.Array, log_weights: jax.Array, angle_dims: tuple[int, ...] = ()) -> jax.Array:
    """Weighted mean of ``particles [N, D]`` with the ``angle_dims`` averaged on the circle.

    For a pose ``(x, y, θ)`` use ``angle_dims=(2,)``.
    """
    return mean_from_probabilities(particles, _weights(log_weights), angle_dims)


def mean_from_probabilities(
    particles: jax.Array, probs: jax.Array, angle_dims: tuple[int, ...] = (), axis_name: str | None = None
) -> jax.Array:
    """:func:`particle_mean` given normalised weights ``probs [N]`` (not logs), for filters
    that already hold them. Angle components: ``atan2(Σ p sin a, Σ p cos a)``.

    ``axis_name`` (inside ``jax.shard_map``): ``particles`` and ``probs`` are this device's block of
    particles spread over that mesh axis; the sums are taken over every device (``psum``: the same
    mean up to the order of the additions)."""
    total = (lambda x: x) if axis_name is None else (lambda x: jax.lax.psum(x, axis_name))
    mean = total(jnp.einsum("n,nd->d", probs, particles))
    if not angle_dims:
        return mean
    dims = jnp.asarray(angle_dims)
    return mean.at[dims].set(_circular_mean_from_probabilities(particles[:, dims], probs, total))


def ess_from_probabilities(probs: jax.Array, axis_name: str | None = None) -> jax.Array:
    """ESS ``1 / Σ p²`` ([A] App. B) of normalised weights ``probs [N]`` (not logs); with ``axis_name``
    (inside ``jax.shard_map``) ``probs`` is this device's block and the sum is over every device (``psum``)."""
    squares = jnp.sum(probs * probs)
    return 1.0 / (squares if axis_name is None else jax.lax.psum(squares, axis_name))


def step_ess(probs: jax.Array, degenerate: jax.Array, axis_name: str | None = None) -> jax.Array:
    """The ESS a filter step reports: ``1 / Σ p²`` of its normalised weights ``probs [N]``, 0 where the step
    was ``degenerate`` (see the module docstring); ``axis_name`` as in :func:`ess_from_probabilities`."""
    return jnp.where(degenerate, jnp.zeros((), probs.dtype), ess_from_probabilities(probs, axis_name))


def weighted_cov(
    particles: jax.Array,
    log_weights: jax.Array,
    angle_dims: tuple[int, ...] = (),
    mean: jax.Array | None = None,
) -> jax.Array:
    """Weighted covariance ``Σ w̄_i (x_i − μ)(x_i − μ)ᵀ`` of ``particles [N, D]``.

    Residuals of ``angle_dims`` are wrapped to ``[-π, π)`` around the circular
    mean, so a cloud straddling ±π gets a small variance, not ~π².
    This is the plug-in (biased) estimator, the one a Gaussian refresh needs.
    """
    w = _weights(log_weights)
    if mean is None:
        mean = mean_from_probabilities(particles, w, angle_dims)
    return cov_from_probabilities(particles, w, mean, angle_dims)


def cov_from_probabilities(
    particles: jax.Array, probs: jax.Array, mean: jax.Array, angle_dims: tuple[int, ...] = ()
) -> jax.Array:
    """:func:`weighted_cov` given normalised weights ``probs [N]`` and the mean (from
    :func:`mean_from_probabilities`), for filters that already hold both: ``(p ∘ r)ᵀ r``, one
    ``[D, N] × [N, D]`` product."""
    resid = particles - mean
    if angle_dims:
        resid = wrap_columns(resid, angle_dims)
    return (resid * probs[:, None]).T @ resid


def wrap_columns(x: jax.Array, angle_dims: tuple[int, ...]) -> jax.Array:
    """``x [..., D]`` with the components ``angle_dims`` wrapped to ``[-π, π)``, the others untouched.

    For particle moments and draws: only those columns are wrapped, and by ``floor``
    instead of the floating-point modulo (which is the most expensive operation of a
    particle set's moments on XLA:CPU); at the two ends a value may fall one rounding
    outside the interval."""
    for d in angle_dims:
        x = x.at[..., d].set(_wrap_angle_floor(x[..., d]))
    return x
