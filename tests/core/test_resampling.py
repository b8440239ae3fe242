"""Tests of jaxnav.core.resampling: the four schemes, conditional resampling, Gaussian refresh.

Property tests use hypothesis with a few fixed array sizes (so every jitted
resampler compiles once per size, not once per example). Statistical tests
use fixed keys and tolerances derived from an explicit Monte Carlo standard
error; the float32 tolerances come from a worst-case round-off bound.
"""

from __future__ import annotations

import math
import zlib
from functools import partial

import hypothesis.extra.numpy as hnp
import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings

from jaxnav.core import resampling as R
from jaxnav.core import weights as W

EPS32 = float(np.finfo(np.float32).eps)
N = 16  # particle count of most tests; the property tests also use N = 1
SIZES = [1, N]
K = 2000  # resamplings (independent keys) per batched call
NAMES = sorted(R.SCHEMES)


@partial(jax.jit, static_argnums=0)
def _batch(name, keys, log_weights):
    """Resample ``log_weights [N]`` once per key of ``keys [K]``.

    Returns offspring counts ``[K, N]`` and indices ``[K, N]``. Every test of
    the schemes goes through this one function, so each (scheme, N) pair is
    compiled once for the whole module.
    """
    n = log_weights.shape[0]

    def one(key):
        idx = R.SCHEMES[name](key, log_weights, n)
        return jnp.zeros(n, jnp.int32).at[idx].add(1), idx

    return jax.vmap(one)(keys)


_split = jax.jit(lambda key: jax.random.split(key, K))


def _keys(seed_or_key) -> jax.Array:
    """K independent keys from an int seed or a key."""
    key = jax.random.PRNGKey(seed_or_key) if isinstance(seed_or_key, int) else seed_or_key
    return _split(key)


def _np_probs(log_weights) -> np.ndarray:
    """Normalised weights in float64 from the same float32 log-weights (NaN/+inf → -inf)."""
    lw = np.asarray(log_weights, np.float64)
    lw = np.where(np.isnan(lw) | (lw == np.inf), -np.inf, lw)
    top = np.max(lw)
    if not np.isfinite(top):
        return np.full(lw.shape, 1.0 / lw.shape[0])
    lw = lw - top
    p = np.exp(lw)
    return p / p.sum()


# --------------------------------------------------------------------------- strategies

_SPECIAL = [-np.inf, np.nan, np.inf, 0.0, 80.0, -80.0, -1e30, 1e30, 3e38, -3e38, -1e-30]
_extreme_elements = st.one_of(
    st.floats(width=32),  # anything, NaN and ±inf included
    st.floats(-100.0, 100.0, width=32),
    st.sampled_from([float(np.float32(v)) for v in _SPECIAL]),
)


@st.composite
def extreme_log_weights(draw):
    """Arbitrary float32 log-weights of a fixed size, or all -inf but one entry."""
    n = draw(st.sampled_from(SIZES))
    if draw(st.booleans()):
        return draw(hnp.arrays(np.float32, n, elements=_extreme_elements))
    lw = np.full(n, -np.inf, np.float32)
    lw[draw(st.integers(0, n - 1))] = draw(st.sampled_from([float(np.float32(v)) for v in _SPECIAL[3:]]))
    return lw


@st.composite
def moderate_log_weights(draw):
    """Log-weights in [-10, 10] with some -inf entries (at least one finite)."""
    n = draw(st.sampled_from(SIZES))
    lw = draw(
        hnp.arrays(
            np.float32,
            n,
            elements=st.one_of(st.floats(-10.0, 10.0, width=32), st.just(float("-inf"))),
        )
    )
    lw[draw(st.integers(0, n - 1))] = draw(st.floats(-10.0, 10.0, width=32))
    return lw


