"""Static UHF-RFID tag localization ([A] Alg. 6, jaxnav.localization.rfid_tag).

The reads here are drawn straight from the sensor models of [A] §4.1.2 (light multipath: the
two-ray mean power times squared-Gamma fading with a large k, the phase with 0.1 rad noise), so the
filter's model is right and its errors are the filter's own. The reader drives two passes along x
at y = −0.3 m, at heights 0.5 and 1.5 m, facing the 2 × 3 × 2 m search box of [A] §5.2.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.localization import rfid_tag as rt
from jaxnav.models import uhf_rfid as U

T = 200
M = 2000
LAM = U.A_WAVELENGTH
GAMMA = U.GammaParams(20.0, 0.05)  # light multipath: mean fading power kθ = 1, k large
TAGS = np.array([[1.2, 1.4, 0.9], [0.6, 2.1, 1.4], [1.7, 0.8, 0.5]], np.float32)
OFFSETS = np.array([0.7, -2.0, 2.9], np.float32)
LATE = slice(3 * T // 4, T)


def _path():
    xs = np.linspace(-0.5, 2.5, T // 2)
    legs = [
        np.stack([x, np.full_like(x, -0.3), np.full_like(x, h), np.full_like(x, np.pi / 2)], 1)
        for x, h in ((xs, 0.5), (xs[::-1], 1.5))
    ]
    return np.concatenate(legs).astype(np.float32)


def _reads(key, tag, offset, path=None, phase_sd=0.1):
    """Light-multipath reads of ``tag`` along the path: [T, 1] slots."""
    path = jnp.asarray(_path() if path is None else path)
    k_fade, k_phase = jax.random.split(key)
    a = U.power_scale(path, jnp.asarray(tag), U.DEFAULT_CHANNEL)
    g = jax.random.gamma(k_fade, GAMMA.k, a.shape) * GAMMA.theta
    d = jnp.linalg.norm(path[:, :3] - jnp.asarray(tag), axis=1)
    ph = U.wrap_phase(-4 * jnp.pi * d / LAM + offset + phase_sd * jax.random.normal(k_phase, d.shape))
    n = path.shape[0]
    return U.UHFReads(
        path[:, None, :], (a * g * g)[:, None], ph[:, None], jnp.full((n, 1), LAM), jnp.ones((n, 1), bool)
    )


def _err(trace, tag, dims=3):
    return np.linalg.norm(np.asarray(trace.estimate)[:, :dims] - np.asarray(tag)[:dims], axis=-1)


@pytest.fixture(scope="module")
def params():
    return rt.default_params(gamma=GAMMA)


@pytest.fixture(scope="module")
def traces(params):
    """Three weightings × three seeds on tag 0 (one compilation per weighting)."""
    out = {}
    for w in rt.WEIGHTINGS:
        cfg = rt.RFIDTagConfig(num_particles=M, weighting=w)
        for seed in range(3):
            reads = _reads(jax.random.PRNGKey(seed), TAGS[0], OFFSETS[0])
            s0 = rt.init(jax.random.PRNGKey(100 + seed), cfg, params)
            out[w, seed] = rt.run(jax.random.PRNGKey(200 + seed), s0, cfg, params, reads)[1]
    return out


def test_light_multipath_3d_converges_below_20_cm(traces):
    """[A] §5.2.1 (light multipath, 3D): RMSE < 0.20 m for every weighting once converged
    (last quarter of the run, every seed); never degenerate."""
    for (w, seed), tr in traces.items():
        late = _err(tr, TAGS[0])[LATE]
        assert np.sqrt(np.mean(late**2)) < 0.20, (w, seed, late.max())
        assert not np.asarray(tr.degenerate).any()
        assert np.isfinite(np.asarray(tr.estimate)).all()


def test_phase_only_starts_worse_than_combined(traces):
    """[A] §5.2.1: "the accuracy when only phase is used is very low at the beginning". Over the
    first quarter (3 seeds), phase-only's mean error exceeds the combined filter's by 1.5× or more
    (measured ~0.28 against ~0.15 m)."""
    early = slice(10, T // 4)
    phase = np.mean([_err(traces["phase", s], TAGS[0])[early].mean() for s in range(3)])
    combined = np.mean([_err(traces["combined", s], TAGS[0])[early].mean() for s in range(3)])
    assert phase > 1.5 * combined, (phase, combined)


def test_the_phase_offset_is_estimated(traces):
    """Combined weights recover the cable offset θ_off together with the position. The two trade
    off: a range error ε shifts every predicted phase by 4πε/λ, so the bound is
    4π·ε_final/λ + 0.3 rad (0.3 rad: three times the 0.1 rad phase noise)."""
    for s in range(3):
        est = np.asarray(traces["combined", s].estimate)[-1]
        eps = float(np.linalg.norm(est[:3] - TAGS[0]))
        off_err = abs(np.angle(np.exp(1j * (est[3] - OFFSETS[0]))))
        assert off_err < 4 * np.pi * eps / LAM + 0.3, (s, off_err, eps)


def test_step_loop_equals_run(params):
    cfg = rt.RFIDTagConfig(num_particles=300, weighting="combined")
    reads = jax.tree.map(lambda x: x[:12], _reads(jax.random.PRNGKey(5), TAGS[1], OFFSETS[1]))
    s0 = rt.init(jax.random.PRNGKey(6), cfg, params)
    key = jax.random.PRNGKey(7)
    final, trace = rt.run(key, s0, cfg, params, reads)
    state = s0
    for t in range(12):
        state, info = rt.step(jax.random.fold_in(key, t), state, cfg, params, jax.tree.map(lambda x: x[t], reads))
        np.testing.assert_allclose(np.asarray(info.estimate), np.asarray(trace.estimate[t]), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(np.asarray(state.particles), np.asarray(final.particles), rtol=1e-5, atol=1e-6)


def test_masked_reads_change_nothing(params):
    """A step whose read slots are all masked keeps the particles and weights (the values in the
    masked slots are garbage on purpose: NaN-free but meaningless)."""
    cfg = rt.RFIDTagConfig(num_particles=300)
    s0 = rt.init(jax.random.PRNGKey(1), cfg, params)
    reads = jax.tree.map(lambda x: x[0], _reads(jax.random.PRNGKey(2), TAGS[0], OFFSETS[0]))
    blank = reads._replace(rssi=jnp.full((1,), 123.0), mask=jnp.zeros((1,), bool))
    s1, info = rt.step(jax.random.PRNGKey(3), s0, cfg, params, blank)
    np.testing.assert_array_equal(np.asarray(s1.particles), np.asarray(s0.particles))
    np.testing.assert_allclose(np.asarray(s1.log_weights), np.asarray(s0.log_weights), atol=1e-6)
    assert int(info.num_reads) == 0 and not bool(info.resampled) and float(info.log_likelihood) == 0.0


def test_refresh_draws_from_the_gaussian_of_the_weighted_set(params):
    """A resampling step redraws the set from N(μ, Σ) of the reweighed set (μ the step's estimate):
    with M = 20,000 the new set's mean is within 4 standard errors of μ and its covariance within 5 %
    of Σ entrywise (relative to the diagonal), and the weights are uniform."""
    m = 20_000
    cfg = rt.RFIDTagConfig(num_particles=m, ess_threshold=1.0)
    k1, k2, k3 = jax.random.split(jax.random.PRNGKey(8), 3)
    center = jnp.asarray([1.0, 1.5, 1.0, 0.5])
    particles = center + jax.random.normal(k1, (m, 4)) * jnp.asarray([0.1, 0.15, 0.08, 0.3])
    log_w = 2.0 * jax.random.normal(k2, (m,))  # a non-uniform prior weighting
    reads = jax.tree.map(lambda x: x[40], _reads(jax.random.PRNGKey(2), TAGS[0], OFFSETS[0]))
    state = rt.RFIDTagState(particles, log_w - jax.scipy.special.logsumexp(log_w))
    new, info = rt.step(k3, state, cfg, params, reads)
    assert bool(info.resampled)
    w = np.exp(np.asarray(state.log_weights + rt.log_likelihoods(cfg, params, particles, reads), np.float64))
    w /= w.sum()
    x = np.asarray(particles, np.float64)
    mu = w @ x
    mu[3] = np.arctan2(w @ np.sin(x[:, 3]), w @ np.cos(x[:, 3]))  # the offset's mean is on the circle
    np.testing.assert_allclose(np.asarray(info.estimate), mu, atol=1e-4)
    r = x - mu
    r[:, 3] = np.angle(np.exp(1j * r[:, 3]))
    cov = (w[:, None] * r).T @ r
    got = np.asarray(new.particles, np.float64)
    se = np.sqrt(np.diag(cov) / m)
    assert np.all(np.abs(got.mean(0) - mu) < 4 * se), (got.mean(0), mu, se)
    scale = np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    assert np.all(np.abs(np.cov(got.T) - cov) < 0.05 * scale), (np.cov(got.T), cov)
    np.testing.assert_allclose(np.asarray(new.log_weights), -np.log(m), rtol=1e-6)


def test_run_tags_vmaps_over_tags_like_separate_runs(params):
    """Three tags in one vmapped call: each tag's first step equals its own run's (same keys), and
    all localise. Later steps are not compared: vmapped reductions sum in another order, and the
    round-off changes systematic-resampling indices, after which two runs part like two seeds."""
    cfg = rt.RFIDTagConfig(num_particles=M)
    reads = [_reads(jax.random.PRNGKey(10 + g), TAGS[g], OFFSETS[g]) for g in range(3)]
    stacked = jax.tree.map(lambda *x: jnp.stack(x), *reads)
    key = jax.random.PRNGKey(42)
    finals, traces = rt.run_tags(key, cfg, params, stacked)
    assert traces.estimate.shape == (3, T, 4)
    for g in range(3):
        k_g = jax.random.fold_in(key, g)
        s0 = rt.init(jax.random.fold_in(k_g, 2**31 - 1), cfg, params)
        _, alone = rt.run(k_g, s0, cfg, params, reads[g])
        np.testing.assert_allclose(
            np.asarray(traces.estimate[g, 0]), np.asarray(alone.estimate[0]), rtol=1e-4, atol=1e-4
        )
        assert np.sqrt(np.mean(_err(jax.tree.map(lambda x: x[g], traces), TAGS[g])[LATE] ** 2)) < 0.20, g
        assert np.sqrt(np.mean(_err(alone, TAGS[g])[LATE] ** 2)) < 0.20, g


def test_run_composes_with_jit_and_vmap_over_seeds(params):
    """``run`` is callable inside ``jit``/``vmap`` (its host checks skip tracers): seeds vmapped
    over keys give the same first estimates as separate calls."""
    cfg = rt.RFIDTagConfig(num_particles=200)
    reads = _reads(jax.random.PRNGKey(5), TAGS[1], OFFSETS[1])
    short = jax.tree.map(lambda x: x[:5], reads)

    def one(key):
        return rt.run(key, rt.init(jax.random.fold_in(key, 1), cfg, params), cfg, params, short)[1].estimate

    keys = jax.random.split(jax.random.PRNGKey(0), 3)
    batched = jax.jit(jax.vmap(one))(keys)
    assert batched.shape == (3, 5, 4)
    for i in range(3):
        np.testing.assert_allclose(np.asarray(batched[i, 0]), np.asarray(one(keys[i])[0]), rtol=1e-4, atol=1e-4)


def test_2d_keeps_the_known_height_and_is_more_accurate(params, traces):
    """[A] §5.2.2: in 2D (z known) z never moves, and the late error is no larger than in 3D."""
    cfg = rt.RFIDTagConfig(num_particles=M, dims=2, weighting="combined")
    p2 = params._replace(tag_height=jnp.float32(TAGS[0, 2]))
    errs2, errs3 = [], []
    for seed in range(3):
        reads = _reads(jax.random.PRNGKey(seed), TAGS[0], OFFSETS[0])
        final, tr = rt.run(
            jax.random.PRNGKey(200 + seed), rt.init(jax.random.PRNGKey(100 + seed), cfg, p2), cfg, p2, reads
        )
        np.testing.assert_allclose(np.asarray(final.particles[:, 2]), TAGS[0, 2])
        errs2.append(_err(tr, TAGS[0])[LATE].mean())
        errs3.append(_err(traces["combined", seed], TAGS[0])[LATE].mean())
    assert np.mean(errs2) <= np.mean(errs3) + 0.01, (errs2, errs3)


def test_wrong_wavelength_is_worse_negative_control(params, traces):
    """Negative control: filtering the same reads with λ 10 % off (the phase model then predicts
    wrong spheres) ends farther from the tag than the right λ, for every seed."""
    cfg = rt.RFIDTagConfig(num_particles=M, weighting="phase")
    for seed in range(2):
        reads = _reads(jax.random.PRNGKey(seed), TAGS[0], OFFSETS[0])
        bad = reads._replace(wavelength=reads.wavelength * 1.1)
        s0 = rt.init(jax.random.PRNGKey(100 + seed), cfg, params)
        _, tr = rt.run(jax.random.PRNGKey(200 + seed), s0, cfg, params, bad)
        assert _err(tr, TAGS[0])[LATE].mean() > 2 * _err(traces["phase", seed], TAGS[0])[LATE].mean()


def test_likelihood_gradients_are_finite(params):
    """``jax.grad`` of the summed log-likelihood with respect to k, θ, σ_phase, λ and (with the
    smooth antenna) the particle positions is finite."""
    cfg = rt.RFIDTagConfig(num_particles=50, antenna_softness=0.05)
    reads = jax.tree.map(lambda x: x[50], _reads(jax.random.PRNGKey(0), TAGS[0], OFFSETS[0]))
    s0 = rt.init(jax.random.PRNGKey(1), cfg, params)

    def total(p, parts, lam):
        return jnp.sum(rt.log_likelihoods(cfg, p, parts, reads._replace(wavelength=lam)))

    gp, gx, gl = jax.grad(total, argnums=(0, 1, 2))(params, s0.particles, reads.wavelength)
    for leaf in (gp.gamma.k, gp.gamma.theta, gp.phase_sigma, gl, gx):
        assert np.all(np.isfinite(np.asarray(leaf)))
    assert np.any(np.asarray(gx) != 0)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(dims=4), "dims"),
        (dict(weighting="rss"), "weighting"),
        (dict(ess_threshold=0.0), "ess_threshold"),
        (dict(num_particles=0), "num_particles"),
        (dict(refresh="roughen"), "refresh"),
    ],
)
def test_bad_config_is_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        rt.RFIDTagConfig(**kwargs)


def test_bad_params_and_reads_are_refused(params):
    with pytest.raises(ValueError, match="positive volume"):
        rt.default_params(box_lo=(0, 0, 0), box_hi=(2, 0, 2))
    with pytest.raises(ValueError, match="phase_sigma"):
        rt.default_params(phase_sigma=0.0)
    with pytest.raises(ValueError, match="k"):
        rt.default_params(gamma=U.GammaParams(0.0, 1.0))
    cfg = rt.RFIDTagConfig(num_particles=10)
    s0 = rt.init(jax.random.PRNGKey(0), cfg, params)
    reads = _reads(jax.random.PRNGKey(0), TAGS[0], OFFSETS[0])
    with pytest.raises(ValueError, match="RSSI"):
        rt.run(jax.random.PRNGKey(0), s0, cfg, params, reads._replace(rssi=reads.rssi.at[3, 0].set(0.0)))
    with pytest.raises(ValueError, match=r"\[0, 2π\)"):
        rt.run(jax.random.PRNGKey(0), s0, cfg, params, reads._replace(phase=reads.phase - 4.0))
    with pytest.raises(ValueError, match="shape"):
        rt.step(jax.random.PRNGKey(0), s0, cfg, params, reads)  # [T, J] given to step
    # a masked slot may hold a zero RSSI: it is not a read
    ok = reads._replace(rssi=reads.rssi.at[3, 0].set(0.0), mask=reads.mask.at[3, 0].set(False))
    rt.run(jax.random.PRNGKey(0), s0, cfg, params, ok)
