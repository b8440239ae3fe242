"""The gradient estimators through resampling (jaxnav.core.gradients), against the exact score of a
linear-Gaussian model.

Model (dimension D, t = 1 … T)::

    x_0 ~ N(0, 2 I),   x_t = A(a) x_{t−1} + N(0, q I),   y_t = x_t + N(0, r I),

with ``A(a) = (a / 0.9) A₀`` (A₀ = 0.9 I plus a small rotation) and θ = (a, log q, log r). The Kalman
filter gives ``log Z(θ) = log p(y_{1:T} | θ)`` exactly, and ``jax.grad`` its score.

A bootstrap particle filter built from the library's step tail (:func:`finish_step`, whose
resampling carries the estimator) returns ``log Ẑ`` and, by ``jax.grad``, ``g = ∇ log Ẑ``. With
stop-gradient resampling ``∇Ẑ`` is unbiased for ``∇Z``, so with ``ρ = Ẑ / Z`` the products
``ρ g = ∇Ẑ / Z`` over R independent filters have mean ``∇ log Z``: a z-test per component,
``|z| < 5`` (as tests/core/test_bootstrap_kalman.py tests ``E[ρ] = 1``; N = 1000 keeps
``sd(log Ẑ)`` at 0.2–0.6 here, so ``ρ`` is only mildly skewed). The naive estimator (uniform weights
after resampling, no derivative) must fail the same test: it misses how θ moved the ancestors.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.core import weights
from jaxnav.core.particle_filter import finish_step

N = 1000  # particles
R = 200  # independent filters
Z_MAX = 5.0
THETA = np.array([0.9, 0.0, 0.0])  # a, log q, log r


def _transition(dim: int) -> np.ndarray:
    return 0.9 * np.eye(dim) + 0.05 * (np.eye(dim, k=1) - np.eye(dim, k=-1))


def _simulate(dim: int, steps: int, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    a0 = _transition(dim)
    x = rng.standard_normal(dim) * math.sqrt(2.0)
    ys = []
    for _ in range(steps):
        x = a0 @ x + rng.standard_normal(dim)
        ys.append(x + rng.standard_normal(dim))
    return np.asarray(ys)


def _model(theta, dim):
    return theta[0] / 0.9 * jnp.asarray(_transition(dim), theta.dtype), jnp.exp(theta[1]), jnp.exp(theta[2])


def _kalman_log_likelihood(theta, ys):
    dim = ys.shape[-1]
    a, q, r = _model(theta, dim)
    eye = jnp.eye(dim, dtype=theta.dtype)

    def step(carry, y):
        m, p = carry
        m, p = a @ m, a @ p @ a.T + q * eye
        s = p + r * eye
        gain = p @ jnp.linalg.inv(s)
        return (m + gain @ (y - m), (eye - gain) @ p), jax.scipy.stats.multivariate_normal.logpdf(y, m, s)

    _, lls = jax.lax.scan(step, (jnp.zeros(dim, theta.dtype), 2.0 * eye), ys)
    return jnp.sum(lls)


def _pf_log_likelihood(theta, key, ys, threshold, gradient, scheme):
    dim = ys.shape[-1]
    a, q, r = _model(theta, dim)
    k0, k_steps = jax.random.split(key)
    x = math.sqrt(2.0) * jax.random.normal(k0, (N, dim))
    lw = jnp.full((N,), -math.log(N))

    def step(carry, inp):
        x, lw = carry
        t, y = inp
        k_move, k_res = jax.random.split(jax.random.fold_in(k_steps, t))
        x = x @ a.T + jnp.sqrt(q) * jax.random.normal(k_move, (N, dim))
        loglik = -0.5 * (dim * jnp.log(2 * jnp.pi * r) + jnp.sum((y - x) ** 2, -1) / r)
        norm = weights.normalize(lw + loglik)
        res, info = finish_step(k_res, x, norm, threshold=threshold, scheme=scheme, gradient=gradient)
        return (res.particles, res.log_weights), (info.log_likelihood, info.resampled)

    _, (increments, resampled) = jax.lax.scan(step, (x, lw), (jnp.arange(ys.shape[0]), ys))
    return jnp.sum(increments), jnp.mean(resampled.astype(jnp.float32))


# Compiled with XLA's backend optimisation at level 1, not the suite's compile-fast level 0
# (tests/conftest.py): 200 filters of 1000 particles run about 5 times faster so. Level 1 runs them
# about as fast as the default level 3 (within 0.5 s a case, on a 2-core CPU) and compiles in half its
# time (4 s against 8 s); the compiler's options change no value beyond a float's last bits.
_filters = jax.jit(
    jax.vmap(jax.value_and_grad(_pf_log_likelihood, has_aux=True), (None, 0, None, None, None, None)),
    static_argnums=(3, 4, 5),
    compiler_options={"xla_backend_optimization_level": 1},
)
_kalman = jax.jit(jax.value_and_grad(_kalman_log_likelihood))


@functools.cache
def _exact(dim: int, steps: int) -> tuple[np.ndarray, float, np.ndarray]:
    """The data, ``log Z`` and the score at θ (float64): one compiled Kalman filter per shape,
    shared by the cases of that shape."""
    ys = _simulate(dim, steps)
    with jax.enable_x64(True):
        log_z, score = _kalman(jnp.asarray(THETA), jnp.asarray(ys))
        return ys, float(log_z), np.asarray(score)


def _z_scores(dim, steps, threshold, gradient, scheme, key):
    ys, log_z, score = _exact(dim, steps)
    keys = jax.random.split(key, R)
    (log_z_hat, frac), g = _filters(
        jnp.asarray(THETA, jnp.float32), keys, jnp.asarray(ys, jnp.float32), threshold, gradient, scheme
    )
    log_z_hat, g = np.asarray(log_z_hat, np.float64), np.asarray(g, np.float64)
    assert np.all(np.isfinite(log_z_hat)) and np.all(np.isfinite(g))
    products = np.exp(log_z_hat - log_z)[:, None] * g
    z = (products.mean(0) - score) / (products.std(0, ddof=1) / math.sqrt(R))
    return z, float(np.mean(frac)), score, g.mean(0)


CASES = [
    pytest.param(1, 50, 1.0, "multinomial", id="1d-resample-always"),
    pytest.param(1, 50, 0.5, "multinomial", id="1d-ess-conditional"),
    pytest.param(1, 50, 0.5, "systematic", id="1d-ess-conditional-systematic"),
    pytest.param(4, 20, 1.0, "multinomial", id="4d-resample-always"),
]


@pytest.mark.slow
@pytest.mark.parametrize(("dim", "steps", "threshold", "scheme"), CASES)
def test_score_estimator_matches_the_kalman_score(dim, steps, threshold, scheme, getkey):
    z, frac, score, mean_g = _z_scores(dim, steps, threshold, "score", scheme, getkey())
    if threshold < 1.0:
        assert 0.1 < frac < 0.9, frac  # the ESS rule skipped resampling at some steps
    assert np.all(np.abs(z) < Z_MAX), dict(z=z, score=score, mean_gradient=mean_g)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("dim", "steps", "threshold", "scheme"),
    [CASES[1], CASES[3]],
)
def test_naive_gradient_fails_the_same_test(dim, steps, threshold, scheme, getkey):
    """The negative control: resampling treated as constant is biased, and the z-test sees it."""
    z, _, score, mean_g = _z_scores(dim, steps, threshold, "naive", scheme, getkey())
    assert np.max(np.abs(z)) > Z_MAX, dict(z=z, score=score, mean_gradient=mean_g)
