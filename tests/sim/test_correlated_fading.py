"""Spatially correlated fading of the UHF-RFID reader simulator: jaxnav.sim.uhf_reader, ``Multipath.correlation_length``.

The reads are drawn with both sensitivities at 0 (every read kept) and without
walls, so the fading is recovered exactly from them, ``g = √(y / a)``. The reads
of one call are ``N = T·J`` independent draws of the field (a fresh field per
read slot), so the tolerances are those of ``N`` i.i.d. samples: 4 standard
errors, each estimated from the samples themselves (:func:`_corr_and_se`), or
the 1 % critical value of the Kolmogorov–Smirnov distance. Speed: the module
fixture's two calls (independent and correlated fading) and the tag-order test
share one shape, so the file compiles the simulator four times.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import special

from jaxnav.models import uhf_rfid as U
from jaxnav.sim import uhf_reader as R

T, J = 25, 200  # N = 5 000 reads per tag
N = T * J
ELL = R.FADING_CORRELATION_LENGTH
ORIGIN = np.array([1.0, 1.0, 1.0])
# distances from ORIGIN in units of ℓ along x, and 0.5 ℓ along z (the field is isotropic)
OFFSETS = [np.zeros(3)] + [np.array([s * ELL, 0.0, 0.0]) for s in (0.25, 0.5, 1.0)] + [np.array([0.0, 0.0, 0.5 * ELL])]
TAGS = ORIGIN + np.stack(OFFSETS)
DISTANCES = np.linalg.norm(np.stack(OFFSETS), axis=1)
PATH = R.line_path([0.0, -0.5, 1.0], [2.0, -0.5, 1.0], T, facing=ORIGIN)
ZERO = dict(reads_per_step=J, sensitivity=0.0, tag_sensitivity=0.0)
# the strong preset's fading (k = 8, θ = 0.125) without its walls: y = a·g² exactly
STRONG_FADING = R.STRONG_MULTIPATH._replace(room=R.LIGHT_MULTIPATH.room)
KEY = jax.random.PRNGKey(20260601)


def _fading(reads, tags) -> np.ndarray:
    """``g [G, N]`` recovered from the RSSI of a wall-less multipath: ``y = a·g²``."""
    a = U.power_scale(jnp.asarray(PATH)[None], jnp.asarray(tags, jnp.float32)[:, None], U.DEFAULT_CHANNEL)  # [G, T]
    return np.sqrt(np.asarray(reads.rssi, np.float64) / np.asarray(a, np.float64)[..., None]).reshape(len(tags), -1)


def _corr_and_se(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Pearson correlation and its standard error by the delta method on the sample moments.

    Valid for any distribution with finite fourth moments (the fading's are), unlike
    ``(1 − r²)/√N``, which holds for Gaussian pairs only.
    """
    x = (x - x.mean()) / x.std()
    y = (y - y.mean()) / y.std()
    r = float(np.mean(x * y))
    # influence function of the correlation coefficient (standardised variables)
    psi = x * y - 0.5 * r * (x * x + y * y)
    return r, float(psi.std() / math.sqrt(x.size))


def _ks_gamma(u, k, th) -> float:
    u = np.sort(np.asarray(u, np.float64))
    cdf = special.gammainc(float(k), u / float(th))
    i = np.arange(1, u.size + 1)
    return max(np.max(i / u.size - cdf), np.max(cdf - (i - 1) / u.size))


@pytest.fixture(scope="module")
def reads():
    """Reads of TAGS with the strong preset's fading, independent and correlated, one key."""
    off = R.simulate_reads(KEY, PATH, TAGS, multipath=STRONG_FADING, **ZERO)
    on = R.simulate_reads(KEY, PATH, TAGS, multipath=R.correlated_fading(STRONG_FADING), **ZERO)
    return off, on, _fading(off, TAGS), _fading(on, TAGS)