def _roundoff_tol(n: int) -> float:
    """Worst-case error of ``N·(c_i − c_{i−1})`` against ``N·w̄_i`` (float64), for log-weights in ``[-10, 10]``.

    The CDF and the points are exact (integer arithmetic), so the only error is in
    the float32 weights ``exp(ℓ − max ℓ)``: the subtraction errs by at most
    ``20·eps/2`` absolute and ``exp`` by a few ulps, together less than ``16·eps``
    relative per weight; the exact normalisation doubles that at most. So an
    interval length, in units of ``1/N``, is off by less than ``N·32·eps``.
    """
    return n * 32 * EPS32


# --------------------------------------------------------------------------- (a), (e) valid indices


@pytest.mark.parametrize("name", NAMES)
@settings(max_examples=40, deadline=None)
@given(lw=extreme_log_weights(), seed=st.integers(0, 2**31 - 1))
def test_indices_in_range_for_any_weights(name, lw, seed):
    """Any float32 log-weights (NaN, ±inf, ±1e30, ±3e38, one finite entry) give
    ``N`` int32 indices in ``[0, N)`` — for each of K keys. Particles of zero
    weight (-inf/NaN/+inf entries, which are sanitised to -inf) are never
    chosen unless the set is degenerate and resampled uniformly."""
    n = lw.shape[0]
    counts, idx = map(np.asarray, _batch(name, _keys(seed), jnp.asarray(lw)))
    assert idx.shape == (K, n) and idx.dtype == np.int32
    assert np.all((idx >= 0) & (idx < n))
    assert np.all(counts.sum(axis=1) == n)
    sane = np.where(np.isnan(lw) | (lw == np.inf), -np.inf, lw)
    if np.any(np.isfinite(sane)):
        assert np.all(np.isfinite(sane[idx])), (sane, np.unique(idx))


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("fill", [-np.inf, np.nan, "mixed"])
def test_degenerate_weights_resample_uniformly(name, fill, getkey):
    """A degenerate set (no finite log-weight) is resampled exactly as the
    uniform set would be with the same key (never an out-of-range index)."""
    if fill == "mixed":
        lw = np.resize(np.array([np.nan, -np.inf, np.inf], np.float32), N)
    else:
        lw = np.full(N, fill, np.float32)
    keys = _keys(getkey())
    _, idx = _batch(name, keys, jnp.asarray(lw))
    idx = np.asarray(idx)
    assert np.all((idx >= 0) & (idx < N))
    np.testing.assert_array_equal(idx, _batch(name, keys, jnp.zeros(N))[1])


_resample_weights = jax.jit(R.resample_weights, static_argnames=("num_samples", "scheme"))


