"""64-bit unsigned integers on uint32 words (jaxnav.core.u64) against Python's exact integers.

Each operation is checked on random words, on the words that carry (all ones, powers of two) and
under ``vmap``; the Python reference is exact, so the comparisons are equalities.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.core import resampling as R
from jaxnav.core import u64

MASK32, MASK64 = 2**32 - 1, 2**64 - 1
EDGES = [0, 1, 2**31 - 1, 2**31, 2**32 - 1, 2**32, 2**63 - 1, 2**63, 2**64 - 1, 0xDEADBEEF12345678]


def _values(n: int, seed: int, bits: int = 64) -> list[int]:
    rng = np.random.default_rng(seed)
    edges = [v for v in EDGES if v < 2**bits]
    return edges + [int(x) for x in rng.integers(0, 2**bits, n, dtype=np.uint64)]


def _u64(values: list[int]) -> u64.U64:
    arr = np.array(values, dtype=np.uint64)
    return u64.U64(jnp.asarray((arr >> 32).astype(np.uint32)), jnp.asarray((arr & MASK32).astype(np.uint32)))


def _ints(x: u64.U64) -> list[int]:
    return [(int(h) << 32) | int(l) for h, l in zip(np.asarray(x.hi), np.asarray(x.lo))]


def test_add_sub_and_comparisons_are_exact_modulo_two_to_the_64():
    a, b = _values(500, 1), _values(500, 2)[::-1][: len(_values(500, 1))]
    ua, ub = _u64(a), _u64(b)
    assert _ints(jax.jit(u64.add)(ua, ub)) == [(x + y) & MASK64 for x, y in zip(a, b)]
    assert _ints(jax.jit(u64.sub)(ua, ub)) == [(x - y) & MASK64 for x, y in zip(a, b)]
    small = [v & MASK32 for v in b]
    assert _ints(u64.add_u32(ua, jnp.asarray(small, jnp.uint32))) == [(x + y) & MASK64 for x, y in zip(a, small)]
    np.testing.assert_array_equal(u64.less(ua, ub), [x < y for x, y in zip(a, b)])
    np.testing.assert_array_equal(u64.less_equal(ua, ua), True)
    np.testing.assert_array_equal(u64.less_equal(ua, ub), [x <= y for x, y in zip(a, b)])


def test_products_are_exact():
    x = [v & MASK32 for v in _values(400, 4, bits=32)]
    a = _values(400, 3)[: len(x)]
    ua, ux = _u64(a), jnp.asarray(x, jnp.uint32)
    full = [p * q for p, q in zip(a, x)]
    w2, w1, w0 = jax.jit(u64.mul_u32)(ua, ux)
    got = [(int(c) << 64) | (int(b) << 32) | int(d) for c, b, d in zip(np.asarray(w2), np.asarray(w1), np.asarray(w0))]
    assert got == full
    assert _ints(u64.mul_high(ua, ux)) == [p >> 32 for p in full]
    assert _ints(u64.mul_low(ua, ux)) == [p & MASK64 for p in full]
    lo = [v & MASK32 for v in a]
    assert _ints(u64.mul32(jnp.asarray(lo, jnp.uint32), ux)) == [p * q for p, q in zip(lo, x)]


def test_cumsum_is_exact_over_many_carries():
    """2¹⁸ values near 2⁶⁰: the low words wrap on most steps; the total stays below 2⁶⁴ mod arithmetic."""
    rng = np.random.default_rng(5)
    vals = [int(v) for v in rng.integers(0, 2**45, 2**18, dtype=np.uint64)]
    vals[::97] = [2**32 - 1] * len(vals[::97])
    got = _ints(jax.jit(u64.cumsum)(_u64(vals)))
    want, run = [], 0
    for v in vals:
        run = (run + v) & MASK64
        want.append(run)
    assert got == want


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_from_float_is_the_exact_floor(dtype):
    with jax.enable_x64(dtype == jnp.float64):
        rng = np.random.default_rng(6)
        x = np.concatenate(
            [rng.random(300) * 2.0 ** rng.integers(0, 64, 300), [0.0, 0.5, 1.0, 2.0**63, 2.0**64 - 2.0**40]]
        )
        x = x.astype(np.dtype(dtype))
        got = _ints(jax.jit(u64.from_float)(jnp.asarray(x)))
        assert got == [int(np.floor(v)) if v < 2.0**64 else 0 for v in x.astype(np.float64)]


def test_divmod_by_a_small_divisor_is_exact():
    d = [int(v) % (2**30 - 1) + 1 for v in _values(300, 8, bits=32)]
    a = _values(300, 7)[: len(d)]
    q, r = jax.jit(u64.divmod_u32)(_u64(a), jnp.asarray(d, jnp.uint32))
    assert _ints(q) == [x // y for x, y in zip(a, d)]
    np.testing.assert_array_equal(np.asarray(r).astype(np.int64), [x % y for x, y in zip(a, d)])


@pytest.mark.parametrize("m", [1, 7, 1000, 2**20 + 3, R.MAX_SAMPLES])
def test_stratum_and_remainder_divide_exactly(m):
    """``k = ⌊x·M/Q⌋`` and ``r = x·M − k·Q`` for totals across the admitted range and x from 0 to Q."""
    rng = np.random.default_rng(m)
    for total in (2**60, 2**61 - 1, int(rng.integers(2**60, 2**61, dtype=np.uint64)), int(2**61 * 1.015)):
        xs = [0, 1, total - 1, total] + [int(v) for v in rng.integers(0, total, 200, dtype=np.uint64)]
        sc = R.scale(u64.constant(total), m, m)
        assert int(sc.reciprocal) == (m << 62) // total
        k, r = jax.jit(lambda x, sc=sc: R.stratum_and_remainder(sc, x))(_u64(xs))
        assert np.asarray(k).tolist() == [x * m // total for x in xs]
        assert _ints(r) == [x * m % total for x in xs]


def test_constant_refuses_out_of_range():
    with pytest.raises(ValueError, match="2\\*\\*64"):
        u64.constant(2**64)