def test_off_by_default_and_the_option_changes_the_rssi_only(reads):
    """The presets carry no correlation length and a Multipath built from its three original fields is
    the preset, so every existing call takes the independent path. With the option, the phase noise and
    the read losses keep their keys: only the RSSI changes."""
    for mp in R.MULTIPATH_NAMES.values():
        assert mp.correlation_length is None
    assert R.Multipath(*R.STRONG_MULTIPATH[:3]) == R.STRONG_MULTIPATH  # off unless asked for
    off, on, _, _ = reads
    for name in ("phase", "mask", "reader", "wavelength"):
        np.testing.assert_array_equal(np.asarray(getattr(off, name)), np.asarray(getattr(on, name)))
    assert not np.allclose(np.asarray(off.rssi), np.asarray(on.rssi))


def test_fading_correlation_falls_with_distance_as_specified(reads):
    """The empirical correlation of g at ORIGIN and at each tag matches fading_correlation(d) within
    4 standard errors (SE about 0.012 at N = 5 000); it falls from 1 to the 1/N floor by d = ℓ = λ/2.
    Negative control: the independent fading is uncorrelated even at 0.25 ℓ."""
    _, _, g_off, g_on = reads
    k = float(R.STRONG_MULTIPATH.gamma.k)
    model = np.asarray(R.fading_correlation(DISTANCES, k))
    np.testing.assert_allclose(model[[0, 3]], [1.0, 1.0 / R.FADING_WAVES], atol=1e-6)  # ρ(0) = 1, ρ(ℓ) = 0
    rows = []
    for i in range(1, len(TAGS)):
        r, se = _corr_and_se(g_on[0], g_on[i])
        rows.append((DISTANCES[i] / ELL, r, float(model[i]), se))
    print("(d/ℓ, empirical, model, SE):", [tuple(round(v, 4) for v in row) for row in rows])
    for _, r, m, se in rows:
        assert abs(r - m) < 4 * se
    assert rows[0][1] > 0.6 and rows[2][1] < 0.08  # 0.25 ℓ: strongly correlated; ℓ: nearly independent
    assert rows[0][1] > rows[1][1] > rows[2][1]
    r_iso, se_iso = rows[3][1], rows[3][3]  # 0.5 ℓ along z against 0.5 ℓ along x
    assert abs(r_iso - rows[1][1]) < 4 * math.hypot(se_iso, rows[1][3])
    r_off, se_off = _corr_and_se(g_off[0], g_off[1])
    assert abs(r_off) < 4 * se_off


def test_marginal_fading_is_the_presets_gamma(reads):
    """At every tag g ~ Gamma(8, 0.125) (the strong preset's): KS distance below its 1 % critical
    value 1.63/√N, and the mean kθ within 4 standard errors √(k θ²/N)."""
    _, _, _, g_on = reads
    k, th = float(R.STRONG_MULTIPATH.gamma.k), float(R.STRONG_MULTIPATH.gamma.theta)
    crit = 1.63 / math.sqrt(N)
    for g in g_on:
        assert _ks_gamma(g, k, th) < crit
        assert abs(g.mean() - k * th) < 4 * math.sqrt(k * th * th / N)


