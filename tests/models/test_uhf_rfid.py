"""UHF-RFID sensor models ([A] §4.1.2, §4.3.1–4.3.2, App. A, C, D, E): jaxnav.models.uhf_rfid."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import special, stats
from scipy.optimize import brentq

from jaxnav.models import uhf_calibration
from jaxnav.models import uhf_rfid as U

TWO_PI = 2.0 * math.pi


# ----------------------------------------------------------------------------- units


def test_power_and_gain_unit_helpers():
    np.testing.assert_allclose(U.dbm_to_watt(30.0), 1.0, rtol=1e-6)
    np.testing.assert_allclose(U.dbm_to_watt(0.0), 1e-3, rtol=1e-6)
    np.testing.assert_allclose(U.dbm_to_watt(-70.0), 1e-10, rtol=1e-5)
    p = jnp.array([-80.0, -55.5, 0.0, 33.0])
    np.testing.assert_allclose(U.watt_to_dbm(U.dbm_to_watt(p)), p, atol=1e-4)
    np.testing.assert_allclose(U.db_to_linear(3.0), 1.9952623, rtol=1e-6)
    np.testing.assert_allclose(U.linear_to_db(U.db_to_linear(8.0)), 8.0, rtol=1e-6)
    np.testing.assert_allclose(U.DEFAULT_ANTENNA.g0, U.db_to_linear(8.0), rtol=1e-6)
    # [A]'s 0.173 m is (to 0.1 %) half the 866 MHz wavelength
    np.testing.assert_allclose(U.wavelength_from_frequency(866e6), 0.3461807, rtol=1e-6)
    assert abs(2 * U.A_WAVELENGTH / U.WAVELENGTH_866MHZ - 1) < 1e-3
    assert U.DEFAULT_WAVELENGTH == U.A_WAVELENGTH == 0.173


# ----------------------------------------------------------------------------- antenna


def _dir(az, el):
    return np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


def test_antenna_gain_in_each_lobe():
    p = U.DEFAULT_ANTENNA
    ps = p.phi_s
    psi = 0.7
    cases = []
    for sign in (1.0, -1.0):
        for frac, want in (
            (0.0, p.g0),
            (0.5, p.g0),
            (0.95, p.g0),
            (1.05, p.g_sll),
            (1.5, p.g_sll),
            (1.95, p.g_sll),
            (2.05, p.g_bll),
            (3.0, p.g_bll),
        ):
            cases.append((_dir(psi + sign * frac * ps, 0.0), want))  # azimuth offsets
            cases.append((_dir(psi, sign * frac * ps), want))  # elevation offsets
    cases.append((_dir(psi + math.pi, 0.0), p.g_bll))  # straight behind
    cases.append((np.array([0.0, 0.0, 1.0]), p.g_bll))  # straight up (γ = π/2 > 2φ_s = π/3)
    dirs = np.stack([c[0] for c in cases]) * 2.5  # any length
    want = np.array([c[1] for c in cases])
    got = U.antenna_gain(dirs, psi, p)
    np.testing.assert_allclose(got, want, rtol=1e-6)
    # a combined azimuth + elevation offset uses the angle to the boresight (a cone)
    d = _dir(psi + 0.8 * ps, 0.8 * ps)  # each offset is in the main lobe, γ ≈ 1.13 φ_s is not
    gamma = float(U.off_boresight_angle(d, psi))
    assert gamma > ps
    np.testing.assert_allclose(U.antenna_gain(d, psi, p), p.g_sll, rtol=1e-6)


def test_antenna_pattern_turns_with_heading(getkey):
    d = jax.random.normal(getkey(), (2000, 3))
    g_ref = U.antenna_gain(d, 0.0)
    for psi in (0.3, -2.0, 3.0):
        c, s = math.cos(psi), math.sin(psi)
        rot = jnp.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        gamma0 = U.off_boresight_angle(d, 0.0)
        np.testing.assert_allclose(U.off_boresight_angle(d @ rot.T, psi), gamma0, atol=2e-5)
        # ignore directions within 1e-4 rad of a lobe edge (float32 round-off may flip them)
        ps = U.DEFAULT_ANTENNA.phi_s
        far = (jnp.abs(gamma0 - ps) > 1e-4) & (jnp.abs(gamma0 - 2 * ps) > 1e-4)
        np.testing.assert_array_equal(np.asarray(U.antenna_gain(d @ rot.T, psi))[far], np.asarray(g_ref)[far])


def test_antenna_gain_equals_thesis_three_direction_angle_rule(getkey):
    """[A] §4.3.1 literally: direction angles of the tag in the antenna frame against the boresight's."""
    p = U.DEFAULT_ANTENNA
    ps = p.phi_s
    psi = -1.1
    d = np.asarray(jax.random.normal(getkey(), (20000, 3)), np.float64)
    c, s = math.cos(-psi), math.sin(-psi)
    local = d @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T  # into the antenna frame
    unit = local / np.linalg.norm(local, axis=1, keepdims=True)
    phi_t = np.arccos(np.clip(unit, -1, 1))  # (φ_T1, φ_T2, φ_T3)
    phi_ant = np.array([0.0, math.pi / 2, math.pi / 2])  # the antenna vector's direction angles
    dev = np.abs(phi_t - phi_ant)
    thesis = np.where(np.all(dev <= ps, axis=1), p.g0, np.where(np.any(dev > 2 * ps, axis=1), p.g_bll, p.g_sll))
    gamma = np.arccos(np.clip(unit[:, 0], -1, 1))
    far = (np.abs(gamma - ps) > 1e-4) & (np.abs(gamma - 2 * ps) > 1e-4)
    got = np.asarray(U.antenna_gain(jnp.asarray(d, jnp.float32), psi, p))
    np.testing.assert_allclose(got[far], thesis[far], rtol=1e-6)
    # all three lobes are represented in the sample
    assert {round(float(v), 4) for v in thesis} == {round(p.g0, 4), round(p.g_sll, 4), round(p.g_bll, 4)}


