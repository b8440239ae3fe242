"""Fast float32 kernels (jaxnav.core.fastmath) and the O(N) inverse CDF that uses them."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxnav.core import fastmath as fm
from jaxnav.core import resampling as R

F32_EPS = float(np.finfo(np.float32).eps)


def test_sincos_accuracy_over_the_documented_range():
    x = np.concatenate([np.linspace(-8192, 8192, 200001), np.linspace(-7, 7, 100001)]).astype(np.float32)
    s, c = jax.jit(fm.sincos)(jnp.asarray(x))
    x64 = x.astype(np.float64)
    # x is exact in float32, so the only error is the kernel's: a few ulp of 1.
    assert np.max(np.abs(np.asarray(s) - np.sin(x64))) <= 4 * F32_EPS
    assert np.max(np.abs(np.asarray(c) - np.cos(x64))) <= 4 * F32_EPS


def test_atan2_accuracy_all_quadrants_and_zero():
    rng = np.random.default_rng(0)
    y = np.concatenate([rng.normal(size=200000), rng.normal(size=1000) * 1e-30, [0.0, 0.0, 1.0, -1.0]]).astype(np.float32)
    x = np.concatenate([rng.normal(size=200000), rng.normal(size=1000), [1.0, -1.0, 0.0, 0.0]]).astype(np.float32)
    got = np.asarray(jax.jit(fm.atan2)(jnp.asarray(y), jnp.asarray(x)))
    want = np.arctan2(y.astype(np.float64), x.astype(np.float64))
    np.testing.assert_allclose(got, want, atol=4 * F32_EPS * np.pi, rtol=0)
    assert float(fm.atan2(jnp.float32(0.0), jnp.float32(0.0))) == 0.0


def test_float64_falls_back_to_full_precision():
    with jax.enable_x64(True):
        x = jnp.linspace(-10, 10, 1001, dtype=jnp.float64)
        np.testing.assert_allclose(fm.sin(x), np.sin(np.asarray(x)), rtol=0, atol=1e-15)
        np.testing.assert_allclose(fm.atan2(x, 1.0 + x * 0), np.arctan2(np.asarray(x), 1.0), rtol=0, atol=1e-15)


def test_gradients_are_the_analytic_ones():
    x = jnp.asarray([0.3, -2.0, 5.0])
    np.testing.assert_allclose(jax.vmap(jax.grad(fm.sin))(x), np.cos(np.asarray(x)), atol=1e-6)
    np.testing.assert_allclose(jax.vmap(jax.grad(fm.cos))(x), -np.sin(np.asarray(x)), atol=1e-6)
    check_grads(fm.atan2, (jnp.asarray([0.4, -1.2]), jnp.asarray([-0.7, 2.0])), order=1, modes=["fwd", "rev"], atol=1e-2, rtol=1e-2)


@pytest.mark.parametrize("n", [1, 7, 16, 17, 1000, 65537])
def test_cumsum_is_accurate_and_monotone_even_with_zero_runs(n):
    rng = np.random.default_rng(n)
    x = (rng.random(n) ** 8).astype(np.float32)
    x[n // 3 : n // 2] = 0.0  # long runs of zeros: the case that breaks naive blocked sums
    got = np.asarray(jax.jit(fm.cumsum)(jnp.asarray(x)))
    want = np.cumsum(x.astype(np.float64))
    assert np.all(np.diff(got) >= 0)
    np.testing.assert_allclose(got, want, rtol=0, atol=4 * F32_EPS * max(want[-1], 1e-30) * np.log2(max(n, 2)))


@pytest.mark.parametrize("m", [5, 16, 3000, 70001])
def test_count_cumsum_is_exact(m):
    counts = np.random.default_rng(m).integers(0, 4, m)
    np.testing.assert_array_equal(jax.jit(fm.count_cumsum)(jnp.asarray(counts)), np.cumsum(counts))


@pytest.mark.parametrize("n", [3000, 100003])
@pytest.mark.parametrize("spread", [0.1, 5.0, 40.0])
def test_stratified_inverse_cdf_equals_binary_search(n, spread):
    """The O(N) path returns exactly the searchsorted indices (systematic and stratified points)."""
    rng = np.random.default_rng(int(spread * 10) + n)
    lw = jnp.asarray(rng.normal(size=n) * spread, jnp.float32)
    lw = lw.at[: n // 10].set(-jnp.inf)  # a run of zero weights
    w = jnp.exp(lw - lw.max())
    w = w / w.sum()
    fast = jax.jit(R.stratified_inverse_cdf)
    ref = jax.jit(R.inverse_cdf)
    for u in [0.0, 0.5, float(np.nextafter(np.float32(1), np.float32(0)))]:
        pts = (jnp.float32(u) + jnp.arange(n, dtype=jnp.float32)) / n
        np.testing.assert_array_equal(fast(pts, w), ref(pts, w))
    pts = (jax.random.uniform(jax.random.PRNGKey(n), (n,)) + jnp.arange(n)) / n
    np.testing.assert_array_equal(fast(pts, w), ref(pts, w))


@pytest.mark.parametrize(
    "shape_a, shape_b",
    [((2, 2), (2, 2)), ((3, 2), (2,)), ((2,), (2, 3)), ((4,), (4,)), ((2, 4), (4, 5)), ((3, 6), (6, 2)), ((2, 3, 2), (2, 2))],
)
def test_matmul_equals_the_matrix_product(shape_a, shape_b, getkey):
    """Written-out products (contractions ≤ 4) and the ``@`` fallback (longer contractions, 3-D operands)
    agree with ``@``, also under vmap and in their gradients."""
    a = jax.random.normal(getkey(), (5,) + shape_a)
    b = jax.random.normal(getkey(), (5,) + shape_b)
    got = jax.vmap(fm.matmul)(a, b)
    np.testing.assert_allclose(got, jax.vmap(jnp.matmul)(a, b), rtol=1e-5, atol=1e-6)
    loss = lambda f: lambda x, y: jnp.sum(jnp.sin(jax.vmap(f)(x, y)))  # noqa: E731
    ref = jax.grad(loss(jnp.matmul), argnums=(0, 1))(a, b)
    for g, r in zip(jax.grad(loss(fm.matmul), argnums=(0, 1))(a, b), ref):
        np.testing.assert_allclose(g, r, rtol=1e-5, atol=1e-5)


def test_small_sum_equals_sum(getkey):
    for n in (1, 2, 4, 9):
        x = jax.random.normal(getkey(), (n,))
        np.testing.assert_allclose(fm.small_sum(x), jnp.sum(x), rtol=1e-6, atol=1e-6)
    y = jax.random.normal(getkey(), (3, 2))
    np.testing.assert_allclose(fm.small_sum(y), jnp.sum(y), rtol=1e-6)
