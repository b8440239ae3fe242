"""Tests of jaxnav.core.weights: normalisation, ESS, moments, marginal increments.

Reference values are computed in float64 NumPy/SciPy from the *same* float32
inputs the library sees, so the only tolerance needed is float32 round-off
(a few ulps of the quantities involved).
"""

from __future__ import annotations

import math

import hypothesis.extra.numpy as hnp
import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from scipy.special import logsumexp as np_logsumexp

from jaxnav.core import weights as _W

EPS32 = float(np.finfo(np.float32).eps)


class W:
    """The functions under test, jitted: one XLA compilation per function and
    input shape instead of one per primitive in eager mode (keeps the suite fast)."""

    normalize = staticmethod(jax.jit(_W.normalize))
    ess = staticmethod(jax.jit(_W.ess))
    log_ess = staticmethod(jax.jit(_W.log_ess))
    log_marginal_increment = staticmethod(jax.jit(_W.log_marginal_increment))
    weighted_mean = staticmethod(jax.jit(_W.weighted_mean))
    weighted_cov = staticmethod(jax.jit(_W.weighted_cov, static_argnames="angle_dims"))
    particle_mean = staticmethod(jax.jit(_W.particle_mean, static_argnames="angle_dims"))
    circular_mean = staticmethod(jax.jit(_W.circular_mean))
    wrap_angle = staticmethod(jax.jit(_W.wrap_angle))


@jax.jit
def _summary(log_weights):
    """Everything the edge-case tests inspect, in one compilation per shape.

    The moments use the particles ``x_i = i`` (``[N, 1]``)."""
    n = log_weights.shape[0]
    norm = _W.normalize(log_weights)
    particles = jnp.arange(n, dtype=jnp.float32)[:, None]
    return dict(
        log_weights=norm.log_weights,
        log_norm=norm.log_norm,
        degenerate=norm.degenerate,
        lse_normalized=jax.scipy.special.logsumexp(norm.log_weights),
        log_ess=_W.log_ess(log_weights),
        ess=_W.ess(log_weights),
        mean=_W.weighted_mean(particles, log_weights)[0],
        cov=_W.weighted_cov(particles, log_weights)[0, 0],
        increment_from_uniform=_W.log_marginal_increment(jnp.zeros(n), log_weights),
    )


def _rng(request) -> np.random.Generator:
    """Test data from NumPy (no XLA compilation), seeded per test for reproducibility."""
    return np.random.default_rng(request.getfixturevalue("test_seed"))


def _np_probs(log_weights) -> np.ndarray:
    """Normalised weights in float64 (NaN/+inf treated as -inf, as the library does)."""
    lw = np.asarray(log_weights, np.float64)
    lw = np.where(np.isnan(lw) | (lw == np.inf), -np.inf, lw)
    top = np.max(lw)
    lw = lw - (top if np.isfinite(top) else 0.0)  # exact for nearby values; keeps the O(log N) term
    return np.exp(lw - np_logsumexp(lw))


# --------------------------------------------------------------------------- normalize


def test_normalize_matches_logsumexp(request):
    lw = (10.0 * _rng(request).standard_normal(50) - 300.0).astype(np.float32)
    norm = W.normalize(lw)
    expected_norm = np_logsumexp(np.asarray(lw, np.float64))
    np.testing.assert_allclose(float(norm.log_norm), expected_norm, rtol=4 * EPS32)
    np.testing.assert_allclose(float(jax.scipy.special.logsumexp(norm.log_weights)), 0.0, atol=1e-5)
    np.testing.assert_allclose(np.exp(np.asarray(norm.log_weights, np.float64)), _np_probs(lw), rtol=1e-4, atol=1e-7)
    assert not bool(norm.degenerate)


def test_normalize_is_shift_invariant(request):
    lw = _rng(request).standard_normal(20).astype(np.float32)
    a = W.normalize(lw).log_weights
    b = W.normalize(lw + 1234.5).log_weights
    # Forming lw + c in float32 rounds each entry by ≤ ulp(1240)/2; the
    # normalised value differs of two such entries (entry and max), plus a few
    # ulps of O(1) numbers: 2·ulp(1240) bounds it.
    np.testing.assert_allclose(a, b, atol=2 * float(np.spacing(np.float32(1240.0))))