def test_soft_antenna_gain_tends_to_step_and_has_gradient():
    p = U.DEFAULT_ANTENNA
    psi = 0.2
    d = jnp.stack([_dir(psi + f * p.phi_s, 0.0) for f in (0.5, 1.5, 2.5)])
    for tau in (1e-2, 1e-3):
        np.testing.assert_allclose(U.antenna_gain(d, psi, p, softness=tau), [p.g0, p.g_sll, p.g_bll], rtol=1e-4)
    # the hard model has zero gradient, the soft one a finite, non-zero one near an edge
    edge = jnp.asarray(_dir(psi + 1.02 * p.phi_s, 0.0), jnp.float32)
    g_hard = jax.grad(lambda x: U.antenna_gain(x, psi, p))(edge)
    g_soft = jax.grad(lambda x: U.antenna_gain(x, psi, p, softness=0.05))(edge)
    np.testing.assert_array_equal(g_hard, 0.0)
    assert np.all(np.isfinite(g_soft)) and float(jnp.linalg.norm(g_soft)) > 1.0


# ----------------------------------------------------------------------------- path loss and power


def test_two_ray_path_loss_both_sides_of_the_breakpoint():
    with jax.enable_x64(True):
        lam, hr, ht = 0.173, 1.0, 0.5
        dc = 4 * math.pi * hr * ht / lam
        np.testing.assert_allclose(U.two_ray_breakpoint(hr, ht, lam), dc, rtol=1e-14)
        near = np.array([0.05, 0.3, 1.0, 0.999 * dc])
        far = np.array([dc, 1.001 * dc, 2 * dc, 50.0])
        np.testing.assert_allclose(
            U.two_ray_path_loss(near, hr, ht, lam), (lam / (4 * math.pi * near)) ** 2, rtol=1e-13
        )
        np.testing.assert_allclose(U.two_ray_path_loss(far, hr, ht, lam), (hr * ht / far**2) ** 2, rtol=1e-13)
        # continuity: both formulas equal (λ²/(16π² h_R h_T))² at D_c, so a jump of relative
        # size ε in D changes L by ≈ (2 + 4)ε; with ε = 1e-6 the step must stay below 1e-5
        at = (lam**2 / (16 * math.pi**2 * hr * ht)) ** 2
        np.testing.assert_allclose((lam / (4 * math.pi * dc)) ** 2, at, rtol=1e-13)
        np.testing.assert_allclose((hr * ht / dc**2) ** 2, at, rtol=1e-13)
        lo, hi = U.two_ray_path_loss(np.array([dc * (1 - 1e-6), dc * (1 + 1e-6)]), hr, ht, lam)
        assert abs(float(hi - lo)) / at < 1e-5
        # negative control: a breakpoint at the wrong place (λ/(2πD) scaling) is visibly discontinuous
        wrong_near = (lam / (2 * math.pi * dc)) ** 2
        assert abs(wrong_near - at) / at > 1.0
        # gradient finite at, below and above the breakpoint and at D = 0
        g = jax.vmap(jax.grad(lambda x: U.two_ray_path_loss(x, hr, ht, lam)))(jnp.array([0.0, 0.5 * dc, dc, 2 * dc]))
        assert np.all(np.isfinite(g))


def test_received_power_written_out():
    params = U.DEFAULT_CHANNEL
    reader = jnp.array([0.1, -0.2, 0.8, 0.3])
    # D_c = 4π h_R h_T/λ is ~35 m for tags at 0.6 m with λ = 0.173 m: indoors only tags near
    # the floor reach the plane-earth branch (the last two here)
    tags = jnp.array([[1.5, 0.2, 0.6], [0.5, 0.1, 0.9], [-2.0, 0.0, 0.02], [8.0, 2.5, 0.05]])
    a = U.power_scale(reader, tags, params)
    d = np.asarray(tags) - np.asarray(reader[:3])
    dist = np.linalg.norm(d, axis=1)
    g_r = np.asarray(U.antenna_gain(d, reader[3], params.antenna))
    lam = params.wavelength
    dc = 4 * math.pi * 0.8 * np.asarray(tags[:, 2]) / lam
    loss = np.where(dist < dc, (lam / (4 * math.pi * dist)) ** 2, (0.8 * np.asarray(tags[:, 2]) / dist**2) ** 2)
    want = params.tx_power * params.tag_efficiency * g_r**2 * params.tag_gain**2 * loss**2
    assert (dist < dc).any() and (dist >= dc).any()  # both two-ray branches are exercised
    np.testing.assert_allclose(a, want, rtol=1e-5)
    h2 = jnp.array([0.5, 1.0, 2.0, 0.1])
    np.testing.assert_allclose(U.received_power(reader, tags, params, h2), want * np.asarray(h2) ** 2, rtol=1e-5)
    gam = U.GammaParams(3.0, 0.2)
    np.testing.assert_allclose(U.mean_power(reader, tags, params, gam), want * 3 * 4 * 0.04, rtol=1e-5)
    # particles [M, 3] against one pose, and a per-read wavelength override
    a2 = U.power_scale(reader, tags, params, wavelength=jnp.full((4,), lam))
    np.testing.assert_allclose(a2, a, rtol=1e-6)