@pytest.mark.parametrize("name", NAMES)
def test_subnormal_weights_keep_their_sizes_and_zeros(name):
    """Weights that are all below float32's smallest normal number ``2⁻¹²⁶`` (which XLA:CPU flushes to
    zero in arithmetic) are resampled by their exact values: ``[2⁻¹⁴⁹, 2⁻¹⁴⁹, 0]`` never draws the zero and
    gives ``M/2`` copies each (systematic, stratified, residual: exactly); ``[3, 1, 0, 0]·2⁻¹⁴⁹`` gives
    three quarters and a quarter; float64 subnormals likewise. The log-weight path never sees a
    subnormal maximum (``exp(ℓ − max ℓ)``): very negative log-weights are resampled as their
    differences say, and ``-inf`` entries are never drawn."""
    m = 1000
    tiny = float(np.float32(2.0**-149))
    half = _resample_weights(
        jax.random.PRNGKey(0), jnp.asarray([tiny, tiny, 0.0], jnp.float32), num_samples=m, scheme=name
    )
    counts = np.bincount(np.asarray(half), minlength=3)
    assert counts[2] == 0, counts
    quarter = _resample_weights(
        jax.random.PRNGKey(1), jnp.asarray([3 * tiny, tiny, 0.0, 0.0], jnp.float32), num_samples=m, scheme=name
    )
    counts4 = np.bincount(np.asarray(quarter), minlength=4)
    assert counts4[2] == counts4[3] == 0, counts4
    if name == "multinomial":  # binomial: 5 standard deviations
        assert abs(counts[0] - m / 2) < 5 * math.sqrt(m / 4), counts
        assert abs(counts4[1] - m / 4) < 5 * math.sqrt(m * 3 / 16), counts4
    else:
        np.testing.assert_array_equal(counts, [m // 2, m // 2, 0])
        np.testing.assert_array_equal(counts4, [3 * m // 4, m // 4, 0, 0])
    with jax.enable_x64(True):
        w64 = jnp.asarray([5e-324, 0.0, 1e-323], jnp.float64)  # 2⁻¹⁰⁷⁴, 0, 2·2⁻¹⁰⁷⁴
        idx = np.asarray(jax.jit(R.resample_weights, static_argnums=(2, 3))(jax.random.PRNGKey(2), w64, 999, name))
        counts64 = np.bincount(idx, minlength=3)
        assert counts64[1] == 0, counts64
        if name != "multinomial":
            np.testing.assert_array_equal(counts64, [333, 0, 666])
    resample = jax.jit(R.SCHEMES[name], static_argnums=2)
    for lw, expected in [
        ([-1e4, -1e4, -1e4 - np.log(2.0), -np.inf], [0.4, 0.4, 0.2, 0.0]),
        ([-np.inf, -1e4, -np.inf, -np.inf], [0.0, 1.0, 0.0, 0.0]),
    ]:
        idx = resample(jax.random.PRNGKey(3), jnp.asarray(lw, jnp.float32), m)
        frac = np.bincount(np.asarray(idx), minlength=4) / m
        assert frac[3] == 0 and np.all(frac[np.asarray(expected) == 0] == 0), frac
        np.testing.assert_allclose(frac, expected, atol=0.002 if name != "multinomial" else 5 * math.sqrt(0.25 / m))


# --------------------------------------------------------------------------- (b) offspring bounds


@settings(max_examples=50, deadline=None)
@given(lw=moderate_log_weights(), seed=st.integers(0, 2**31 - 1))
def test_systematic_counts_within_floor_ceil(lw, seed):
    """Systematic: every offspring count is ``⌊N w̄_i⌋`` or ``⌈N w̄_i⌉``.

    The points ``(u + m)/N`` are exactly ``1/N`` apart, so the interval
    ``[c_{i−1}, c_i)`` of length ``w̄_i`` contains ``⌊N w̄_i⌋`` or
    ``⌈N w̄_i⌉`` of them, whatever ``u`` — a deterministic property, checked
    for K keys per weight vector up to the float32 rounding of the weights
    (:func:`_roundoff_tol`).
    """
    n = lw.shape[0]
    counts = np.asarray(_batch("systematic", _keys(seed), jnp.asarray(lw))[0])
    target = n * _np_probs(lw)
    tol = _roundoff_tol(n)
    assert np.all(counts >= np.floor(target - tol)), (counts.min(0), target)
    assert np.all(counts <= np.ceil(target + tol)), (counts.max(0), target)


@settings(max_examples=50, deadline=None)
@given(lw=moderate_log_weights(), seed=st.integers(0, 2**31 - 1))
def test_stratified_counts_within_two_of_expectation(lw, seed):
    """Stratified: ``|count_i − N w̄_i| < 2`` — *not* floor/ceil.

    Each stratum ``[m, m+1)`` (in units of ``1/N``) gets its own uniform. The
    interval ``[a, b)`` with ``b − a = N w̄_i`` fully covers
    ``⌊b⌋ − ⌈a⌉ ∈ (N w̄_i − 2, N w̄_i]`` strata, each contributing exactly one
    point, and partially overlaps at most two more, each contributing 0 or 1.
    Hence ``N w̄_i − 2 < count_i < N w̄_i + 2``; the floor/ceil bound of
    systematic resampling fails in general (see
    :func:`test_stratified_can_leave_floor_ceil`).
    """
    n = lw.shape[0]
    counts = np.asarray(_batch("stratified", _keys(seed), jnp.asarray(lw))[0])
    target = n * _np_probs(lw)
    assert np.all(np.abs(counts - target) < 2 + _roundoff_tol(n)), (counts.min(0), counts.max(0), target)


def test_stratified_can_leave_floor_ceil():
    """Why the stratified bound is ±2, not floor/ceil: with N = 16 and
    ``N w̄ = (0.5, 2, 13.5/14, …)``, particle 1 owns ``[0.5, 2.5)`` in units of
    1/N. Stratum 1 always lands in it, strata 0 and 2 each with probability
    1/2, so its count is 1, 2 or 3 with probabilities 1/4, 1/2, 1/4 although
    ``N w̄_1 = 2``. Over K = 2000 keys both 1 and 3 occur (each is missed with
    probability 0.75²⁰⁰⁰), and the frequency of 3 is 1/4 within 5 binomial SE."""
    nw = np.concatenate([[0.5, 2.0], np.full(N - 2, 13.5 / (N - 2))])
    counts = np.asarray(_batch("stratified", _keys(0), jnp.log(jnp.asarray(nw / N, jnp.float32)))[0])
    c1 = counts[:, 1]
    assert set(np.unique(c1).tolist()) == {1, 2, 3}
    assert abs(np.mean(c1 == 3) - 0.25) < 5 * math.sqrt(0.25 * 0.75 / K)


@settings(max_examples=30, deadline=None)
@given(lw=moderate_log_weights(), seed=st.integers(0, 2**31 - 1))
def test_residual_keeps_deterministic_copies(lw, seed):
    """Residual: at least ``⌊N w̄_i⌋`` copies of every particle (the deterministic part)."""
    n = lw.shape[0]
    counts = np.asarray(_batch("residual", _keys(seed), jnp.asarray(lw))[0])
    target = n * _np_probs(lw)
    assert np.all(counts >= np.floor(target - _roundoff_tol(n))), (counts.min(0), target)


# --------------------------------------------------------------------------- (c) unbiasedness

# N·w̄ with every fractional part in [0.1, 0.9]: then no scheme has a
# particle whose count is (nearly) deterministic, so the empirical standard
# error below is a meaningful scale for every particle.
_SKEWED = np.array([4.3, 3.6, 2.2, 1.4, 0.9, 0.7, 0.6, 0.5, 0.4, 0.35, 0.3, 0.25, 0.15, 0.15, 0.1, 0.1])


@pytest.mark.parametrize("name", NAMES)
def test_all_schemes_are_unbiased(name):
    """E[count_i] = N·w̄_i for every scheme (Douc & Cappé 2005).

    Over K = 2000 independent keys, the mean count of each particle is
    compared with ``N w̄_i``. Tolerance: 5 standard errors, with the standard
    error ``sd(count_i)/√K`` estimated from the same draws. The counts are
    bounded (0…N), so by the CLT the mean is Gaussian to a good approximation
    at K = 2000; the probability that any of the 16 particles exceeds 5 SE
    under a correct resampler is ≈ 16 × 5.7e-7 ≈ 1e-5. The keys are fixed, so
    the test is deterministic.
    """
    assert _SKEWED.size == N and abs(_SKEWED.sum() - N) < 1e-12
    lw = jnp.asarray(np.log(_SKEWED / N) - 3.7, jnp.float32)  # unnormalised on purpose
    target = N * _np_probs(lw)
    counts = np.asarray(_batch(name, _keys(zlib.crc32(name.encode()) % 2**31), lw)[0], np.float64)
    mean = counts.mean(axis=0)
    se = counts.std(axis=0, ddof=1) / math.sqrt(K)
    assert np.all(se > 0), se
    z = (mean - target) / se
    assert np.all(np.abs(z) < 5.0), dict(z=z.round(2), mean=mean, target=target)


# --------------------------------------------------------------------------- (d) reference implementation

_inverse_cdf = jax.jit(R.inverse_cdf)


@pytest.mark.parametrize("n", [1, N])
@pytest.mark.parametrize("seed", range(10))
def test_systematic_matches_filterpy(n, seed, monkeypatch):
    """Same uniform draw ⇒ same indices as ``filterpy``'s ``systematic_resample``.

    filterpy calls ``random()`` from the module namespace of
    ``filterpy.monte_carlo.resampling``; it is patched to return ``u``. Both
    sides run in float64 so that they see the same cumulative sums.
    """
    pytest.importorskip("filterpy")
    import filterpy.monte_carlo.resampling as fp

    rng = np.random.default_rng(1000 * n + seed)
    w = rng.dirichlet(np.full(n, 0.5))
    if seed == 0 and n > 1:
        w[1::3] = 0.0  # some zero weights too
        w /= w.sum()
    u = 0.0 if seed == 1 else float(rng.uniform())
    monkeypatch.setattr(fp, "random", lambda *args: u)
    expected = fp.systematic_resample(w)
    with jax.enable_x64(True):
        points = (u + np.arange(n, dtype=np.float64)) / n
        got = np.asarray(_inverse_cdf(jnp.asarray(points), jnp.asarray(w)))
    np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("n", [1, 7, 100, 500])
def test_batched_inverse_cdf_is_the_unbatched_one(n):
    """Under ``vmap`` (its binary searches become batched loops) the inverse CDF returns the unbatched
    indices, with batched or shared weights and points, zero weights too."""
    rng = np.random.default_rng(n)
    w = rng.dirichlet(np.full(n, 0.3), size=6).astype(np.float32)
    w[0, ::3] = 0.0
    u = rng.uniform(size=(6, n)).astype(np.float32)
    points = jnp.asarray((np.arange(n) + u) / n)  # stratified points
    one = jax.jit(R.inverse_cdf)
    expected = np.stack([np.asarray(one(points[b], jnp.asarray(w[b]))) for b in range(6)])
    np.testing.assert_array_equal(jax.jit(jax.vmap(R.inverse_cdf))(points, jnp.asarray(w)), expected)
    shared = jax.jit(jax.vmap(R.inverse_cdf, (0, None)))(points, jnp.asarray(w[3]))
    np.testing.assert_array_equal(shared[3], expected[3])


@pytest.mark.parametrize("name", NAMES)
def test_vmapped_schemes_equal_the_unbatched_ones(name):
    """A batch of runs resamples each run's weights with its own key exactly as one run would (the data-
    dependent loops of multinomial and residual run to the longest run's trip count)."""
    rng = np.random.default_rng(3)
    lw = jnp.asarray(np.log(rng.dirichlet(np.full(100, 0.3), size=4)), jnp.float32).at[0, ::3].set(-jnp.inf)
    keys = jax.random.split(jax.random.PRNGKey(1), 4)
    one = jax.jit(lambda k, l: R.SCHEMES[name](k, l, 100))
    batched = np.asarray(jax.jit(jax.vmap(one))(keys, lw))
    for b in range(4):
        np.testing.assert_array_equal(batched[b], one(keys[b], lw[b]))


def test_gradients_flow_through_a_resampling_step(getkey):
    """Indices carry no gradient; the particles' values do. (Jitted: run op by op, the gradient and
    its vmap compile every primitive on its own, 12.5 s with XLA's defaults against 2.4 s.)"""

    def loss(shift, key):
        lw = -0.5 * (jnp.linspace(-2.0, 2.0, 50) - shift) ** 2
        res = R.conditional_resample(key, jnp.linspace(-2.0, 2.0, 50) * shift, lw, threshold=1.0)
        return jnp.sum(res.particles)

    key = getkey()
    g = jax.jit(jax.grad(loss))(0.5, key)
    idx = jax.jit(R.systematic, static_argnums=2)(
        jax.random.split(key)[0], -0.5 * (jnp.linspace(-2.0, 2.0, 50) - 0.5) ** 2, 50
    )
    assert float(g) == pytest.approx(float(jnp.sum(jnp.linspace(-2.0, 2.0, 50)[idx])), rel=1e-5)
    gs = jax.jit(jax.vmap(jax.grad(loss), (None, 0)))(0.5, jax.random.split(key, 3))
    assert np.all(np.isfinite(np.asarray(gs)))


def test_inverse_cdf_edges():
    """Queries at 0 pick the first positive-weight particle; queries ≥ 1 are clamped."""
    w = jnp.array([0.0, 0.25, 0.0, 0.75, 0.0])
    idx = np.asarray(_inverse_cdf(jnp.array([0.0, 0.2499, 0.25, 0.9999, 1.0, 1.5]), w))
    np.testing.assert_array_equal(idx, [1, 1, 3, 3, 3, 3])


def test_get_resampler():
    for name in NAMES:
        assert R.get_resampler(name) is R.SCHEMES[name]
    with pytest.raises(ValueError, match="unknown"):
        R.get_resampler("bogus")


# --------------------------------------------------------------------------- (f) conditional resampling

_cond = jax.jit(R.conditional_resample, static_argnames=("scheme", "refresh", "angle_dims"))
_PARTICLES = jnp.arange(2 * N, dtype=jnp.float32).reshape(N, 2)


@settings(max_examples=40, deadline=None)
@given(
    lw=hnp.arrays(np.float32, N, elements=st.floats(-6.0, 6.0, width=32)),
    threshold=st.floats(0.05, 0.95),
    seed=st.integers(0, 2**31 - 1),
)
def test_conditional_resample_iff_ess_below_threshold(lw, threshold, seed):
    """Resampled iff ESS < threshold·N; otherwise particles, normalised weights
    and ``arange`` ancestors pass through unchanged."""
    p = _np_probs(lw)
    ess = 1.0 / np.sum(p**2)
    # Skip examples on the decision boundary, where float32 round-off of the
    # ESS (relative error ≪ 1e-4) may legitimately decide either way.
    if abs(ess - threshold * N) < 1e-4 * N:
        return
    res = _cond(jax.random.PRNGKey(seed), _PARTICLES, jnp.asarray(lw), threshold)
    assert bool(res.resampled) == (ess < threshold * N)
    if res.resampled:
        np.testing.assert_allclose(res.log_weights, np.full(N, -math.log(N)), rtol=1e-6)
        np.testing.assert_array_equal(res.particles, np.asarray(_PARTICLES)[np.asarray(res.ancestors)])
    else:
        np.testing.assert_array_equal(res.ancestors, np.arange(N))
        np.testing.assert_array_equal(res.particles, _PARTICLES)
        np.testing.assert_allclose(np.exp(res.log_weights), p, rtol=1e-5, atol=1e-7)


def test_conditional_resample_threshold_one_always_resamples(getkey):
    res = _cond(getkey(), _PARTICLES, jnp.zeros(N), 1.0)
    assert bool(res.resampled)
    # Uniform weights with systematic resampling: every particle exactly once.
    np.testing.assert_array_equal(np.sort(np.asarray(res.ancestors)), np.arange(N))


def test_conditional_resample_decides_per_run_under_vmap(getkey):
    """Under vmap the lax.cond becomes a select: each run decides for itself."""
    uniform = jnp.zeros(N)
    collapsed = jnp.full(N, -50.0).at[7].set(0.0)  # ESS ≈ 1
    lw = jnp.stack([uniform, collapsed])
    particles = jnp.stack([_PARTICLES, 100.0 + _PARTICLES])
    keys = jax.random.split(getkey(), 2)
    res = jax.jit(jax.vmap(lambda k, x, w: R.conditional_resample(k, x, w, 0.5)))(keys, particles, lw)
    np.testing.assert_array_equal(res.resampled, [False, True])
    np.testing.assert_array_equal(res.ancestors[0], np.arange(N))
    np.testing.assert_array_equal(res.particles[0], particles[0])
    np.testing.assert_array_equal(res.ancestors[1], np.full(N, 7))
    np.testing.assert_array_equal(res.particles[1], np.tile(np.asarray(particles[1, 7]), (N, 1)))
    np.testing.assert_allclose(res.log_weights, np.full((2, N), -math.log(N)), rtol=1e-6)


def test_conditional_resample_pytree_particles(getkey):
    """Every leaf of a pytree of particles is gathered with the same ancestors."""
    particles = {"pose": jnp.arange(3 * N, dtype=jnp.float32).reshape(N, 3), "id": jnp.arange(N)}
    lw = jnp.full(N, -jnp.inf).at[jnp.array([2, 5])].set(0.0)
    res = _cond(getkey(), particles, lw, 0.5, scheme="multinomial")
    assert bool(res.resampled)
    anc = np.asarray(res.ancestors)
    assert set(anc.tolist()) <= {2, 5}
    np.testing.assert_array_equal(res.particles["id"], anc)
    np.testing.assert_array_equal(res.particles["pose"], np.asarray(particles["pose"])[anc])


# --------------------------------------------------------------------------- gaussian refresh


@partial(jax.jit, static_argnames="angle_dims")
def _moments(particles, log_weights, angle_dims):
    return W.particle_mean(particles, log_weights, angle_dims), W.weighted_cov(particles, log_weights, angle_dims)


_refresh = jax.jit(R.gaussian_refresh, static_argnames=("angle_dims",))


def test_gaussian_refresh_preserves_moments_and_wraps_angles(getkey):
    """The refreshed cloud has the input's (weighted) mean and covariance within
    Monte Carlo error, and its heading stays in [-π, π) although the cloud
    straddles ±π.

    The output is n draws of N(μ̂, Σ̂), so (up to the negligible wrapping of a
    heading with sd 0.3 rad) its sample mean has SE √(Σ̂_jj/n) and a sample
    covariance entry has SE √((Σ̂_jj Σ̂_kk + Σ̂_jk²)/n); 5 SE per entry.
    """
    n = 20000
    rng = np.random.default_rng(3)
    true_cov = np.array([[1.0, 0.3, 0.05], [0.3, 0.5, 0.0], [0.05, 0.0, 0.09]])
    x = rng.multivariate_normal([2.0, -1.0, 3.0], true_cov, size=n)
    x[:, 2] = (x[:, 2] + np.pi) % (2 * np.pi) - np.pi
    particles = jnp.asarray(x, jnp.float32)
    lw = jnp.asarray(0.5 * rng.standard_normal(n), jnp.float32)
    mean_in, cov_in = (np.asarray(a, np.float64) for a in _moments(particles, lw, (2,)))
    new = _refresh(getkey(), particles, lw, angle_dims=(2,))
    assert new.shape == particles.shape and np.all(np.isfinite(np.asarray(new)))
    theta = np.asarray(new[:, 2])
    assert np.all((theta >= -np.pi) & (theta < np.pi))
    assert np.any(theta > 3.0) and np.any(theta < -3.0)  # it does straddle the cut
    mean_out, cov_out = (np.asarray(a, np.float64) for a in _moments(new, jnp.zeros(n), (2,)))
    dmean = mean_out - mean_in
    dmean[2] = (dmean[2] + np.pi) % (2 * np.pi) - np.pi
    se_mean = np.sqrt(np.diag(cov_in) / n)
    assert np.all(np.abs(dmean) < 5 * se_mean), (mean_out, mean_in, se_mean)
    d = np.diag(cov_in)
    se_cov = np.sqrt((np.outer(d, d) + cov_in**2) / n)
    assert np.all(np.abs(cov_out - cov_in) < 5 * se_cov), (cov_out, cov_in, se_cov)


@pytest.mark.parametrize("jitter", [1e-9, 0.0])
def test_gaussian_refresh_collapsed_cloud_has_no_nan(jitter, getkey):
    """All particles identical: the covariance is 0; with the default jitter the
    Cholesky factor exists, with none the diagonal fallback is used, and the
    output stays at the point (sd √jitter)."""
    n = 100
    point = np.array([1.5, -2.0, 3.14159], np.float32)
    particles = jnp.tile(jnp.asarray(point), (n, 1))
    new = np.asarray(_refresh(getkey(), particles, None, angle_dims=(2,), jitter=jitter))
    assert np.all(np.isfinite(new))
    assert np.all((new[:, 2] >= -np.pi) & (new[:, 2] < np.pi))
    diff = new.astype(np.float64) - point
    diff[:, 2] = (diff[:, 2] + np.pi) % (2 * np.pi) - np.pi
    # 6 sd of the jitter, plus float32 round-off of the weighted mean of n
    # equal values (recursive-summation bound (n + 2)·eps·|x|).
    assert np.all(np.abs(diff) < 6 * math.sqrt(jitter) + (n + 2) * EPS32 * np.abs(point).max())


def test_kernel_refresh_keeps_two_modes_where_the_gaussian_merges_them(getkey):
    """Two clusters at x = ±5 (sd 0.1). The kernel refresh moves each particle by N(0, h²Σ) with
    h = 0.37 (Silverman, N = 2000, d = 2) and Σ_xx ≈ 25: displacement sd ≈ 1.85, so most particles
    stay on their cluster's side and few land in |x| < 2.5. [A]'s one Gaussian N(0, 25) (negative
    control) puts ~38 % of the set there."""
    n = 2000
    rng = np.random.default_rng(0)
    x = np.concatenate([rng.normal(-5, 0.1, (n // 2, 2)), rng.normal(5, 0.1, (n // 2, 2))]).astype(np.float32)
    h = R.silverman_bandwidth(n, 2)
    assert h == pytest.approx((4 / (n * 4)) ** (1 / 6))
    kern = np.asarray(R.kernel_refresh(getkey(), jnp.asarray(x)))
    gauss = np.asarray(R.gaussian_refresh(getkey(), jnp.asarray(x)))
    # the kernel adds N(0, h² Σ) to each particle: displacement sd h·5.0 along x (Σ_xx ≈ 25)
    disp = kern[:, 0] - x[:, 0]
    assert np.std(disp) == pytest.approx(h * np.std(x[:, 0]), rel=0.1)  # MC: sd of an sd estimate ~1.6 %
    assert np.mean(np.sign(kern[:, 0]) == np.sign(x[:, 0])) > 0.7
    middle_k = np.mean(np.abs(kern[:, 0]) < 2.5)
    middle_g = np.mean(np.abs(gauss[:, 0]) < 2.5)
    # kernel: P(|N(±5, (1.85)²)| < 2.5) ≈ 0.09; Gaussian N(0, 25): P(|x| < 2.5) ≈ 0.38
    assert middle_k < 0.15 < 0.3 < middle_g


def test_refresh_option_of_conditional_resample(getkey):
    x = jnp.asarray(np.random.default_rng(1).normal(size=(500, 2)), jnp.float32)
    lw = jnp.full((500,), -jnp.inf).at[:3].set(0.0)  # three survivors: resampling happens
    for refresh in (False, True, "gaussian", "kernel"):
        res = R.conditional_resample(getkey(), x, lw, threshold=0.5, refresh=refresh)
        assert bool(res.resampled)
        distinct = np.unique(np.asarray(res.particles), axis=0).shape[0]
        assert distinct == (3 if refresh is False else 500), refresh
    with pytest.raises(ValueError, match="refresh"):
        R.conditional_resample(getkey(), x, lw, refresh="roughen")


@pytest.mark.parametrize("scheme", ["systematic", "stratified"])
def test_copy_ancestors_in_place_equals_take(scheme):
    """For the sorted ancestors of systematic/stratified resampling the in-place row copy
    equals ``x[ancestors]``; unsorted ancestors (residual) are outside its contract."""
    from jaxnav.core.resampling import SORTED_SCHEMES, copy_ancestors_in_place, get_resampler

    assert scheme in SORTED_SCHEMES
    rng = np.random.default_rng(1)
    x = jnp.asarray(rng.normal(size=(50, 7)), jnp.float32)
    y = jnp.asarray(rng.normal(size=(50, 2, 2)), jnp.float32)
    logw = jnp.asarray(rng.normal(0, 2, 50), jnp.float32)
    idx = get_resampler(scheme)(jax.random.PRNGKey(3), logw, 50)
    assert np.all(np.diff(np.asarray(idx)) >= 0)
    a, b = jax.jit(copy_ancestors_in_place)((x, y), idx)
    np.testing.assert_array_equal(np.asarray(a), np.asarray(x)[np.asarray(idx)])
    np.testing.assert_array_equal(np.asarray(b), np.asarray(y)[np.asarray(idx)])
