"""Fast float32 kernels and the exact integer cumulative sum of jaxnav.core.fastmath."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxnav.core import fastmath as fm

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
    y = np.concatenate([rng.normal(size=200000), rng.normal(size=1000) * 1e-30, [0.0, 0.0, 1.0, -1.0]]).astype(
        np.float32
    )
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
    check_grads(
        fm.atan2,
        (jnp.asarray([0.4, -1.2]), jnp.asarray([-0.7, 2.0])),
        order=1,
        modes=["fwd", "rev"],
        atol=1e-2,
        rtol=1e-2,
    )


@pytest.mark.parametrize("dtype", [jnp.int32, jnp.uint32])
@pytest.mark.parametrize("m", [1, 5, 8, 9, 3000, 70001])
def test_int_cumsum_is_exact_and_wraps_on_both_backends_paths(m, dtype):
    """The blocked integer product (XLA:CPU) and ``jnp.cumsum`` (other backends) both equal NumPy's sum
    modulo 2³², with values that overflow 32 bits many times over."""
    x = np.random.default_rng(m).integers(0, 2**32, m, dtype=np.uint64)
    want = (np.cumsum(x) % 2**32).astype(np.uint32).view(np.dtype(dtype))
    arr = jnp.asarray(x.astype(np.uint32).view(np.dtype(dtype)))
    np.testing.assert_array_equal(jax.jit(fm.int_cumsum)(arr), want)
    np.testing.assert_array_equal(jax.jit(fm.blocked_int_cumsum)(arr), want)
    np.testing.assert_array_equal(jax.jit(lambda v: jnp.cumsum(v, dtype=v.dtype))(arr), want)
    np.testing.assert_array_equal(
        jax.jit(jax.vmap(fm.int_cumsum))(jnp.stack([arr, arr[::-1]])),
        np.stack([want, (np.cumsum(x[::-1]) % 2**32).astype(np.uint32).view(np.dtype(dtype))]),
    )


def test_int_cumsum_refuses_other_types():
    with pytest.raises(TypeError, match="int32 or uint32"):
        fm.int_cumsum(jnp.ones(4))
    with pytest.raises(TypeError, match="1-D"):
        fm.int_cumsum(jnp.ones((4, 2), jnp.int32))


@pytest.mark.parametrize(
    "shape_a, shape_b",
    [
        ((2, 2), (2, 2)),
        ((3, 2), (2,)),
        ((2,), (2, 3)),
        ((4,), (4,)),
        ((2, 4), (4, 5)),
        ((3, 6), (6, 2)),
        ((2, 3, 2), (2, 2)),
    ],
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