# ----------------------------------------------------------------------------- RSSI density


def _thesis_w_rssi(y, a, k, theta):
    """[A] §4.3.1 second line, written out: 1/(2θ^k Γ(k) a^{k/2}) y^{(k−2)/2} exp(−√y/(θ√a))."""
    return (
        1.0
        / (2.0 * theta**k * math.gamma(k) * a ** (k / 2))
        * y ** ((k - 2) / 2)
        * np.exp(-np.sqrt(y) / (theta * np.sqrt(a)))
    )


def _app_c(z, a, k, theta):
    """[A] App. C, first form: f_X(√(z/a)) / (2√(az)) with the Gamma(k, θ) density f_X."""
    x = np.sqrt(z / a)
    return x ** (k - 1) * np.exp(-x / theta) / (theta**k * math.gamma(k)) / (2 * np.sqrt(a * z))


GAMMA_CASES = [(0.7, 1.5, 1e-9), (1.0, 1.0, 1.0), (2.0, 0.5, 3e-7), (5.0, 0.2, 2e-10), (30.0, 0.04, 1e-6)]


@pytest.mark.parametrize("k,theta,a", GAMMA_CASES)
def test_log_w_rssi_equals_thesis_formula(k, theta, a):
    g = np.geomspace(1e-3, 8.0, 40) * k * theta  # around the Gamma mean kθ
    y = a * g**2
    ref = np.log(_thesis_w_rssi(y, a, k, theta))
    np.testing.assert_allclose(np.log(_app_c(y, a, k, theta)), ref, rtol=1e-12, atol=1e-12)
    # a third, independent form: scipy's Gamma log-density of g plus the Jacobian of y = a g²
    np.testing.assert_allclose(stats.gamma.logpdf(g, k, scale=theta) - np.log(2 * a * g), ref, rtol=1e-10, atol=1e-10)
    with jax.enable_x64(True):
        np.testing.assert_allclose(U.log_w_rssi(y, a, k, theta), ref, rtol=1e-12, atol=1e-10)
    # float32: log y ≈ −20 … −50 is summed with O(1) terms, so the absolute error is a few ulp of ~50
    np.testing.assert_allclose(U.log_w_rssi(jnp.asarray(y, jnp.float32), a, k, theta), ref, rtol=2e-6, atol=2e-4)


@pytest.mark.parametrize("k,theta,a", GAMMA_CASES)
def test_log_w_rssi_integrates_to_one(k, theta, a):
    """∫ f(y) dy = ∫ f(e^t) e^t dt by the trapezoid rule on a log grid (float64).

    The grid covers g = √(y/a) in [g_lo, g_hi]; the exact mass there is the Gamma CDF
    difference, and the mass outside is below 1e-8 by construction. 40,000 points on a
    smooth log-scale integrand give a quadrature error far below the 1e-6 tolerance.
    """
    g_lo = stats.gamma.ppf(1e-9, k, scale=theta)
    g_hi = stats.gamma.isf(1e-12, k, scale=theta)
    t = np.linspace(np.log(a * g_lo**2), np.log(a * g_hi**2), 40_000)
    with jax.enable_x64(True):
        f = np.exp(np.asarray(U.log_w_rssi(np.exp(t), a, k, theta)) + t)
    total = np.trapezoid(f, t)
    inside = stats.gamma.cdf(g_hi, k, scale=theta) - stats.gamma.cdf(g_lo, k, scale=theta)
    assert abs(total - inside) < 1e-6
    assert abs(total - 1.0) < 1e-6 + 2e-9


def test_monte_carlo_mean_and_score(getkey):
    """Samples y = a g², g ~ Gamma(k, θ): E[y] = a·k(k+1)θ² (the 2nd moment of g) within 5 SE.

    SE = √(Var y / n) with Var y = a²(E g⁴ − (E g²)²), E g⁴ = k(k+1)(k+2)(k+3)θ⁴. The score of
    the density, ∂ log f/∂(k, θ), has mean 0 under the samples (also within 5 SE): the sampler
    and log_w_rssi describe the same distribution.
    """
    k, theta, a, n = 2.0, 0.5, 2e-9, 200_000
    y = U.sample_rssi(getkey(), a, U.GammaParams(k, theta), (n,))
    assert y.shape == (n,) and bool(jnp.all(y > 0))
    m2 = k * (k + 1) * theta**2
    m4 = k * (k + 1) * (k + 2) * (k + 3) * theta**4
    se = a * math.sqrt((m4 - m2**2) / n)
    mean = float(jnp.mean(y.astype(jnp.float32)))
    assert abs(mean - a * m2) < 5 * se
    # negative control: the naive a·(E g)² = a·k²θ² is many SE away
    assert abs(mean - a * (k * theta) ** 2) > 50 * se
    score_fn = jax.vmap(jax.grad(lambda yy, kk, tt: U.log_w_rssi(yy, a, kk, tt), argnums=(1, 2)), (0, None, None))
    score = jax.jit(score_fn)(y, jnp.float32(k), jnp.float32(theta))
    for s in score:
        assert abs(float(jnp.mean(s))) < 5 * float(jnp.std(s)) / math.sqrt(n)


# ----------------------------------------------------------------------------- phase