def test_single_nonzero_weight_has_ess_one():
    lw = np.full(8, -np.inf, np.float32)
    lw[3] = -17.25
    out = _summary(lw)
    expected = np.full(8, -np.inf)
    expected[3] = 0.0
    np.testing.assert_array_equal(out["log_weights"], expected)
    assert float(out["log_norm"]) == -17.25
    assert not bool(out["degenerate"])
    assert float(out["ess"]) == pytest.approx(1.0, rel=4 * EPS32)
    assert float(out["log_ess"]) == pytest.approx(0.0, abs=4 * EPS32)
    assert float(out["mean"]) == 3.0 and float(out["cov"]) == 0.0


@pytest.mark.parametrize("n", [1, 2, 7, 1000])
@pytest.mark.parametrize("value", [0.0, -3.5, 80.0, -80.0, 1e6, -1e30])
def test_equal_weights_have_ess_n(n, value):
    """A uniform set has ESS N whatever the common (unnormalised) log-weight.

    The module documents that ESS "works on unnormalised log-weights"; a
    common value of -1e30 or 1e6 is exactly representable in float32, so the
    input really is uniform and the answer must be N, not 1 — and its weights
    must sum to 1, not N.
    """
    out = _summary(np.full(n, value, np.float32))
    # Every quantity below is O(log N) once the common value is factored out,
    # so float32 round-off of a few ulps of max(1, log N) is the tolerance.
    tol = 4 * EPS32 * max(1.0, math.log(n))
    np.testing.assert_allclose(out["log_weights"], np.full(n, -math.log(n)), rtol=0, atol=tol)
    assert float(out["lse_normalized"]) == pytest.approx(0.0, abs=tol)
    assert float(out["log_norm"]) == pytest.approx(np.float32(value) + math.log(n), rel=4 * EPS32, abs=tol)
    assert float(out["log_ess"]) == pytest.approx(math.log(n), abs=tol)
    assert float(out["ess"]) == pytest.approx(n, rel=2 * tol)
    # Moments are those of the uniform set on 0..N-1 (not scaled by N).
    assert float(out["mean"]) == pytest.approx((n - 1) / 2, rel=2 * tol, abs=tol)
    assert float(out["cov"]) == pytest.approx((n * n - 1) / 12, rel=8 * tol, abs=tol)


