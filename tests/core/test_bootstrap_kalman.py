"""A bootstrap particle filter built from jaxnav.core must estimate the exact
marginal likelihood of a linear-Gaussian model (Kalman filter oracle).

Model (scalar, t = 1 … T)::

    x_0 ~ N(m0, P0),   x_t = a x_{t−1} + N(0, q),   y_t = x_t + N(0, r).

The filter is written the way MCL (jaxnav.localization.mcl) is: propagate,
``norm = normalize(prev_normalised_log_weights + loglik)``, take
``norm.log_norm`` as the log-likelihood increment, then
``conditional_resample``. Its estimate ``Ẑ = Π_t Σ_i w̄_{t−1,i} p(y_t | x_t^i)``
is unbiased for ``Z = p(y_{1:T})`` whether resampling happens every step or
only when the ESS falls below a threshold (Del Moral 2004; Whiteley, Lee &
Heine 2016 for adaptive resampling).

How the comparison is made honest
---------------------------------
``log Ẑ`` is *not* unbiased for ``log Z``: by Jensen it is biased downward,
by about ``σ²/2`` where ``σ² = Var(log Ẑ)`` (the CLT for ``log Ẑ``). So we
test the unbiased quantity. With ``R`` independent filters, ``ρ_r = Ẑ_r / Z``
are i.i.d. with mean 1 (and finite variance, ``≈ e^{σ²} − 1``), so

    z = (mean(ρ) − 1) / (sd(ρ)/√R)

is approximately standard normal; we require ``|z| < 5`` (false-alarm
probability ≈ 6e-7 under the CLT). N = 1000 keeps ``sd(log Ẑ)`` near 0.65
for this model, so ``ρ`` is only moderately skewed (lognormal-like, skewness
of ``mean(ρ)`` ≈ 0.2 at R = 200) and its sample sd is a usable SE; the
margin of 5 SE covers what is left of the skew. ``mean(ρ)`` is computed
stably as ``exp(logsumexp(log Ẑ_r − log Z) − log R)``. As a second,
asymptotic check, ``mean(log Ẑ)`` must equal ``log Z − σ²/2`` within 5 SE.

The negative control computes the increment as the *plain mean* of the
likelihoods, ``log (1/N) Σ_i p(y_t | x_t^i)``, which ignores the non-uniform
weights carried over a step without resampling. On the same particle
trajectories it must fail the same criterion under ESS-conditional
resampling (this shows the test has power), and coincide with the correct
estimator when resampling every step (weights are then uniform).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.special import logsumexp as np_logsumexp

from jaxnav.core import conditional_resample, normalize

A, Q, RV = 0.9, 1.0, 1.0  # transition coefficient, process and observation noise variances
M0, P0 = 0.0, 2.0  # initial state mean and variance
T = 50  # time steps
N = 1000  # particles per filter (Var(log Ẑ) ≈ 0.4 here, see module docstring)
R = 200  # independent filters
Z_MAX = 5.0  # |z| bound of the statistical check
EPS32 = float(np.finfo(np.float32).eps)


def _simulate(seed: int = 20240607) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x = M0 + math.sqrt(P0) * rng.standard_normal()
    ys = np.empty(T)
    for t in range(T):
        x = A * x + math.sqrt(Q) * rng.standard_normal()
        ys[t] = x + math.sqrt(RV) * rng.standard_normal()
    return ys


def kalman_log_marginal(ys: np.ndarray) -> float:
    """Exact ``log p(y_{1:T})`` by the Kalman filter (NumPy, float64)."""
    m, p, total = M0, P0, 0.0
    for y in ys:
        m, p = A * m, A * A * p + Q  # predict
        s = p + RV  # innovation variance
        total += -0.5 * (math.log(2 * math.pi * s) + (y - m) ** 2 / s)
        gain = p / s
        m, p = m + gain * (y - m), (1 - gain) * p  # update
    return total


@jax.jit
def _particle_filters(keys, ys, threshold):
    """``R`` bootstrap filters (vmapped over ``keys``); returns per filter the
    correct and the buggy (plain-mean) ``log Ẑ`` and the fraction of steps resampled."""

    def one(key):
        k0, k_steps = jax.random.split(key)
        x = M0 + math.sqrt(P0) * jax.random.normal(k0, (N,))
        lw = jnp.full((N,), -math.log(N))

        def step(carry, inp):
            x, lw = carry
            t, y = inp
            k_move, k_res = jax.random.split(jax.random.fold_in(k_steps, t))
            x = A * x + math.sqrt(Q) * jax.random.normal(k_move, (N,))
            loglik = -0.5 * (jnp.log(2 * jnp.pi * RV) + (y - x) ** 2 / RV)
            norm = normalize(lw + loglik)  # lw is normalised: log_norm = log Σ w̄ p(y|x)
            buggy = jax.scipy.special.logsumexp(loglik) - math.log(N)  # ignores lw
            res = conditional_resample(k_res, x, norm.log_weights, threshold)
            return (res.particles, res.log_weights), (norm.log_norm, buggy, res.resampled)

        _, (inc, inc_buggy, resampled) = jax.lax.scan(step, (x, lw), (jnp.arange(T), ys))
        return jnp.sum(inc), jnp.sum(inc_buggy), jnp.mean(resampled.astype(jnp.float32))

    return jax.vmap(one)(keys)


def _z_score(log_z_hat: np.ndarray, log_z: float) -> float:
    """z-statistic of the hypothesis E[Ẑ/Z] = 1 from R i.i.d. estimates."""
    d = np.asarray(log_z_hat, np.float64) - log_z
    mean_ratio = math.exp(np_logsumexp(d) - math.log(d.size))
    ratio = np.exp(d)  # d is O(0.1–1) here: no overflow
    se = np.std(ratio, ddof=1) / math.sqrt(d.size)
    return (mean_ratio - 1.0) / se


@pytest.fixture(scope="module")
def data():
    ys = _simulate()
    return ys, kalman_log_marginal(ys)


@pytest.mark.slow
@pytest.mark.parametrize("threshold", [1.0, 0.5], ids=["resample-always", "ess-conditional"])
def test_pf_log_marginal_matches_kalman(threshold, data, getkey):
    ys, log_z = data
    keys = jax.random.split(getkey(), R)
    log_z_hat, log_z_buggy, frac = map(np.asarray, _particle_filters(keys, jnp.asarray(ys, jnp.float32), threshold))
    assert np.all(np.isfinite(log_z_hat))

    # The estimator is unbiased for Z: E[Ẑ/Z] = 1 within Monte Carlo error.
    z = _z_score(log_z_hat, log_z)
    assert abs(z) < Z_MAX, dict(z=z, log_z=log_z, mean_log_z_hat=log_z_hat.mean(), sd=log_z_hat.std())

    # Consistency with the CLT for log Ẑ: mean(log Ẑ) ≈ log Z − σ²/2 (5 SE of
    # the mean, SE = σ/√R). Only a sanity check of the bias explanation.
    sigma2 = log_z_hat.var(ddof=1)
    assert abs(log_z_hat.mean() - (log_z - sigma2 / 2)) < Z_MAX * math.sqrt(sigma2 / R)

    if threshold >= 1.0:
        assert np.all(frac == 1.0)
        # After resampling every step the carried weights are uniform, so the
        # plain mean *is* the right increment: both estimators coincide.
        # Tolerance: float32 round-off accumulated over T increments
        # (≤ 8 eps relative each, recursive-summation bound).
        np.testing.assert_allclose(log_z_buggy, log_z_hat, rtol=8 * T * EPS32)
    else:
        # The ESS rule skipped resampling in a good share of the steps ...
        assert 0.1 < frac.mean() < 0.9, frac.mean()
        # ... and there the plain-mean increment is wrong: the same criterion
        # must reject it (the test has power).
        z_bug = _z_score(log_z_buggy, log_z)
        assert abs(z_bug) > Z_MAX, dict(z_bug=z_bug, mean_log_z_buggy=log_z_buggy.mean(), log_z=log_z)