def test_phase_model_range_period_and_broadcasting(getkey):
    lam = 0.173
    d = jax.random.uniform(getkey(), (1000,), minval=0.0, maxval=5.0)
    off = 1.3
    phi = U.phase(d, lam, off)
    assert bool(jnp.all((phi >= 0) & (phi < TWO_PI)))
    want = np.mod(-4 * np.pi * np.asarray(d, np.float64) / lam + off, TWO_PI)
    circ = np.abs(np.angle(np.exp(1j * (np.asarray(phi, np.float64) - want))))
    assert circ.max() < 2e-4  # float32: 4πD/λ up to 363 rad, ulp 3e-5
    # a distance change of λ/2 turns the phase once
    circ2 = np.abs(np.angle(np.exp(1j * np.asarray(U.phase(d + lam / 2, lam, off) - phi, np.float64))))
    assert circ2.max() < 4e-4
    # exactly-on-the-wrap inputs stay in [0, 2π)
    edge = U.wrap_phase(jnp.array([0.0, TWO_PI, -1e-9, TWO_PI - 1e-9, -TWO_PI, 7 * TWO_PI]))
    assert bool(jnp.all((edge >= 0) & (edge < TWO_PI)))
    # per-read wavelengths (channel hopping): particles [M, 1] against reads [1, T]
    lams = jnp.array([0.3448, 0.3452, 0.3460, 0.3468])[None, :]
    out = U.phase(d[:7, None], lams, off)
    assert out.shape == (7, 4)
    np.testing.assert_allclose(out[:, 2], U.phase(d[:7], 0.3460, off), atol=1e-5)


def _thesis_delta(phi_out, theta_m, dist, lam):
    """[A] §4.3.2 algorithm lines 1–4, literally (float64)."""
    phi_star = np.mod(np.mod(phi_out, TWO_PI) - theta_m, TWO_PI)
    rho_phi = lam * phi_star / (4 * np.pi)
    rho_d = np.mod(dist, lam / 2)
    rmax, rmin = np.maximum(rho_phi, rho_d), np.minimum(rho_phi, rho_d)
    return np.minimum(rmax - rmin, lam / 2 - (rmax - rmin))


def test_phase_distance_is_thesis_delta(getkey):
    lam = 0.173
    n = 5000
    phi_out = np.asarray(jax.random.uniform(getkey(), (n,), maxval=TWO_PI), np.float64) % TWO_PI
    theta_m = np.asarray(jax.random.uniform(getkey(), (n,), maxval=TWO_PI), np.float64)
    dist = np.asarray(jax.random.uniform(getkey(), (n,), minval=0.1, maxval=4.0), np.float64)
    ref = _thesis_delta(phi_out, theta_m, dist, lam)
    assert ref.min() >= 0 and ref.max() <= lam / 4 + 1e-12
    # [A]'s algorithm compares (φ − θ) with +4πD/λ: its Δ is ours against the prediction
    # (+4πD/λ + θ) mod 2π (module docstring, "Phase sign")
    pred_plus = np.mod(4 * np.pi * dist / lam + theta_m, TWO_PI)
    with jax.enable_x64(True):
        np.testing.assert_allclose(U.phase_distance(phi_out, pred_plus, lam), ref, atol=1e-12)
        # with §4.1.2's sign (our phase()), a noiseless read has Δ = 0 …
        phi_clean = np.asarray(U.phase(dist, lam, theta_m))
        np.testing.assert_allclose(U.phase_distance(phi_clean, U.phase(dist, lam, theta_m), lam), 0.0, atol=1e-12)
        # … whereas [A]'s algorithm fed the same read does not give 0 (its sign is inconsistent)
        assert np.mean(_thesis_delta(phi_clean, theta_m, dist, lam)) > 0.01


def test_phase_weight_symmetric_across_the_wrap():
    lam = 0.173
    sigma = U.DEFAULT_PHASE_SIGMA_FRACTION * lam
    eps = 0.02
    below, above = TWO_PI - eps, eps
    reads = jnp.array([below, above, math.pi], jnp.float32)
    d = U.phase_distance(reads, 0.0, lam)
    lw = U.log_w_phase(reads, 0.0, sigma, lam)
    np.testing.assert_allclose(d[0], d[1], rtol=1e-4)
    np.testing.assert_allclose(d[:2], lam * eps / (4 * np.pi), rtol=1e-4)
    np.testing.assert_allclose(lw[0], lw[1], atol=1e-5)  # float32 cancellation ~1e-6
    # the worst read (π away) sits λ/4 from the peak: log-weight lower by (λ/4)²/(2σ²) = 3.125
    np.testing.assert_allclose(d[2], lam / 4, rtol=1e-6)
    np.testing.assert_allclose(lw[0] - lw[2], ((lam / 4) ** 2 - d[0] ** 2) / (2 * sigma**2), rtol=1e-4)
    # normalised Gaussian density of Δ
    np.testing.assert_allclose(lw[2], stats.norm.logpdf(lam / 4, 0, sigma), atol=1e-5)
    # negative control: the raw phase difference (the metric [A] §4.2.3 criticises) ranks the
    # two near-identical reads far apart
    naive = -((np.array([below, above]) * lam / (4 * np.pi)) ** 2) / (2 * sigma**2)
    assert abs(naive[0] - naive[1]) > 5.0


# ----------------------------------------------------------------------------- gradients


def _fd(f, x, h):
    x = np.asarray(x, np.float64)
    out = np.zeros_like(x)
    for i in np.ndindex(x.shape):
        e = np.zeros_like(x)
        e[i] = h
        out[i] = (float(f(x + e)) - float(f(x - e))) / (2 * h)
    return out