def test_fractional_k_keeps_the_gamma_marginal_and_its_correlation():
    """k = 2.5, traced (so ``fading_fields`` = 3 is given): m = 3 fields times B ~ Beta(2.5, 0.5). The
    marginal is Gamma(2.5, θ) (KS below the 1 % critical value 1.63/√N) and the correlation beyond ℓ
    keeps the floor (m − k)/(m + 1) = 0.125 (plus the 1/N term), within 4 standard errors."""
    tags = np.stack([ORIGIN, ORIGIN + [2.0 * ELL, 0.0, 0.0]])
    base = R.correlated_fading("light")

    @jax.jit
    def simulate(k):
        mp = base._replace(gamma=U.GammaParams(k, jnp.float32(0.4)))
        return R.simulate_reads(KEY, PATH, tags, multipath=mp, fading_fields=3, **ZERO)

    g = _fading(simulate(jnp.float32(2.5)), tags)
    for x in g:
        assert _ks_gamma(x, 2.5, 0.4) < 1.63 / math.sqrt(N)
    r, se = _corr_and_se(g[0], g[1])
    model = float(R.fading_correlation(2.0 * ELL, 2.5))
    assert model == pytest.approx(0.125 + 3.5 / 4.0 / R.FADING_WAVES, abs=1e-6)  # ρ(2ℓ) = 0
    print(f"k = 2.5 at 2ℓ: empirical {r:.4f}, model {model:.4f}, SE {se:.4f}")
    assert abs(r - model) < 4 * se
    with pytest.raises(ValueError, match="fading_fields"):  # a traced k and no number of fields
        jax.jit(lambda k: R.simulate_reads(KEY, PATH, tags, multipath=base._replace(gamma=U.GammaParams(k, 0.4))))(2.5)


def test_a_tags_reads_do_not_depend_on_the_other_tags(reads):
    """The field is drawn once per read slot for all tags from a key no tag id reaches: with the other
    tags moved and the order reversed (the ids following the tags), tag 0's reads are unchanged."""
    _, on, _, _ = reads
    moved = TAGS.copy()
    moved[1:] += [0.3, 0.2, 0.1]
    other = R.simulate_reads(
        KEY, PATH, moved[::-1], multipath=R.correlated_fading(STRONG_FADING), tag_ids=np.arange(5)[::-1], **ZERO
    )
    np.testing.assert_array_equal(np.asarray(on.rssi)[0], np.asarray(other.rssi)[4])
    assert not np.array_equal(np.asarray(on.rssi)[1], np.asarray(other.rssi)[3])  # tag 1 moved: its reads did


def test_differentiable_in_positions_and_the_correlation_length():
    """d/dℓ and d/dp of Σ log y are finite; d/dℓ agrees with a central difference (same key: the reads
    are smooth in ℓ). A typed key."""
    path = PATH[:8]
    tags = jnp.asarray(TAGS[:2], jnp.float32)
    key = jax.random.key(11)
    base = R.correlated_fading(R.LIGHT_MULTIPATH._replace(gamma=U.GammaParams(3.0, 1.0 / 3.0)))

    def f(tags, ell):
        r = R.simulate_reads(key, path, tags, multipath=base._replace(correlation_length=ell), reads_per_step=2)
        return jnp.sum(jnp.log(r.rssi))

    vg = jax.jit(jax.value_and_grad(f, argnums=(0, 1)))  # one compilation for the gradient and the differences
    _, (g_tags, g_ell) = vg(tags, jnp.float32(ELL))
    assert np.all(np.isfinite(np.asarray(g_tags))) and np.isfinite(float(g_ell)) and float(g_ell) != 0.0
    h = 1e-3 * ELL
    fd = (vg(tags, jnp.float32(ELL + h))[0] - vg(tags, jnp.float32(ELL - h))[0]) / (2 * h)
    np.testing.assert_allclose(float(g_ell), float(fd), rtol=2e-2)


def test_bad_correlated_fading_inputs_are_refused():
    key = jax.random.PRNGKey(0)
    tag = TAGS[:1]
    with pytest.raises(ValueError, match="correlation_length"):
        R.correlated_fading("strong", 0.0)
    with pytest.raises(ValueError, match="correlation_length"):
        R.get_multipath(R.STRONG_MULTIPATH._replace(correlation_length=np.array([0.1, 0.2])))
    with pytest.raises(ValueError, match="fading_fields"):
        R.simulate_reads(key, PATH, tag, multipath=R.correlated_fading("strong"), fading_fields=7)  # < k = 8
    with pytest.raises(ValueError, match="fading_waves"):
        R.simulate_reads(key, PATH, tag, multipath=R.correlated_fading("strong"), fading_waves=0)
    with pytest.raises(ValueError, match="distance"):
        R.fading_correlation(-1.0, 8.0)