def test_neg_inf_entries_get_zero_weight():
    out = _summary(np.array([0.0, -np.inf, 0.0, -np.inf, 0.0], np.float32))
    np.testing.assert_allclose(np.exp(out["log_weights"]), [1 / 3, 0, 1 / 3, 0, 1 / 3], rtol=1e-6)
    assert float(out["ess"]) == pytest.approx(3.0, rel=1e-6)
    assert float(out["mean"]) == pytest.approx(2.0, rel=1e-6)
    assert not bool(out["degenerate"])


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_nan_and_posinf_are_treated_as_neg_inf(bad):
    base = np.array([0.3, -1.0, 2.0, -0.5, 1.0], np.float32)
    with_bad = base.copy()
    with_neg_inf = base.copy()
    with_bad[[1, 3]] = bad
    with_neg_inf[[1, 3]] = -np.inf
    a, b = _summary(with_bad), _summary(with_neg_inf)
    for name in a:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    assert not bool(a["degenerate"])
    assert not np.any(np.isnan(np.asarray(a["log_weights"])))
    np.testing.assert_allclose(np.exp(a["log_weights"]), _np_probs(with_bad), rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize(
    "lw",
    [
        np.full(6, -np.inf),
        np.full(6, np.nan),
        np.array([-np.inf, np.nan, np.inf, -np.inf, np.nan, -np.inf]),
        np.array([-np.inf]),
    ],
    ids=["all-neg-inf", "all-nan", "mixed", "single-neg-inf"],
)
def test_degenerate_set_resets_to_uniform(lw):
    n = lw.shape[0]
    out = _summary(lw.astype(np.float32))
    assert bool(out["degenerate"])
    np.testing.assert_allclose(out["log_weights"], np.full(n, -math.log(n)), rtol=1e-6)
    assert not np.any(np.isnan(np.asarray(out["log_weights"])))
    assert float(out["log_norm"]) == -np.inf
    assert float(out["log_ess"]) == -np.inf
    assert float(out["ess"]) == 0.0
    # Moments of a degenerate set are those of the uniform set, never NaN.
    assert float(out["mean"]) == pytest.approx((n - 1) / 2, rel=1e-6)
    assert float(out["cov"]) == pytest.approx((n * n - 1) / 12, rel=1e-5, abs=1e-7)
    # A log-marginal increment with zero total likelihood is -inf, not NaN.
    assert float(out["increment_from_uniform"]) == -np.inf


_SPECIAL = [-np.inf, np.nan, np.inf, 0.0, 80.0, -80.0, -1e30, 1e30, 3e38, -3e38]
_log_weight_elements = st.one_of(
    st.floats(width=32),  # anything, NaN and ±inf included
    st.floats(-100.0, 100.0, width=32),
    st.sampled_from([float(np.float32(v)) for v in _SPECIAL]),
)


@settings(max_examples=50, deadline=None)
@given(hnp.arrays(np.float32, st.sampled_from([1, 5, 32]), elements=_log_weight_elements))
def test_ess_bounds_property(lw):
    """For any float32 input: 1 ≤ ESS ≤ N when some entry is finite, ESS = 0 otherwise.

    The reference ESS is computed in float64 from the float32 input. Error
    budget of the float32 value: a shifted log-weight ``d = ℓ_i − max ℓ`` is
    rounded by ≤ |d|·eps/2, i.e. a relative weight error ≤ 45 eps for every
    weight that matters (|d| ≲ 90; smaller weights underflow harmlessly), so
    ``Σ w̄²`` errs by ≤ 2·45 eps plus ≈ N eps of summation; ``(200 + 8N)·eps``
    bounds it with room to spare.
    """
    n = lw.shape[0]
    ess = float(W.ess(jnp.asarray(lw)))
    sane = np.where(np.isnan(lw) | (lw == np.inf), -np.inf, lw)
    if not np.any(np.isfinite(sane)):
        assert ess == 0.0
        return
    tol = (200 + 8 * n) * EPS32
    expected = 1.0 / np.sum(_np_probs(lw) ** 2)
    assert 1.0 - tol <= ess <= n * (1.0 + tol)
    assert ess == pytest.approx(expected, rel=tol)


# --------------------------------------------------------------------------- moments


def test_weighted_mean_and_cov_match_numpy(request):
    n, d = 200, 3
    rng = _rng(request)
    particles = (rng.standard_normal((n, d)) * [1.0, 5.0, 0.1] + [2.0, -1.0, 0.5]).astype(np.float32)
    lw = (2.0 * rng.standard_normal(n) - 40.0).astype(np.float32)
    x = np.asarray(particles, np.float64)
    p = _np_probs(lw)
    mean = np.average(x, axis=0, weights=p)
    cov = np.cov(x, rowvar=False, aweights=p, bias=True)
    np.testing.assert_allclose(W.weighted_mean(particles, lw), mean, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(W.weighted_cov(particles, lw), cov, rtol=1e-4, atol=1e-5)
    # With no angle dims, particle_mean is the Euclidean weighted mean.
    np.testing.assert_allclose(W.particle_mean(particles, lw), mean, rtol=1e-5, atol=1e-5)


def test_circular_mean_across_pi():
    """3.1 and -3.1 rad are 0.083 rad apart across ±π: their mean is ≈ π, not 0."""
    mean = float(W.circular_mean(jnp.array([3.1, -3.1])))
    assert abs(abs(mean) - math.pi) < 1e-5
    # Weighted: three quarters of the mass at 3.1 pulls the mean towards +3.1.
    lw = jnp.log(jnp.array([0.75, 0.25]))
    a = np.array([3.1, -3.1])
    expected = math.atan2(0.75 * math.sin(a[0]) + 0.25 * math.sin(a[1]), 0.75 * math.cos(a[0]) + 0.25 * math.cos(a[1]))
    assert float(W.circular_mean(jnp.asarray(a, jnp.float32), lw)) == pytest.approx(expected, abs=1e-5)
    assert 3.1 < expected < math.pi


def test_particle_mean_averages_angle_dims_on_circle():
    particles = jnp.array([[1.0, 10.0, 3.1], [3.0, 20.0, -3.1]])
    lw = jnp.zeros(2)
    mean = np.asarray(W.particle_mean(particles, lw, angle_dims=(2,)))
    np.testing.assert_allclose(mean[:2], [2.0, 15.0], rtol=1e-6)
    assert abs(abs(mean[2]) - math.pi) < 1e-5


def test_weighted_cov_wraps_angle_residuals(request):
    """A heading cloud straddling ±π has the small spread of its unwrapped values."""
    n = 500
    rng = _rng(request)
    delta = 0.05 * rng.standard_normal(n)
    xy = (rng.standard_normal(n) + 0.3 * delta / 0.05).astype(np.float32)
    theta = np.asarray(W.wrap_angle(jnp.asarray(np.pi + delta, jnp.float32)))  # straddles the ±π cut
    particles = np.stack([xy, theta], axis=1)
    lw = rng.standard_normal(n).astype(np.float32)
    assert np.any(np.asarray(theta) > 3.0) and np.any(np.asarray(theta) < -3.0)
    p = _np_probs(lw)
    # Reference: the same angles unwrapped to [0, 2π), where the cloud is contiguous.
    unwrapped = np.stack([np.asarray(xy, np.float64), np.mod(np.asarray(theta, np.float64), 2 * np.pi)], 1)
    expected = np.cov(unwrapped, rowvar=False, aweights=p, bias=True)
    cov = np.asarray(W.weighted_cov(particles, lw, angle_dims=(1,)))
    np.testing.assert_allclose(cov, expected, rtol=1e-3, atol=1e-6)
    assert cov[1, 1] < 0.01  # not ~π²
    # Without angle_dims the raw residuals give a variance near π².
    assert float(W.weighted_cov(particles, lw)[1, 1]) > 5.0


def test_wrap_angle_range():
    a = jnp.linspace(-20.0, 20.0, 4001)
    w = np.asarray(W.wrap_angle(a), np.float64)
    assert np.all(w >= -np.pi) and np.all(w < np.pi + 1e-6)
    # the floor form used for particle moments: inside up to one rounding at the ends, same point on the circle
    for dtype in (np.float32, np.float64):
        with jax.enable_x64(dtype == np.float64):
            pi = dtype(np.pi)
            ends = np.array(
                [
                    pi,
                    -pi,
                    np.nextafter(pi, dtype(0)),
                    np.nextafter(-pi, dtype(0)),
                    np.nextafter(pi, dtype(4)),
                    np.nextafter(-pi, dtype(-4)),
                    3 * pi,
                    -3 * pi,
                    0.0,
                    20.0,
                    -20.0,
                ],
                dtype,
            )
            e = np.asarray(jax.jit(_W.wrap_columns, static_argnums=1)(jnp.asarray(ends)[:, None], (0,)), np.float64)[
                :, 0
            ]
            ulp = float(np.spacing(pi))
            assert np.all(e >= -np.pi - 2 * ulp) and np.all(e <= np.pi + 2 * ulp), e
            np.testing.assert_allclose(np.exp(1j * e), np.exp(1j * ends.astype(np.float64)), atol=100 * ulp)
            w = np.asarray(W.wrap_angle(jnp.asarray(ends)), np.float64)
            np.testing.assert_allclose(np.exp(1j * e), np.exp(1j * w), atol=100 * ulp)


# --------------------------------------------------------------------------- marginal increment


def test_log_marginal_increment_matches_float64(request):
    n = 300
    rng = _rng(request)
    prev = (3.0 * rng.standard_normal(n) + 17.0).astype(np.float32)  # unnormalised on purpose
    loglik = (5.0 * rng.standard_normal(n) - 50.0).astype(np.float32)
    p = _np_probs(prev)
    expected = np_logsumexp(np.asarray(loglik, np.float64), b=p)  # log Σ w̄_prev · lik
    got = float(W.log_marginal_increment(prev, loglik))
    assert got == pytest.approx(expected, abs=1e-4 * max(1.0, abs(expected)))
    # It is *not* the log of the plain mean of the likelihoods (weights matter).
    plain = np_logsumexp(np.asarray(loglik, np.float64)) - math.log(n)
    assert abs(plain - expected) > 0.1


def test_log_marginal_increment_ignores_nan_and_neg_inf():
    prev = jnp.array([0.0, 1.0, -jnp.inf, 2.0])
    loglik = jnp.array([-1.0, jnp.nan, 3.0, -jnp.inf])
    # Only particle 0 has both positive prior weight and finite likelihood.
    p = _np_probs(prev)
    expected = math.log(p[0] * math.exp(-1.0))
    assert float(W.log_marginal_increment(prev, loglik)) == pytest.approx(expected, abs=1e-5)


def test_gradients_of_log_norm_and_log_ess(request):
    """``d log_norm / dℓ = w̄`` (the softmax), also for a large common offset;
    the max-shift inside ``normalize`` must not leak into the gradient."""
    lw = (_rng(request).standard_normal(10) - 1e4).astype(np.float32)
    lw[2] = -np.inf
    grad = np.asarray(jax.jit(jax.grad(lambda x: _W.normalize(x).log_norm))(jnp.asarray(lw)))
    np.testing.assert_allclose(grad, _np_probs(lw), rtol=1e-4, atol=1e-7)
    assert grad[2] == 0.0
    # ESS is shift-invariant, so its gradient sums to zero (and is finite).
    g_ess = np.asarray(jax.jit(jax.grad(_W.log_ess))(jnp.asarray(lw)))
    assert np.all(np.isfinite(g_ess))
    assert abs(g_ess.sum()) < 1e-5