def _check_grad(f, x, h=1e-6, rtol=1e-6, atol=1e-8):
    """Central differences, float64: truncation O(h²·f‴) ~1e-12, round-off ~1e-16·|f|/h ~1e-9."""
    g = np.asarray(jax.jit(jax.grad(f))(jnp.asarray(x, jnp.float64)))
    assert np.all(np.isfinite(g))
    np.testing.assert_allclose(g, _fd(jax.jit(f), x, h), rtol=rtol, atol=atol)
    return g


READER = np.array([0.2, -0.1, 0.9, 0.4])


@pytest.mark.parametrize("tag", [[1.2, 0.5, 0.7], [6.0, 2.8, 0.05]], ids=["near-branch", "far-branch"])
def test_grad_rssi_loglik_matches_finite_differences(tag):
    with jax.enable_x64(True):
        params = U.DEFAULT_CHANNEL
        tag = np.array(tag)
        d = tag - READER[:3]
        dist = np.linalg.norm(d)
        dc = float(U.two_ray_breakpoint(READER[2], tag[2], params.wavelength))
        assert (dist < dc) == (tag[0] < 2)  # the two cases sit on the two sides of D_c
        assert float(U.off_boresight_angle(d, READER[3])) < 0.8 * params.antenna.phi_s  # inside the main lobe
        k, theta = 2.5, 0.4
        y = float(U.power_scale(READER, tag, params)) * (k * theta * 1.3) ** 2

        def f_pos(x):
            return U.log_w_rssi(y, U.power_scale(READER, x, params), k, theta)

        g = _check_grad(f_pos, tag)
        assert np.linalg.norm(g) > 1e-3  # positions move the likelihood through L
        _check_grad(lambda kk: U.log_w_rssi(y, U.power_scale(READER, tag, params), kk, theta), k)
        _check_grad(lambda tt: U.log_w_rssi(y, U.power_scale(READER, tag, params), k, tt), theta)
        g_lam = _check_grad(
            lambda lam: U.log_w_rssi(y, U.power_scale(READER, tag, params._replace(wavelength=lam)), k, theta), 0.173
        )
        # far branch: L does not depend on λ (only the breakpoint does)
        assert (abs(float(g_lam)) > 1.0) == (dist < dc)
        # soft antenna near a lobe edge: gradients flow through G_R as well
        psi_edge = math.atan2(d[1], d[0]) - 1.05 * params.antenna.phi_s
        pose = np.array([*READER[:3], psi_edge])
        _check_grad(lambda x: U.log_w_rssi(y, U.power_scale(pose, x, params, softness=0.05), k, theta), tag)


def test_grad_phase_loglik_matches_finite_differences():
    with jax.enable_x64(True):
        lam, off, sigma = 0.173, 2.1, 0.1 * 0.173
        tag = np.array([1.1, 0.4, 0.6])
        dist = float(np.linalg.norm(tag - READER[:3]))
        # a measurement 0.6 rad from the prediction, in [0, 2π)
        phi_meas = float(np.mod(-4 * np.pi * dist / lam + off + 0.6, TWO_PI))

        def f(x, o=off, s=sigma, lm=lam):
            dd = jnp.linalg.norm(x - READER[:3])
            return U.log_w_phase(phi_meas, U.phase(dd, lm, o), s, lm)

        g = _check_grad(f, tag)
        assert np.linalg.norm(g) > 1.0
        _check_grad(lambda o: f(tag, o=o), off)
        _check_grad(lambda s: f(tag, s=s), sigma)
        _check_grad(lambda lm: f(tag, lm=lm), lam, h=1e-8, rtol=1e-5)  # dφ/dλ ~ 4πD/λ² ≈ 470


def test_gradients_are_finite_at_singular_points():
    params = U.DEFAULT_CHANNEL
    reader = jnp.array([0.0, 0.0, 1.0, 0.0])
    dc = float(U.two_ray_breakpoint(1.0, 1.0, params.wavelength))
    tags = jnp.array(
        [
            [0.0, 0.0, 1.0],  # at the reader: D = 0
            [2.0, 0.0, 1.0],  # on the boresight: |d × b| = 0
            [-2.0, 0.0, 1.0],  # straight behind
            [dc, 0.0, 1.0],  # on the two-ray breakpoint
            [0.0, 0.0, 0.0],  # straight below, on the ground: h_T = 0, so a = 0
        ]
    )
    for soft in (None, 0.05):
        f = lambda x: U.log_w_rssi(1e-9, U.power_scale(reader, x, params, softness=soft), 2.0, 0.5)  # noqa: E731
        vals = jax.jit(jax.vmap(f))(tags)
        g = jax.jit(jax.vmap(jax.grad(f)))(tags)
        assert np.all(np.isfinite(np.asarray(g))), (soft, g)
        # a = 0 cannot produce a read: weight −inf, not NaN
        assert np.all(np.isfinite(np.asarray(vals[:4]))) and float(vals[4]) == -math.inf
    # y = 0 or a = 0 under jit (values unchecked): −inf, no NaN in value or gradient
    lw = jax.jit(U.log_w_rssi)(jnp.array([0.0, 1e-9, 1e-9]), jnp.array([1e-9, 0.0, 1e-9]), 2.5, 0.5)
    assert lw.tolist()[:2] == [-math.inf, -math.inf] and math.isfinite(float(lw[2]))
    g = jax.grad(lambda a: jax.jit(U.log_w_rssi)(1e-9, a, 2.5, 0.5))(0.0)
    assert math.isfinite(float(g))
    ph = lambda x: U.log_w_phase(0.0, U.phase(jnp.linalg.norm(x - reader[:3] + 1e-12)), 0.02)  # noqa: E731
    assert np.all(np.isfinite(np.asarray(jax.jit(jax.vmap(jax.grad(ph)))(tags))))


