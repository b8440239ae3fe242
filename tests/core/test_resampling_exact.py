"""Exactness of jaxnav.core.resampling at large N, against a reference in exact arithmetic.

The reference takes the same float weights and the same uniforms and decides every
point in exact rational arithmetic (Python integers):

* every weight is an exact integer multiple of ``2⁻¹⁰⁷⁴`` (``float.as_integer_ratio``),
  so the CDF ``S_i`` and its total ``Q`` are exact integers;
* a point ``(s + F/2³²)/M`` (stratum ``s``, 32-bit fraction ``F``) lies below
  ``S_i/Q`` exactly when its key ``P = s·2³² + F`` is below
  ``c_i = ⌈S_i·M·2³²/Q⌉``, so the number of points below particle ``i``'s boundary
  is ``searchsorted(P, c_i)`` on 64-bit integer keys.

The uniforms are those that jaxnav documents for each scheme (systematic
``U = bits(key)``, stratified ``U_s = bits(key, (M,))``, multinomial and residual
the points of ``sorted_uniform_draws``). The comparisons are of integers, not
statistics, so they are deterministic: any difference is a bug. jaxnav's integer
weights are exact for every weight above ``2⁻³⁷`` of the total; the adversarial
cases include tiny weights, which jaxnav truncates by less than ``2⁻⁵⁹`` of the
total — a point would have to fall within that of a boundary to tell.
"""

from __future__ import annotations

import bisect
import functools
import itertools

import hypothesis.strategies as st
import jax
import jax.extend.core
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings

from jaxnav.core import fastmath
from jaxnav.core import resampling as R

TWO32 = 2**32
SCHEMES = ("systematic", "stratified", "multinomial", "residual")


# --------------------------------------------------------------------------- the exact reference


def exact_integers(weights: np.ndarray) -> list[int]:
    """The (non-negative, finite) floats as exact integer multiples of one power of two ``2⁻ᴷ``, the
    smallest that holds them all; anything else is 0."""
    ratios = [
        w.as_integer_ratio() if (w > 0 and np.isfinite(w)) else (0, 1) for w in np.asarray(weights, np.float64).tolist()
    ]
    k = max(den.bit_length() for _, den in ratios) - 1
    return [num << (k - den.bit_length() + 1) for num, den in ratios]


