"""Redrawing a resampled particle set: the Gaussian refresh of [A] §4.3.3 and the regularised kernel refresh.

For a static target, resampled duplicates stay duplicates forever. A refresh
redraws the resampled set (:func:`~jaxnav.core.resampling.conditional_resample`
applies one with ``refresh=``):

* :func:`gaussian_refresh` — from the Gaussian fitted to the set, [A] §4.3.3
  (:func:`gaussian_draw` draws from given moments);
* :func:`kernel_refresh` — from a Gaussian kernel density of the set (the
  regularised particle filter, :func:`silverman_bandwidth`), which keeps several modes.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxnav.core import rng
from jaxnav.core import weights as _w

__all__ = [
    "REFRESHES",
    "gaussian_draw",
    "gaussian_refresh",
    "silverman_bandwidth",
    "kernel_refresh",
]

REFRESHES = ("gaussian", "kernel")
"""What :func:`~jaxnav.core.resampling.conditional_resample` may redraw the resampled set from (``refresh=``)."""


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