# ----------------------------------------------------------------------------- (k, θ) estimation


N_BUF = 10_000  # one buffer size for every float32 estimator call (one compilation each)


def _anchor_reads(seed, k, theta, n=N_BUF, dtype=np.float32):
    """Anchor reads y_i = a_i g_i², g_i ~ Gamma(k, θ), with a different known a_i per read
    (the reader moves; a_i log-uniform over 1e-10…1e-8 W). Drawn with NumPy: jax.random.gamma
    compiles slowly for every new shape, and the sampler is tested on its own below."""
    rng = np.random.default_rng(seed)
    a = np.exp(rng.uniform(math.log(1e-10), math.log(1e-8), n))
    g = rng.gamma(k, theta, n)
    return jnp.asarray(a * g * g, dtype), jnp.asarray(a, dtype)


def test_stirling_remainder_bound_of_app_e():
    """App. E truncation: r(k) = 1/(2k) + 1/(12k²) − (ln k − ψ(k)) lies in (0, 1/(120 k⁴))."""
    k = np.geomspace(0.3, 100.0, 400)
    r = 1 / (2 * k) + 1 / (12 * k**2) - (np.log(k) - special.digamma(k))
    assert np.all(r > 0)
    assert np.all(r < 1 / (120 * k**4))
    # the bound is tight for large k (ratio → 1), so it is the right yardstick below
    assert r[-1] * 120 * k[-1] ** 4 > 0.99


@pytest.mark.parametrize("k", [0.8, 2.0, 5.0, 20.0])
def test_closed_form_within_stirling_error_of_exact_ml(k):
    with jax.enable_x64(True):
        y, a = _anchor_reads(int(k * 10), k, 0.3, n=2000, dtype=np.float64)
        cf = uhf_calibration.estimate_gamma_closed_form(y, a)
        ml = uhf_calibration.estimate_gamma_ml(y, a)
        u = np.sqrt(np.asarray(y) / np.asarray(a))
        ubar = u.mean()
        s = np.log(ubar) - np.log(u).mean()
        # the ML is exact: App. D's stationarity equations hold (θk = ū, ln k − ψ(k) = s),
        # and it agrees with a bracketing root-finder to 1e-6 relative. θk = ū to the
        # estimator's documented float64 precision (~1e-8 relative; 6e-9 measured at k = 20
        # with the suite's XLA flags, < 1e-9 with XLA's defaults: the L-BFGS path differs).
        k_star = brentq(lambda x: np.log(x) - special.digamma(x) - s, 1e-3, 1e6, xtol=1e-14)
        np.testing.assert_allclose(float(ml.k), k_star, rtol=1e-6)
        np.testing.assert_allclose(float(ml.k * ml.theta), ubar, rtol=2e-8)
        np.testing.assert_allclose(float(cf.k * cf.theta), ubar, rtol=1e-12)
        # the closed form solves App. E's equation exactly
        np.testing.assert_allclose(1 / (2 * cf.k) * (1 + 1 / (6 * cf.k)), s, rtol=1e-10)
        # 0 ≤ k̂_cf − k* ≤ bound (module docstring); the 1e-6·k* slack is the ML accuracy above
        diff = float(cf.k) - float(ml.k)
        bound = float(uhf_calibration.closed_form_error_bound(ml.k))
        assert -1e-6 * k_star <= diff <= bound + 1e-6 * k_star, (diff, bound)
        # and the bound is not vacuous: the error is at least half of it here
        assert diff > 0.5 * bound
        # ML maximises the likelihood: it is at least as high as at the closed form
        assert float(U.rssi_log_likelihood(y, a, ml)) >= float(U.rssi_log_likelihood(y, a, cf)) - 1e-9


def test_estimators_recover_parameters_and_improve_with_n():
    """k = 3, θ = 0.4 from reads with known per-read a_i.

    Asymptotic SDs (inverse Fisher information of Gamma(k, θ)): SD(k̂) = √(k/(N(kψ′(k) − 1))) =
    0.040 and SD(θ̂) = √(ψ′(k)θ²/(N(kψ′(k) − 1))) = 0.0058 at N = 10⁴. Each of 6 seeded runs must
    be within 4 SD for both estimators; the mean error at N = 10⁴ must be below a third of that
    at N = 100 (expected ratio √100 = 10). N = 100 is the first 100 reads of each buffer (masked).
    """
    k, theta = 3.0, 0.4
    kpsi = k * special.polygamma(1, k)
    sd_k = math.sqrt(k / (N_BUF * (kpsi - 1)))
    sd_t = math.sqrt(special.polygamma(1, k) * theta**2 / (N_BUF * (kpsi - 1)))
    errs = {100: [], N_BUF: []}
    for seed in range(6):
        y, a = _anchor_reads(100 + seed, k, theta)
        for n in errs:
            mask = jnp.arange(N_BUF) < n
            for est in (
                uhf_calibration.estimate_gamma_closed_form(y, a, mask),
                uhf_calibration.estimate_gamma_ml(y, a, mask),
            ):
                errs[n].append(abs(float(est.k) - k) / k)
                if n == N_BUF:
                    assert abs(float(est.k) - k) < 4 * sd_k and abs(float(est.theta) - theta) < 4 * sd_t, est
    assert np.mean(errs[N_BUF]) < np.mean(errs[100]) / 3, errs
    # negative control: ignoring the per-read path loss (one mean a for every read) adds
    # spread to u = √(y/a), and k̂ falls far outside its 4-SD band
    wrong = uhf_calibration.estimate_gamma_closed_form(y, jnp.full_like(a, jnp.mean(a)), jnp.ones(N_BUF, bool))
    assert abs(float(wrong.k) - k) > 10 * sd_k