class Reference:
    """The exact CDF of ``weights`` and the boundaries ``c_i = ⌈S_i·M·2³²/Q⌉`` for ``M`` samples."""

    def __init__(self, weights: np.ndarray, num_samples: int):
        w = exact_integers(weights)
        if not any(w):
            w = [1] * len(w)
        self.weights = w
        self.cdf = list(itertools.accumulate(w))
        self.total = self.cdf[-1]
        self.m = num_samples
        scale = num_samples * TWO32
        q = self.total
        self.bounds = np.array([-((-s * scale) // q) for s in self.cdf], np.int64)

    def counts(self, keys: np.ndarray) -> np.ndarray:
        """Cumulative counts ``#{points below S_i}`` for sorted integer point keys ``P = s·2³² + F``."""
        return np.searchsorted(np.asarray(keys, np.int64), self.bounds, side="left")

    def residual_counts(self, keys_of_draws) -> np.ndarray:
        """Residual scheme: ``⌊M·w_i/Q⌋`` copies, then the draws against ``M·S_i/Q − D_i``."""
        copies = np.array([(self.m * w) // self.total for w in self.weights], np.int64)
        fixed = np.cumsum(copies)
        draws = keys_of_draws(int(self.m - fixed[-1]))
        shifted = self.bounds - fixed * TWO32
        return fixed + np.searchsorted(np.asarray(draws, np.int64), shifted, side="left")


def ancestors(cumulative: np.ndarray, m: int) -> np.ndarray:
    """``a_j = #{i : C_i ≤ j}``: particle ``i`` fills the slots ``[C_{i−1}, C_i)``."""
    return np.searchsorted(cumulative, np.arange(m), side="right")


# one program per size (run op by op, each size compiled its hundred operations)
_sorted_draws = jax.jit(R.sorted_uniform_draws, static_argnames="size")


def _draw_keys(key, count: int, size: int) -> np.ndarray:
    d = _sorted_draws(key, jnp.asarray(count), jnp.asarray(count), size=size)
    s, f = np.asarray(d.stratum, np.int64)[:count], np.asarray(d.fraction, np.int64)[:count]
    return s * TWO32 + f


def reference_ancestors(scheme: str, key, weights: np.ndarray, m: int, ref: Reference | None = None) -> np.ndarray:
    ref = Reference(weights, m) if ref is None else ref
    if scheme == "systematic":
        u = int(jax.random.bits(key, (), jnp.uint32))
        return ancestors(ref.counts(np.arange(m, dtype=np.int64) * TWO32 + u), m)
    if scheme == "stratified":
        u = np.asarray(jax.random.bits(key, (m,), jnp.uint32), np.int64)
        return ancestors(ref.counts(np.arange(m, dtype=np.int64) * TWO32 + u), m)
    if scheme == "multinomial":
        return ancestors(ref.counts(_draw_keys(key, m, m)), m)
    return ancestors(ref.residual_counts(lambda count: _draw_keys(key, count, m)), m)


_resample = jax.jit(R.resample_weights, static_argnames=("num_samples", "scheme"))


def assert_exact(scheme: str, key, weights: np.ndarray, m: int, ref: Reference | None = None) -> np.ndarray:
    got = np.asarray(_resample(key, jnp.asarray(weights), num_samples=m, scheme=scheme))
    expected = reference_ancestors(scheme, key, weights, m, ref)
    bad = np.flatnonzero(got != expected)
    assert bad.size == 0, (
        f"{scheme}: {bad.size} of {m} ancestors differ, first at {bad[:5]}: {got[bad[:5]]} vs {expected[bad[:5]]}"
    )
    return got


# --------------------------------------------------------------------------- weights: random and adversarial


def _weights(kind: str, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    if kind == "random":  # a filter's weights after a step: log-normal, spread over ~40 nats
        w = np.exp(4.0 * rng.standard_normal(n))
        w = w / w.max()
    elif kind == "zeros_at_block_edges":  # every 8th and 16th entry and its neighbours zero
        w = rng.random(n)
        i = np.arange(n)
        w[(i % 8 == 0) | (i % 16 == 15) | (i % 1024 < 2)] = 0.0
    elif kind == "one_dominant":
        w = rng.random(n) * 1e-9
        w[n // 3] = 1.0
    elif kind == "near_smallest_normal":  # un-normalised: a total near float32's smallest normal number
        w = np.float32(np.finfo(np.float32).tiny) * (1.0 + rng.integers(0, 2**20, n))
    elif kind == "mixed_tiny":  # tiny weights beside ordinary ones (truncated below 2⁻³⁷ of the total)
        w = rng.random(n)
        w[rng.random(n) < 0.5] = np.float32(np.finfo(np.float32).tiny) * 3.0
    elif kind == "unnormalised_large":
        w = rng.random(n) * 3e36
    elif kind == "all_subnormal":  # every weight below 2⁻¹²⁶ (m·2⁻¹⁴⁹, m < 2²³), a fifth of them zero
        m = rng.integers(1, 2**23, n, dtype=np.uint32) >> rng.integers(0, 23, n, dtype=np.uint32)
        m[rng.random(n) < 0.2] = 0
        return m.view(np.float32)
    elif kind == "subnormal_beside_normal":  # a few weights just above 2⁻¹²⁶, the others subnormal or zero
        m = rng.integers(0, 2**23, n, dtype=np.uint32)
        m[rng.random(n) < 0.2] = 0
        m[rng.random(n) < 0.01] |= np.uint32(1 << 23)  # exponent field 1: normal, in [2⁻¹²⁶, 2⁻¹²⁵)
        return m.view(np.float32)
    else:
        raise ValueError(kind)
    return np.asarray(w, np.float32)


KINDS = ("random", "zeros_at_block_edges", "one_dominant", "near_smallest_normal", "mixed_tiny", "unnormalised_large")


@pytest.mark.parametrize("scheme", SCHEMES)
@pytest.mark.parametrize("n, m", [(17, 17), (17, 40), (3000, 2999), (3000, 4500)])
def test_small_sets_equal_the_exact_reference_for_every_kind(scheme, n, m):
    for i, kind in enumerate(KINDS):
        key = jax.random.PRNGKey(1000 * n + 10 * m + i)
        got = assert_exact(scheme, key, _weights(kind, n, seed=n + i), m)
        assert np.all(np.diff(got) >= 0)


@pytest.mark.parametrize("scheme", SCHEMES)
@pytest.mark.parametrize("kind", ("all_subnormal", "subnormal_beside_normal"))
def test_subnormal_weights_equal_the_exact_reference(scheme, kind):
    """Weights below float32's smallest normal number, which XLA:CPU flushes to zero in arithmetic and
    comparisons: the integer weights are read from their bits, so the ancestors are those of the exact
    values (not of a uniform set, nor of the normal weights alone) and no zero weight is drawn."""
    for n, m in [(17, 40), (3000, 2999)]:
        w = _weights(kind, n, seed=n)
        assert np.all(w < np.finfo(np.float32).tiny * 2) and np.any((w > 0) & (w < np.finfo(np.float32).tiny))
        got = assert_exact(scheme, jax.random.PRNGKey(n + len(kind)), w, m)
        assert np.all(w[got] > 0)


@functools.cache
def _large_case(kind: str, n: int, m: int) -> tuple[np.ndarray, Reference]:
    """Weights and their exact reference, built once and shared by the four schemes."""
    w = _weights(kind, n, seed=n % 97)
    if kind == "random":
        w[np.random.default_rng(12).random(n) < 0.2] = 0.0  # a fifth of the particles of weight zero
    return w, Reference(w, m)


@pytest.mark.parametrize("scheme", SCHEMES)
@pytest.mark.parametrize("kind", ("random", "zeros_at_block_edges", "mixed_tiny"))
def test_65537_particles_equal_the_exact_reference(scheme, kind):
    n = 2**16 + 1
    w, ref = _large_case(kind, n, n - 1000)
    assert_exact(scheme, jax.random.PRNGKey(7), w, n - 1000, ref)


@pytest.mark.parametrize("scheme", SCHEMES)
def test_a_million_particles_equal_the_exact_reference(scheme):
    """N = 2²⁰ + 1, M = N + 4097, random weights with a fifth of them zero: float32 cannot tell
    neighbouring CDF values apart at this size; the integer CDF decides every point exactly."""
    n = 2**20 + 1
    w, ref = _large_case("random", n, n + 4097)
    got = assert_exact(scheme, jax.random.PRNGKey(13), w, n + 4097, ref)
    assert np.all(w[got] > 0)


@pytest.mark.parametrize("scheme", ("systematic", "stratified"))
def test_equal_weights_copy_every_particle_exactly_once(scheme):
    """The expected count is exactly 1 for every particle: a float32 CDF gave about 2 % of the
    particles 0 copies and 2 % two copies at this size."""
    n = 2**20 + 1
    idx = np.asarray(_resample(jax.random.PRNGKey(5), jnp.ones(n), num_samples=n, scheme=scheme))
    np.testing.assert_array_equal(idx, np.arange(n))


def test_log_weight_schemes_resample_exp_of_the_shifted_log_weights():
    """``systematic(key, ℓ)`` is ``resample_weights(key, exp(ℓ − max ℓ))`` for every scheme (the shapes of the
    small exact test, so the weights' resampler is compiled once for both)."""
    lw = jnp.asarray(np.random.default_rng(0).normal(size=3000) * 5, jnp.float32).at[::7].set(-jnp.inf)
    for scheme, fn in R.SCHEMES.items():
        key = jax.random.PRNGKey(len(scheme))
        np.testing.assert_array_equal(
            jax.jit(fn, static_argnums=2)(key, lw, 2999),
            _resample(key, jnp.exp(lw - jnp.max(lw)), num_samples=2999, scheme=scheme),
        )


# --------------------------------------------------------------------------- zero weights are never drawn


@st.composite
def weights_with_zeros(draw):
    """Random weights with zeros where hypothesis puts them: runs of any start and length, every k-th entry
    from any offset (block starts and ends of any blocking), or all but one."""
    n = draw(st.sampled_from([17, 2**16]))
    w = np.random.default_rng(draw(st.integers(0, 2**32 - 1))).random(n).astype(np.float32)
    for start, length in draw(st.lists(st.tuples(st.integers(0, n - 1), st.integers(1, 4096)), max_size=12)):
        w[start : start + length] = 0.0
    if draw(st.booleans()):
        w[draw(st.integers(0, 15)) :: draw(st.sampled_from([2, 3, 8, 16, 1024]))] = 0.0
    if draw(st.booleans()):
        keep = draw(st.integers(0, n - 1))
        w[np.arange(n) != keep] = 0.0
    return w


@settings(max_examples=25, deadline=None)
@given(w=weights_with_zeros(), seed=st.integers(0, 2**31 - 1), scheme=st.sampled_from(SCHEMES))
def test_a_zero_weight_is_never_drawn(w, seed, scheme):
    """Zeros wherever hypothesis puts them (block starts and ends included), any scheme: an ancestor always
    has positive weight (all-zero sets are resampled uniformly), and every index is in range."""
    n = w.shape[0]
    log_w = jnp.log(jnp.asarray(w))
    idx = np.asarray(jax.jit(R.SCHEMES[scheme], static_argnums=2)(jax.random.PRNGKey(seed), log_w, n))
    assert np.all((idx >= 0) & (idx < n))
    if np.any(w > 0):
        assert np.all(w[idx] > 0)


def test_inverse_cdf_never_returns_a_trailing_zero_weight():
    """Weights that do not sum to one and a query at the top: the last positive particle, never the zero after it."""
    s = np.float32(0.99954)
    w = jnp.asarray([s / 2, s / 2, 0.0], jnp.float32)
    idx = np.asarray(jax.jit(R.inverse_cdf)(jnp.asarray([1.0, np.nextafter(np.float32(1), np.float32(0)), 0.5]), w))
    np.testing.assert_array_equal(idx, [1, 1, 1])


@pytest.mark.parametrize("n", [3000, 2**16 + 1])
def test_inverse_cdf_equals_the_exact_reference_for_unsorted_points(n):
    """Arbitrary float32 points, in any order: ``min{i : u·Q < S_i}`` with ``u`` read as an exact rational."""
    w = _weights("zeros_at_block_edges", n, seed=n)
    u = np.array(jax.random.uniform(jax.random.PRNGKey(n), (5000,)), np.float32)
    u[:3] = [0.0, 0.5, np.nextafter(np.float32(1), np.float32(0))]
    got = np.asarray(jax.jit(R.inverse_cdf)(jnp.asarray(u), jnp.asarray(w)))
    ref = Reference(w, 1)
    # u = num/den exactly: u·Q < S_i  ⟺  S_i > ⌊num·Q/den⌋ (S_i is an integer)
    expected = [
        bisect.bisect_right(ref.cdf, (num * ref.total) // den)
        for num, den in (x.as_integer_ratio() for x in u.astype(np.float64).tolist())
    ]
    np.testing.assert_array_equal(got, expected)


# --------------------------------------------------------------------------- beyond 2²⁴


def test_integer_cumsum_and_search_are_exact_beyond_two_to_the_24():
    """N = 2²⁴ + 8 with all the mass on particle 16,777,217: float32 counts (and float32 indices) cannot
    name it; the integer cumulative sum and the search return exactly it, for every sample."""
    n = 2**24 + 8
    w = jnp.zeros(n, jnp.float32).at[16_777_217].set(1.0)
    idx = np.asarray(jax.jit(R.resample_weights, static_argnums=2)(jax.random.PRNGKey(0), w, 64))
    assert np.all(idx == 16_777_217)
    counts = jnp.ones(n, jnp.int32).at[-1].set(5)
    total = np.asarray(jax.jit(fastmath.int_cumsum)(counts)[-4:])
    np.testing.assert_array_equal(total, [n - 3, n - 2, n - 1, n + 4])


# --------------------------------------------------------------------------- O(N + M)


def _largest_array(fn, *args) -> int:
    """The largest operand of any op in the jaxpr (nested jaxprs included): an M×N block would show."""
    jaxpr = jax.make_jaxpr(fn)(*args)
    biggest = 0

    def visit(jx):
        nonlocal biggest
        for eqn in jx.eqns:
            for v in list(eqn.invars) + list(eqn.outvars):
                shape = getattr(v.aval, "shape", ())
                biggest = max(biggest, int(np.prod(shape)) if shape else 1)
            for sub in jax.extend.core.jaxprs_in_params(eqn.params):
                visit(sub)

    visit(jaxpr.jaxpr)
    return biggest


@pytest.mark.parametrize("scheme", SCHEMES)
def test_every_array_is_linear_in_n_plus_m(scheme):
    """At N = M = 10⁶ no array of the computation has more than a few times N + M entries (the former
    multinomial drew an M × N block of Gumbel noise: 10¹² entries here)."""
    n = 10**6
    fn = lambda key, lw: R.SCHEMES[scheme](key, lw, n)  # noqa: E731
    assert _largest_array(fn, jax.random.PRNGKey(0), jnp.zeros(n)) <= 4 * (2 * n + 2)
