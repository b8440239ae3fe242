"""``jaxnav.core.rng`` returns jax.random's numbers bit for bit, and really takes its fast form on the CPU."""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.core import fastmath, rng

SHAPES = [(), (1,), (7,), (1000, 3), (2, 3, 5), (4097,)]
KEYS = [jax.random.key(0), jax.random.key(2**31 + 12345), jax.random.fold_in(jax.random.key(7), 3)]


def _same(a: jax.Array, b: jax.Array) -> None:
    assert a.dtype == b.dtype and a.shape == b.shape
    a, b = np.asarray(a), np.asarray(b)
    if a.dtype.kind == "f":
        a, b = a.view(f"u{a.dtype.itemsize}"), b.view(f"u{b.dtype.itemsize}")
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("shape", SHAPES)
def test_bits_are_jax_random_bits(shape):
    for key in KEYS:
        _same(rng.bits(key, shape), jax.random.bits(key, shape))


@pytest.mark.parametrize("shape", SHAPES)
def test_uniform_and_normal_are_jax_randoms_float32(shape):
    for key in KEYS:
        _same(rng.uniform(key, shape), jax.random.uniform(key, shape))
        _same(
            rng.uniform(key, shape, jnp.float32, -np.pi, np.pi),
            jax.random.uniform(key, shape, jnp.float32, -np.pi, np.pi),
        )
        _same(rng.normal(key, shape, jnp.float32), jax.random.normal(key, shape, jnp.float32))


def test_float64_draws_and_64_bit_words_are_jax_randoms():
    with jax.enable_x64(True):
        for key in KEYS:
            _same(rng.bits(key, (333,), jnp.uint64), jax.random.bits(key, (333,), jnp.uint64))
            _same(
                rng.uniform(key, (333, 2), jnp.float64, 2.0, 5.0),
                jax.random.uniform(key, (333, 2), jnp.float64, 2.0, 5.0),
            )
            _same(rng.normal(key, (333, 2), jnp.float64), jax.random.normal(key, (333, 2), jnp.float64))
            _same(rng.normal(key, (5,)), jax.random.normal(key, (5,)))  # default dtype: float64 here


def test_default_dtypes_are_jax_randoms_with_and_without_x64():
    """``dtype=None`` is what jax.random picks: 64-bit words and float64 draws under ``jax_enable_x64``,
    32-bit ones without; the numbers are jax.random's, eagerly and under ``jit``."""
    for x64, word, real in [(True, jnp.uint64, jnp.float64), (False, jnp.uint32, jnp.float32)]:
        with jax.enable_x64(x64):
            for key in KEYS:
                assert rng.bits(key, (333,)).dtype == word
                assert rng.uniform(key, (333,)).dtype == rng.normal(key, (333,)).dtype == real
                _same(rng.bits(key, (333,)), jax.random.bits(key, (333,)))
                _same(jax.jit(lambda k: rng.bits(k, (7, 3)))(key), jax.random.bits(key, (7, 3)))
                _same(rng.uniform(key, (333,)), jax.random.uniform(key, (333,)))
                _same(rng.normal(key, (333,)), jax.random.normal(key, (333,)))


def test_64_bit_dtypes_without_x64_give_jax_randoms_32_bit_numbers():
    """Without ``jax_enable_x64`` jax.random narrows a requested ``uint64``/``float64`` to 32 bits (with a
    warning): the same 32-bit numbers here."""
    with jax.enable_x64(False), warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        for key in KEYS:
            _same(rng.bits(key, (333,), jnp.uint64), jax.random.bits(key, (333,), jnp.uint64))
            _same(rng.uniform(key, (333,), jnp.float64), jax.random.uniform(key, (333,), jnp.float64))
            _same(rng.normal(key, (333,), jnp.float64), jax.random.normal(key, (333,), jnp.float64))


def test_array_bounds_broadcast_like_jax_random():
    key = KEYS[1]
    lo = jnp.asarray([0.0, -1.0, 10.0], jnp.float32)
    hi = jnp.asarray([1.0, 1.0, 20.0], jnp.float32)
    _same(rng.uniform(key, (50, 3), jnp.float32, lo, hi), jax.random.uniform(key, (50, 3), jnp.float32, lo, hi))


def test_raw_uint32_keys_are_accepted_like_jax_random():
    raw = jax.random.PRNGKey(42)
    _same(rng.normal(raw, (100, 3)), jax.random.normal(raw, (100, 3)))
    _same(rng.bits(raw, (9,)), jax.random.bits(raw, (9,)))