def test_fallback_to_default_and_masks():
    y, a = _anchor_reads(7, 3.0, 0.4)
    # missing reads are masked; what they hold (0, NaN) must not matter
    junk = jnp.where(jnp.arange(N_BUF) % 2 == 0, 0.0, jnp.nan)
    for n_valid, expect_default in ((10, True), (29, True), (30, False), (40, False)):
        mask = jnp.arange(N_BUF) < n_valid
        yy = jnp.where(mask, y, junk)
        for method in ("closed_form", "ml"):
            fit = uhf_calibration.estimate_gamma(yy, a, mask, method=method)
            assert int(fit.n_valid) == n_valid and bool(fit.used_default) == expect_default
            if expect_default:
                assert (float(fit.params.k), float(fit.params.theta)) == U.DEFAULT_GAMMA
                continue
            ref = (
                uhf_calibration.estimate_gamma_closed_form
                if method == "closed_form"
                else uhf_calibration.estimate_gamma_ml
            )(y, a, mask)
            # the ML's float32 precision is ~1e-4 relative (its docstring); sampling SD here is ~15 %
            np.testing.assert_allclose(fit.params, ref, rtol=1e-5 if method == "closed_form" else 1e-3)
    # masked buffer = the compacted valid reads
    mask = jnp.arange(N_BUF) < 40
    np.testing.assert_allclose(
        uhf_calibration.estimate_gamma_closed_form(jnp.where(mask, y, junk), a, mask),
        uhf_calibration.estimate_gamma_closed_form(y[:40], a[:40]),
        rtol=1e-5,
    )
    # a custom default and threshold
    fit = uhf_calibration.estimate_gamma(y, a, jnp.arange(N_BUF) < 5, min_reads=6, default=U.GammaParams(7.0, 0.1))
    assert bool(fit.used_default) and float(fit.params.k) == 7.0
    # a degenerate sample (identical reads: s = 0, k̂ = ∞) also falls back
    same = jnp.full((N_BUF,), 1e-9)
    fit = uhf_calibration.estimate_gamma(same, jnp.full((N_BUF,), 1e-9), mask)
    assert bool(fit.used_default) and float(fit.params.k) == U.DEFAULT_GAMMA.k
    assert float(uhf_calibration.estimate_gamma_closed_form(same, jnp.full((N_BUF,), 1e-9), mask).k) == math.inf
    # inside jit, with traced masks: same result
    jit_fit = jax.jit(lambda yy, m: uhf_calibration.estimate_gamma(yy, a, m))(y, mask)
    np.testing.assert_allclose(jit_fit.params, uhf_calibration.estimate_gamma(y, a, mask).params, rtol=1e-6)
    # the masked log-likelihood ignores junk in masked slots
    ll = U.rssi_log_likelihood(jnp.where(mask, y, junk), a, U.GammaParams(3.0, 0.4), mask)
    np.testing.assert_allclose(ll, U.rssi_log_likelihood(y[:40], a[:40], U.GammaParams(3.0, 0.4)), rtol=1e-5)


# ----------------------------------------------------------------------------- validation


def test_bad_inputs_are_refused_with_clear_messages():
    with pytest.raises(ValueError, match="positive received power"):
        U.log_w_rssi(0.0, 1e-9, 2.0, 0.5)
    with pytest.raises(ValueError, match="positive received power"):
        U.log_w_rssi(jnp.array([1e-9, -1e-9]), 1e-9, 2.0, 0.5)
    with pytest.raises(ValueError, match="^k must be finite and strictly positive"):
        U.log_w_rssi(1e-9, 1e-9, 0.0, 0.5)
    with pytest.raises(ValueError, match="^theta must be finite and strictly positive"):
        U.log_w_rssi(1e-9, 1e-9, 2.0, -0.5)
    with pytest.raises(ValueError, match="^a must be finite and strictly positive"):
        U.log_w_rssi(1e-9, 0.0, 2.0, 0.5)
    with pytest.raises(ValueError, match="^wavelength must be finite and strictly positive"):
        U.phase(1.0, 0.0)
    with pytest.raises(ValueError, match="^wavelength must be finite and strictly positive"):
        U.two_ray_path_loss(1.0, 1.0, 1.0, -0.17)
    with pytest.raises(ValueError, match="^wavelength"):
        U.power_scale(READER, np.array([1.0, 0.0, 0.5]), U.DEFAULT_CHANNEL._replace(wavelength=0.0))
    with pytest.raises(ValueError, match=r"phi_meas must be a phase in \[0, 2π\)"):
        U.log_w_phase(TWO_PI, 0.0, 0.02)
    with pytest.raises(ValueError, match=r"phi_meas must be a phase in \[0, 2π\).*wrap_phase"):
        U.phase_distance(jnp.array([0.1, -0.1]), 0.0)
    with pytest.raises(ValueError, match="^sigma must be finite and strictly positive"):
        U.log_w_phase(1.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="reads.*positive received power"):
        uhf_calibration.estimate_gamma_closed_form(jnp.array([1e-9, 0.0, 2e-9]), 1e-9)
    with pytest.raises(ValueError, match="at least 2 valid reads"):
        uhf_calibration.estimate_gamma_closed_form(jnp.array([1e-9, 0.0, 2e-9]), 1e-9, jnp.array([True, False, False]))
    with pytest.raises(ValueError, match=r"mask must have shape \(3\)"):
        uhf_calibration.estimate_gamma(jnp.array([1e-9, 1e-9, 2e-9]), 1e-9, jnp.array([True, False]))
    with pytest.raises(ValueError, match="mask must be boolean"):
        uhf_calibration.estimate_gamma(jnp.array([1e-9, 1e-9, 2e-9]), 1e-9, jnp.array([1, 0, 1]))
    with pytest.raises(ValueError, match="method must be one of"):
        uhf_calibration.estimate_gamma(jnp.array([1e-9, 1e-9, 2e-9]), 1e-9, method="newton")
    with pytest.raises(ValueError, match="min_reads must be ≥ 2"):
        uhf_calibration.estimate_gamma(jnp.array([1e-9, 1e-9, 2e-9]), 1e-9, min_reads=1)
    with pytest.raises(ValueError, match=r"antenna.phi_s must be in \(0, π/2\]"):
        U.antenna_gain(np.ones(3), 0.0, U.DEFAULT_ANTENNA._replace(phi_s=2.0))
    with pytest.raises(ValueError, match="tag's height"):
        U.power_scale(READER, np.array([1.0, 0.0, -0.5]))
    with pytest.raises(ValueError, match=r"reader_pose must have shape \(\.\.\., 4\)"):
        U.power_scale(np.zeros(3), np.array([1.0, 0.0, 0.5]))
    with pytest.raises(ValueError, match=r"tag_efficiency must be in \(0, 1\]"):
        U.power_scale(READER, np.array([1.0, 0.0, 0.5]), U.DEFAULT_CHANNEL._replace(tag_efficiency=2.0))
    # value checks are skipped for tracers (as everywhere in jaxnav): no error inside jit
    out = jax.jit(U.log_w_rssi)(1e-9, 1e-9, -1.0, 0.5)
    assert out.shape == ()


