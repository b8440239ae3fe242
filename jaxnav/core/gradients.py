"""How gradients pass a resampling step: the three estimators a particle filter can use.

A particle filter's log marginal-likelihood estimate ``log Ẑ = Σ_t log Σ_i w̄_{t−1,i} p(z_t | x_t^i)``
is differentiable in the parameters θ everywhere except at resampling, whose ancestors are
integers. What a filter does there decides which gradient ``jax.grad`` of ``log Ẑ`` computes.
The particles themselves are reparameterised (a motion draw is ``f(x, u) + σ·ε`` with ``ε``
drawn from the key), so gradients pass the moves pathwise in all three.

``"score"`` (the default): stop-gradient resampling (Ścibior & Wood 2021, "Differentiable
    particle filtering without modifying the forward pass"). After resampling, particle ``i``
    (ancestor ``a_i``) carries the log-weight ``−log N + ℓ̄_{a_i} − ⊥(ℓ̄_{a_i})``, ``ℓ̄`` the
    normalised log-weights and ``⊥`` the stop-gradient: the value is ``−log N`` as before, so
    the forward pass is unchanged bit for bit, and the derivative carries ``∇ log w̄_{a_i}``, the
    score of the selection, into every later increment. ``∇Ẑ`` is then an unbiased estimate of
    ``∇Z`` with multinomial resampling and no refresh (the other schemes' ancestors are not
    independent draws, and the same correction treats them as if they were: with systematic
    resampling it passed the same z-test in ``tests/core/test_gradient_estimators.py``; a
    Gaussian or kernel refresh redraws the particles the correction is attached to), and ``∇ log Ẑ = ∇Ẑ / Ẑ`` a consistent
    estimate of the score ``∇ log p(z_{1:T} | θ)`` — Fisher's identity over the particles'
    genealogy (Poyiadjis, Doucet & Singh 2011), whose variance grows with the length of the run.
``"soft"``: soft resampling (Karkus, Hsu & Lee 2018). Ancestors are drawn from the mixture
    ``q = α w̄ + (1 − α)/N`` and carry the importance weights ``w̄_{a_i} / q_{a_i}`` (normalised),
    with gradients through both. This changes the forward pass (the weights after resampling are
    not uniform, and the ESS after resampling is lower); it is biased (no gradient reaches the
    choice of ancestors), less so as ``α`` falls: ``α = 1`` is plain resampling with zero
    gradient through the weights, ``α = 0`` draws ancestors uniformly (importance weights
    ``N w̄``, the least biased and the noisiest).
``"naive"``: the weights after resampling are the constant ``−log N``: resampling is treated as
    independent of θ. Biased: the gradient misses every term by which θ moved the ancestors,
    and the bias does not vanish with N. Kept as the documented baseline (what jaxnav's filters
    computed before the estimators were selectable).
"""

from __future__ import annotations

import numbers
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import weights as _w

__all__ = ["GRADIENT_ESTIMATORS", "check_gradient", "selection_score", "soft_proposal", "soft_carried_log_weights"]

GRADIENT_ESTIMATORS = ("score", "soft", "naive")
"""The gradient estimators through resampling, by name (module docstring)."""


def check_gradient(gradient: Any, soft_mixing: Any) -> None:
    """Refuse an unknown estimator name or a mixing weight outside ``[0, 1]``, naming the field."""
    if not isinstance(gradient, str) or gradient not in GRADIENT_ESTIMATORS:
        raise ValueError(f"gradient must be one of {list(GRADIENT_ESTIMATORS)}, got {gradient!r}")
    real = isinstance(soft_mixing, (numbers.Real, np.floating)) and not isinstance(soft_mixing, (bool, np.bool_))
    if not real or not 0.0 <= float(soft_mixing) <= 1.0:
        raise ValueError(f"soft_mixing must be a number in [0, 1], got {soft_mixing!r}")


def selection_score(selected_log_weights: jax.Array) -> jax.Array:
    """``ℓ̄_a − ⊥(ℓ̄_a)`` of the ancestors' normalised log-weights ``ℓ̄_a [M]``: zero in value,
    ``∇ ℓ̄_a`` in derivative (stop-gradient resampling).

    A log-weight that is not finite (a zero-weight particle, which the exact resamplers never draw)
    counts as zero, so the value is an exact zero everywhere and never NaN (``−∞ − (−∞)``).
    """
    finite = jnp.where(jnp.isfinite(selected_log_weights), selected_log_weights, 0.0)
    return finite - jax.lax.stop_gradient(finite)


def soft_proposal(log_weights: jax.Array, soft_mixing: float) -> jax.Array:
    """``log q`` with ``q = α w̄ + (1 − α)/N``, for normalised ``log_weights [N]`` (α = ``soft_mixing``).

    A particle of zero weight (``−∞``) gets ``log((1 − α)/N)``, ``−∞`` when ``α = 1``, with a zero
    derivative (never NaN).
    """
    n = log_weights.shape[0]
    dtype = log_weights.dtype
    finite = jnp.isfinite(log_weights)
    log_alpha = jnp.log(jnp.asarray(soft_mixing, dtype))
    log_rest = jnp.log(jnp.asarray(1.0 - soft_mixing, dtype)) - jnp.log(jnp.asarray(n, dtype))
    mixed = jnp.logaddexp(log_alpha + jnp.where(finite, log_weights, 0.0), log_rest)
    return jnp.where(finite, mixed, log_rest)


def soft_carried_log_weights(log_weights: jax.Array, log_proposal: jax.Array, ancestors: jax.Array) -> jax.Array:
    """The normalised log importance weights ``log(w̄_a / q_a) − logsumexp(·)`` of soft resampling.

    An ancestor of zero weight (drawn from the uniform part of ``q`` when ``α < 1``) carries zero
    weight. With a small ``α`` every ancestor of a step can be one (with N = 64, one particle of
    positive weight and ``α = 0``, about 37 % of the multinomial draws); the carried weights are then
    reset to uniform, as :func:`jaxnav.core.weights.normalize` does with a degenerate set, and a
    filter's step reports it in ``info.degenerate`` (:func:`jaxnav.core.particle_filter.finish_step`).
    """
    picked = jnp.take(log_weights, ancestors, axis=0, mode="clip")
    finite = jnp.isfinite(picked)
    ratio = jnp.where(finite, picked, 0.0) - jnp.take(log_proposal, ancestors, axis=0, mode="clip")
    return _w.normalize(jnp.where(finite, ratio, -jnp.inf)).log_weights