def test_same_numbers_under_jit_vmap_and_scan():
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(3), i))(jnp.arange(16))

    def scanned(draw):
        def body(carry, t):
            k = jax.random.fold_in(carry, t)
            return carry, jax.vmap(lambda kk: draw(kk, (200, 3), jnp.float32))(jax.random.split(k, 4))

        return jax.jit(lambda k: jax.lax.scan(body, k, jnp.arange(5))[1])

    for draw_ours, draw_jax in [(rng.normal, jax.random.normal), (rng.uniform, jax.random.uniform)]:
        _same(
            jax.jit(jax.vmap(lambda k: draw_ours(k, (64,), jnp.float32)))(keys),
            jax.vmap(lambda k: draw_jax(k, (64,), jnp.float32))(keys),
        )
        _same(scanned(draw_ours)(keys[0]), scanned(draw_jax)(keys[0]))


def test_other_key_implementations_and_settings_use_jax_random():
    key = jax.random.key(5, impl="rbg")
    _same(rng.normal(key, (100,)), jax.random.normal(key, (100,)))
    _same(rng.uniform(key, (10, 2)), jax.random.uniform(key, (10, 2)))
    previous = jax.config.jax_threefry_partitionable
    try:
        jax.config.update("jax_threefry_partitionable", False)
        _same(rng.normal(KEYS[0], (100,)), jax.random.normal(KEYS[0], (100,)))
    finally:
        jax.config.update("jax_threefry_partitionable", previous)
    # Dtypes without a fast form: jax.random's result, or its error.
    _same(rng.normal(KEYS[0], (10,), jnp.complex64), jax.random.normal(KEYS[0], (10,), jnp.complex64))
    _same(rng.bits(KEYS[0], (10,), jnp.uint8), jax.random.bits(KEYS[0], (10,), jnp.uint8))
    for ours, theirs in [
        (lambda: rng.uniform(KEYS[0], (3,), jnp.int32), lambda: jax.random.uniform(KEYS[0], (3,), jnp.int32)),
        (
            lambda: rng.normal(jax.random.split(KEYS[0], 2), (3,)),
            lambda: jax.random.normal(jax.random.split(KEYS[0], 2), (3,)),
        ),
    ]:
        with pytest.raises(Exception) as expected:
            theirs()
        with pytest.raises(expected.type, match=str(expected.value)[:30]):
            ours()


def _compiled(fn, *args) -> str:
    return jax.jit(fn).lower(*args).compile().as_text()


def _has_loop(draw, *args) -> bool:
    # A new function object each time: jit traces it afresh, so the switch (read when tracing) applies.
    return "stablehlo.while" in jax.jit(lambda *a: draw(*a)).lower(*args).as_text()


def test_cpu_draws_are_loop_free_and_plain_forms_restore_jax_random():
    """The fast bits and uniforms are one elementwise expression; jax.random's CPU lowering of the hash is a
    loop, which the switch brings back (the normals keep their bits in a buffer of their own, through a loop
    that never runs, so they are left to the bit-for-bit tests)."""
    draws = [lambda k: rng.uniform(k, (1000,), jnp.float32), lambda k: rng.bits(k, (10,))]
    assert not any(_has_loop(draw, KEYS[0]) for draw in draws)
    try:
        fastmath.use_plain_forms(True)
        assert all(_has_loop(draw, KEYS[0]) for draw in draws)
        _same(draws[0](KEYS[0]), jax.random.uniform(KEYS[0], (1000,), jnp.float32))
    finally:
        fastmath.use_plain_forms(False)
    assert not fastmath.use_plain_forms()


def test_plain_forms_switch_fastmath_to_jnp():
    x = jnp.linspace(-3.0, 3.0, 101, dtype=jnp.float32)
    ints = jnp.arange(5000, dtype=jnp.int32) % 7
    fast = (fastmath.sin(x), fastmath.atan2(x, 1.0 - x))
    assert " dot(" in _compiled(lambda v: fastmath.int_cumsum(v), ints)  # the blocked form's row products
    try:
        fastmath.use_plain_forms(True)
        _same(fastmath.sin(x), jnp.sin(x))
        _same(fastmath.atan2(x, 1.0 - x), jnp.arctan2(x, 1.0 - x))
        assert " dot(" not in _compiled(lambda v: fastmath.int_cumsum(v), ints)  # jnp.cumsum's lowering
    finally:
        fastmath.use_plain_forms(False)
    np.testing.assert_allclose(fast[0], np.sin(np.asarray(x)), atol=2e-7)
    np.testing.assert_allclose(fast[1], np.arctan2(np.asarray(x), 1.0 - np.asarray(x)), atol=4e-7)


def test_draws_feed_gradients_like_jax_random():
    """A reparameterised draw differentiates the same way (the noise itself carries no gradient)."""

    def loss(draw, sd):
        return jnp.sum((sd * draw(KEYS[2], (50,), jnp.float32)) ** 2)

    g_ours = jax.grad(lambda s: loss(rng.normal, s))(0.7)
    g_jax = jax.grad(lambda s: loss(jax.random.normal, s))(0.7)
    _same(g_ours, g_jax)