def test_read_log_likelihood_equals_the_public_formulas():
    """The filters' fused hot path (log-domain power, angle-free lobe test, round-based wrap) gives
    Σ_j log_w_rssi(y_j, power_scale) + log_w_phase over the valid reads, computed in float64 from the
    public functions: tags in the main, side and back lobes, near and beyond the two-ray breakpoint,
    phases across the wrap, a masked slot. The filter path runs in float32: the phase argument
    |4πD/λ| reaches ~3000 rad (D ≈ 40 m), whose round-off (~4e-4 rad) moves a phase term by at most
    (λ/4πσ)²·π·4e-4 ≈ 2e-3 (λ = 0.33 m, σ = 0.02 m); atol is 5e-3 per read, rtol covers log a."""
    rng = np.random.default_rng(7)
    m, j = 64, 5
    reader = np.stack(
        [rng.uniform(-1, 3, j), rng.uniform(-1, 3, j), rng.uniform(0.3, 2.0, j), rng.uniform(-np.pi, np.pi, j)], -1
    )
    tags = np.stack([rng.uniform(-2, 4, m), rng.uniform(-2, 4, m), rng.uniform(0.1, 2.0, m)], -1)
    tags[:4] = reader[0, :3] + np.array([[30.0, 0.5, 0.0], [0.0, 25.0, 0.2], [-40.0, 1.0, 0.0], [1.0, -35.0, 0.1]])
    tags[:4, 2] = np.clip(tags[:4, 2], 0.1, None)
    offset = rng.uniform(-np.pi, np.pi, m)
    lam = np.array([0.173, 0.173, 0.33, 0.173, 0.33])
    rssi = 10 ** rng.uniform(-9, -4, j)
    phi = np.array([0.001, 6.282, 3.0, 1.0, 5.0])
    mask = np.array([True, True, True, False, True])
    gamma, sigma = U.GammaParams(3.0, 0.4), 0.02
    with jax.enable_x64(True):
        a = U.power_scale(
            jnp.asarray(reader)[None], jnp.asarray(tags)[:, None], U.DEFAULT_CHANNEL, wavelength=jnp.asarray(lam)
        )
        lo_d = np.linalg.norm(tags[:, None, :] - reader[None, :, :3], axis=-1)
        pred = U.phase(jnp.asarray(lo_d), jnp.asarray(lam), jnp.asarray(offset)[:, None])
        want = np.asarray(U.log_w_rssi(jnp.asarray(rssi), a, gamma.k, gamma.theta)) + np.asarray(
            U.log_w_phase(jnp.asarray(phi), pred, sigma, jnp.asarray(lam))
        )
        want = np.where(mask, want, 0.0).sum(-1)
    gain = np.asarray(U.antenna_gain(jnp.asarray(tags[:, None] - reader[None, :, :3]), jnp.asarray(reader[:, 3])))
    assert len(np.unique(np.round(gain, 6))) == 3  # all three lobes are exercised
    assert np.any(lo_d > np.asarray(U.two_ray_breakpoint(reader[None, :, 2], tags[:, None, 2], lam)))
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    channel, gam = U.read_model_float32(U.DEFAULT_CHANNEL, gamma)
    got = U.read_log_likelihood(
        f32(reader)[None],
        f32(tags)[:, None],
        f32(offset)[:, None],
        f32(rssi),
        f32(phi),
        f32(lam),
        jnp.asarray(mask),
        channel,
        gam,
        f32(sigma),
    )
    np.testing.assert_allclose(np.asarray(got), want, rtol=2e-4, atol=5e-3 * j)
