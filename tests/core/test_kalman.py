"""Kalman core (jaxnav.core.kalman): EKF = UKF = exact Kalman filter = filterpy on a linear model.

The linear-Gaussian model is W4's: a 4-D constant-velocity state
``(x, y, vx, vy)``, 2-D position observations. For a linear model the EKF's
Jacobians are the matrices themselves and the unscented transform is exact,
so all three must give the exact Kalman posterior; float64 agreement to 1e-9
(relative) is a rounding-level check, float32 to 1e-4.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.core import kalman
from jaxnav.core.validation import check_covariance

DT = 0.1


def _model(dtype=np.float64):
    a = np.eye(4)
    a[0, 2] = a[1, 3] = DT
    q = 0.05 * np.array(
        [[DT**3 / 3, 0, DT**2 / 2, 0], [0, DT**3 / 3, 0, DT**2 / 2], [DT**2 / 2, 0, DT, 0], [0, DT**2 / 2, 0, DT]]
    )
    c = np.zeros((2, 4))
    c[0, 0] = c[1, 1] = 1.0
    r = np.diag([0.3**2, 0.2**2])
    return tuple(x.astype(dtype) for x in (a, q, c, r))


def _simulate(seed: int, steps: int):
    a, q, c, r = _model()
    rng = np.random.default_rng(seed)
    x = np.array([0.0, 0.0, 1.0, -0.5])
    zs = []
    for _ in range(steps):
        x = a @ x + rng.multivariate_normal(np.zeros(4), q)
        zs.append(c @ x + rng.multivariate_normal(np.zeros(2), r))
    return np.array(zs)


def _filterpy_run(zs):
    fp = pytest.importorskip("filterpy.kalman")
    a, q, c, r = _model()
    kf = fp.KalmanFilter(dim_x=4, dim_z=2)
    kf.x = np.zeros(4)
    kf.P = np.eye(4)
    kf.F, kf.Q, kf.H, kf.R = a, q, c, r
    means, covs, lls = [], [], []
    for z in zs:
        kf.predict()
        kf.update(z)
        means.append(kf.x.copy())
        covs.append(kf.P.copy())
        lls.append(kf.log_likelihood)
    return np.array(means), np.array(covs), np.array(lls)


@functools.cache
def _jax_run_cached(seed: int, steps: int, kind: str, dtype):
    """``_jax_run`` on ``_simulate(seed, steps)``, once per argument list (numpy outputs, read only)."""
    with jax.enable_x64(dtype == jnp.float64):
        out = _jax_run(_simulate(seed, steps), kind, dtype)
    for x in out:
        x.flags.writeable = False
    return out


def _jax_run(zs, kind: str, dtype):
    a, q, c, r = (jnp.asarray(m) for m in _model(dtype))
    weights = kalman.sigma_weights(4, alpha=0.5, beta=2.0, kappa=0.0, dtype=dtype)

    @jax.jit
    def run(zs):
        def body(g, z):
            if kind == "kf":
                prior = kalman.kalman_predict(g.mean, g.cov, a, q)
                res = kalman.kalman_update(prior.mean, prior.cov, z, c, r)
            elif kind == "ekf":
                prior = kalman.ekf_predict(g.mean, g.cov, lambda x: a @ x, q)
                res = kalman.ekf_update(prior.mean, prior.cov, z, lambda x: c @ x, r)
            else:
                prior, _ = kalman.ukf_predict(g.mean, g.cov, lambda x: a @ x, q, weights)
                res = kalman.ukf_update(prior.mean, prior.cov, z, lambda x: c @ x, r, weights=weights)
            return kalman.Gaussian(res.mean, res.cov), (res.mean, res.cov, res.log_likelihood)

        g0 = kalman.Gaussian(jnp.zeros(4, dtype), jnp.eye(4, dtype=dtype))
        return jax.lax.scan(body, g0, zs)[1]

    return tuple(np.asarray(x) for x in run(jnp.asarray(zs, dtype)))


@pytest.mark.parametrize("kind", ["kf", "ekf", "ukf"])
def test_linear_gaussian_matches_filterpy_float64(kind):
    zs = _simulate(0, 60)
    ref_m, ref_p, ref_ll = _filterpy_run(zs)
    m, p, ll = _jax_run_cached(0, 60, kind, jnp.float64)
    np.testing.assert_allclose(m, ref_m, rtol=1e-9, atol=1e-11)
    np.testing.assert_allclose(p, ref_p, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(ll, ref_ll, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("kind", ["ekf", "ukf"])
def test_linear_gaussian_float32_equals_exact_kf(kind):
    ref_m, ref_p, ref_ll = _jax_run_cached(1, 200, "kf", jnp.float64)
    m, p, ll = _jax_run_cached(1, 200, kind, jnp.float32)
    assert m.dtype == np.float32
    np.testing.assert_allclose(m, ref_m, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(p, ref_p, rtol=1e-3, atol=1e-6)
    np.testing.assert_allclose(ll, ref_ll, rtol=1e-4, atol=1e-3)
    # covariances stay symmetric positive definite in float32 over 200 steps
    assert np.all(np.linalg.eigvalsh(p) > 0)


def test_sequential_update_equals_joint_update():
    """Two scalar observations fused in turn = one 2-D update (independent noises, linear model)."""
    with jax.enable_x64(True):
        mean = jnp.asarray([0.3, -0.2, 1.0, 0.5])
        cov = jnp.asarray(np.diag([1.0, 2.0, 0.5, 0.5]) + 0.1)
        _, _, c, r = (jnp.asarray(m) for m in _model())
        z = jnp.asarray([0.7, -1.1])

        def h(x, aux):
            row, _ = aux
            return (row @ x)[None]

        @jax.jit  # one program rather than one per eager operation
        def both(mean, cov, z, c, r):
            joint = kalman.ekf_update(mean, cov, z, lambda x: c @ x, r)
            rows = (c, jnp.diag(r))
            g = kalman.Gaussian(mean, cov)
            for k in range(2):
                res = kalman.ekf_update(
                    g.mean, g.cov, z[k : k + 1], h, jnp.diag(r)[k][None, None], (rows[0][k], rows[1][k])
                )
                g = kalman.Gaussian(res.mean, res.cov)
            return joint, g

        joint, g = both(mean, cov, z, c, r)
        np.testing.assert_allclose(g.mean, joint.mean, rtol=1e-10)
        np.testing.assert_allclose(g.cov, joint.cov, rtol=1e-10, atol=1e-14)


def test_sequential_scan_equals_loop_and_skips_invalid():
    """ekf_update_sequential = a Python loop of ekf_update over the valid slots only."""
    with jax.enable_x64(True):
        mean = jnp.asarray([1.0, 2.0, 0.3])
        cov = jnp.diag(jnp.asarray([0.2, 0.3, 0.05]))
        landmarks = jnp.asarray([[4.0, 2.0], [1.0, 6.0], [-3.0, 0.0]])
        r = jnp.diag(jnp.asarray([0.1, 0.02]) ** 2)

        def h(x, m):
            d = m - x[:2]
            return jnp.stack([jnp.linalg.norm(d), jnp.arctan2(d[1], d[0]) - x[2]])

        zs = jnp.asarray([[3.1, -0.25], [jnp.nan, jnp.nan], [4.0, 2.9]])
        valid = jnp.asarray([True, False, True])

        @jax.jit  # one program rather than one per eager operation; both paths are in it
        def both(mean, cov, zs, r, landmarks, valid):
            seq = kalman.ekf_update_sequential(mean, cov, zs, h, r, landmarks, valid=valid, obs_angle_dims=(1,))
            g = kalman.Gaussian(mean, cov)
            for k in (0, 2):
                res = kalman.ekf_update(g.mean, g.cov, zs[k], h, r, landmarks[k], obs_angle_dims=(1,))
                g = kalman.Gaussian(res.mean, res.cov)
            return seq, g

        seq, g = both(mean, cov, zs, r, landmarks, valid)
        np.testing.assert_allclose(seq.mean, g.mean, rtol=1e-12)
        np.testing.assert_allclose(seq.cov, g.cov, rtol=1e-12)
        assert np.all(np.isfinite(seq.mean)) and seq.accepted.tolist() == [True, False, True]
        assert seq.nis[1] == 0.0


def test_bearing_residual_is_wrapped():
    """A bearing measured at +π − 0.01 against a prediction of −π + 0.01 is a 0.02 rad innovation, not 2π."""
    mean = jnp.asarray([0.0, 0.0, 0.0])
    cov = jnp.diag(jnp.asarray([0.01, 0.01, 0.01]))
    m = jnp.asarray([-5.0, -0.05])  # behind the robot, bearing ≈ −π + 0.01
    r = jnp.diag(jnp.asarray([0.1, 0.05]) ** 2)

    def h(x, lm):
        d = lm - x[:2]
        return jnp.stack([jnp.linalg.norm(d), jnp.arctan2(d[1], d[0]) - x[2]])

    z = jnp.asarray([5.0, math.pi - 0.01])
    res, unwrapped = jax.jit(  # one program rather than one per eager operation
        lambda mean, cov, z, r, m: (
            kalman.ekf_update(mean, cov, z, h, r, m, obs_angle_dims=(1,)),
            kalman.ekf_update(mean, cov, z, h, r, m),
        )
    )(mean, cov, z, r, m)
    assert float(res.nis) < 1.0
    assert float(unwrapped.nis) > 1000.0  # negative control: without wrapping the innovation is ~2π


def test_gate_rejects_outlier_and_reports_it():
    _, _, c, r = (jnp.asarray(m, jnp.float32) for m in _model(np.float32))
    mean, cov = jnp.zeros(4), jnp.eye(4)
    gate = kalman.chi2_gate(0.99, 2)
    update = jax.jit(  # one program (for both calls) rather than one per eager operation
        lambda mean, cov, z, c, r: kalman.ekf_update(mean, cov, z, lambda x: c @ x, r, gate=gate)
    )
    good = update(mean, cov, jnp.asarray([0.5, -0.5]), c, r)
    bad = update(mean, cov, jnp.asarray([50.0, 0.0]), c, r)
    assert bool(good.accepted) and not bool(bad.accepted)
    assert float(bad.nis) > gate
    np.testing.assert_array_equal(bad.mean, mean)
    np.testing.assert_array_equal(bad.cov, cov)
    assert float(bad.log_likelihood) == 0.0


def test_chi2_gate_quantiles():
    scipy_stats = pytest.importorskip("scipy.stats")
    for dof in (1, 2, 3, 5):
        for p in (0.9, 0.95, 0.99, 0.999):
            ref = scipy_stats.chi2.ppf(p, dof)
            assert abs(kalman.chi2_gate(p, dof) - ref) <= 1e-9 * ref
    with pytest.raises(ValueError, match="probability"):
        kalman.chi2_gate(1.0, 2)


def test_ukf_flags_failed_cholesky_without_nan():
    """An indefinite covariance cannot be factorised: the UKF flags it and returns finite numbers."""
    weights = kalman.sigma_weights(2)
    cov = jnp.asarray([[1.0, 2.0], [2.0, 1.0]])  # eigenvalues 3 and −1
    update = jax.jit(  # one program (for both calls) rather than one per eager operation
        lambda cov: kalman.ukf_update(
            jnp.zeros(2), cov, jnp.asarray([0.3]), lambda x: x[:1], jnp.eye(1) * 0.1, weights=weights
        )
    )
    res = update(cov)
    assert bool(res.cholesky_failed)
    assert np.all(np.isfinite(res.mean)) and np.all(np.isfinite(res.cov))
    ok = update(jnp.eye(2))
    assert not bool(ok.cholesky_failed)


def test_ukf_heading_mean_across_pi():
    """Sigma points of a heading at π spread over ±π; the predicted mean must stay at π, not 0."""
    weights = kalman.sigma_weights(3)
    mean = jnp.asarray([0.0, 0.0, math.pi - 1e-3])
    cov = jnp.diag(jnp.asarray([0.01, 0.01, 0.04]))
    prior, failed = jax.jit(  # one program rather than one per eager operation
        lambda mean, cov: kalman.ukf_predict(mean, cov, lambda x: x, jnp.zeros((3, 3)), weights, state_angle_dims=(2,))
    )(mean, cov)
    assert not bool(failed)
    assert abs(abs(float(prior.mean[2])) - math.pi) < 2e-3
    np.testing.assert_allclose(prior.cov, cov, rtol=1e-4, atol=1e-7)


def test_check_covariance_rejects_bad_matrices():
    check_covariance("P", np.eye(3), 3)
    with pytest.raises(ValueError, match="positive definite"):
        check_covariance("P", np.array([[1.0, 2.0], [2.0, 1.0]]))
    with pytest.raises(ValueError, match="symmetric"):
        check_covariance("P", np.array([[1.0, 0.5], [0.0, 1.0]]))
    with pytest.raises(ValueError, match="shape"):
        check_covariance("P", np.eye(3), 2)
    with pytest.raises(ValueError, match="NaN"):
        check_covariance("P", np.array([[np.nan, 0.0], [0.0, 1.0]]))


def test_sigma_weights_validation():
    with pytest.raises(ValueError, match="λ"):
        kalman.sigma_weights(3, alpha=0.1, kappa=-4.0)
    w = kalman.sigma_weights(4, alpha=0.5)
    np.testing.assert_allclose(float(jnp.sum(w.wm)), 1.0, rtol=1e-6)


# ---------------------------------------------------------------------------
# kalman_predict / kalman_update: the scalar form (float32, n, m ≤ 4) and the matrix form
# (float64, larger sizes) against a float64 NumPy Joseph filter over long runs


def _numpy_joseph_filter(m0, p0, zs, a, q, c, r):
    """float64 reference: predict, then the Joseph-form update with solves; one sequence."""
    m, p = np.asarray(m0, np.float64), np.asarray(p0, np.float64)
    means, covs, lls = [], [], []
    for z in zs:
        m, p = a @ m, a @ p @ a.T + q
        s = c @ p @ c.T + r
        k = np.linalg.solve(s, c @ p).T
        y = z - c @ m
        lls.append(-0.5 * (y @ np.linalg.solve(s, y) + np.linalg.slogdet(s)[1] + len(y) * math.log(2 * math.pi)))
        m = m + k @ y
        ikc = np.eye(len(m)) - k @ c
        p = ikc @ p @ ikc.T + k @ r @ k.T
        means.append(m)
        covs.append(p)
    return np.array(means), np.array(covs), np.array(lls)


def _standard_form_update(mean, cov, z, c, r):
    """The standard update ``P − K C P`` (symmetrised), for the negative control."""
    s = c @ cov @ c.T + r
    gain = jnp.linalg.solve(s, c @ cov).T
    return kalman.UpdateResult(
        mean + gain @ (z - c @ mean), kalman.symmetrize(cov - gain @ (c @ cov)), 0.0, 0.0, True, False
    )


def _kf_batch(m0, p0, zs, model, dtype, update=None):
    """``jit(vmap(scan))`` of kalman_predict + kalman_update (or ``update``) over ``[B, T, m]`` observations."""
    a, q, c, r = (jnp.asarray(x, dtype) for x in model)
    update = kalman.kalman_update if update is None else update

    def one(m, p, z_seq):
        def body(g, z):
            prior = kalman.kalman_predict(g.mean, g.cov, a, q)
            res = update(prior.mean, prior.cov, z, c, r)
            return kalman.Gaussian(res.mean, res.cov), (res.mean, res.cov, res.log_likelihood)

        return jax.lax.scan(body, kalman.Gaussian(m, p), z_seq)[1]

    out = jax.jit(jax.vmap(one))(*(jnp.asarray(x, dtype) for x in (m0, p0, zs)))
    return tuple(np.asarray(x) for x in out)


@functools.cache  # the NumPy reference is slow; the outputs are read only
def _long_run_inputs(b: int, steps: int, p0_scale: float = 1.0, r_scale: float = 1.0, seed: int = 5):
    """``b`` sequences of the W4 model with R scaled by ``r_scale``; P0 differs per sequence."""
    a, q, c, r = _model()
    r = r * r_scale
    rng = np.random.default_rng(seed)
    p0 = np.stack([np.diag([1.0, 1.0, 0.5, 0.5]) * p0_scale * s for s in rng.uniform(0.5, 2.0, b)])
    x = rng.normal(0.0, 1.0, (b, 4))
    m0 = x + rng.standard_normal((b, 4)) * np.sqrt(np.diagonal(p0, axis1=1, axis2=2))
    zs = np.empty((b, steps, 2))
    lq, lr = np.linalg.cholesky(q), np.linalg.cholesky(r)
    for t in range(steps):
        x = x @ a.T + rng.standard_normal((b, 4)) @ lq.T
        zs[:, t] = x @ c.T + rng.standard_normal((b, 2)) @ lr.T
    refs = [_numpy_joseph_filter(m0[i], p0[i], zs[i], a, q, c, r) for i in range(b)]
    ref = tuple(np.stack([x[k] for x in refs]) for k in range(3))
    for x in (m0, p0, zs, a, q, c, r, *ref):
        x.flags.writeable = False
    return (m0, p0, zs), (a, q, c, r), ref


def _cov_error(p, ref_p):
    """Largest covariance error relative to ``sqrt(P_ii P_jj)`` of the reference (a correlation scale)."""
    d = np.sqrt(np.diagonal(ref_p, axis1=-2, axis2=-1))
    return float(np.max(np.abs(p - ref_p) / (d[..., :, None] * d[..., None, :])))


@pytest.mark.parametrize("scalar_form", [False, True], ids=["matrix", "scalar"])
def test_kalman_long_run_float64_matches_numpy_joseph(scalar_form, monkeypatch):
    """Both forms in float64, 3 sequences × 1000 steps: the reference to rounding level (1e-9)."""
    monkeypatch.setattr(kalman, "_SCALAR_FORM_FLOAT64", scalar_form)
    inputs, model, (ref_m, ref_p, ref_ll) = _long_run_inputs(3, 1000)
    with jax.enable_x64(True):
        m, p, ll = _kf_batch(*inputs, model, jnp.float64)
    assert m.dtype == np.float64
    np.testing.assert_allclose(m, ref_m, rtol=0, atol=1e-9 * np.abs(ref_m).max())
    assert _cov_error(p, ref_p) < 1e-9
    np.testing.assert_allclose(ll, ref_ll, rtol=1e-9, atol=1e-9)


def test_kalman_long_run_float32_accurate_symmetric_positive_definite():
    """The float32 scalar form over 3 sequences × 2000 steps: close to the float64 reference, every
    covariance exactly symmetric and positive definite. The positions reach ~900 m, where float32
    numbers are 6e-5 m apart: an innovation error of that size moves a step's log-likelihood by
    ~1e-3 (its ``y²/R`` term, ``R`` down to 0.04 m²), hence the absolute bound 5e-3."""
    inputs, model, (ref_m, ref_p, ref_ll) = _long_run_inputs(3, 2000)
    m, p, ll = _kf_batch(*inputs, model, jnp.float32)
    assert m.dtype == np.float32 and p.dtype == np.float32
    np.testing.assert_allclose(m, ref_m, rtol=0, atol=1e-5 * np.abs(ref_m).max())
    assert _cov_error(p, ref_p) < 1e-4
    np.testing.assert_allclose(ll, ref_ll, rtol=1e-4, atol=5e-3)
    np.testing.assert_array_equal(p, np.swapaxes(p, -1, -2))
    assert np.all(np.linalg.eigvalsh(p.astype(np.float64)) > 0)


def test_kalman_float32_precise_observations_stay_positive_definite():
    """P0 × 10⁴, R × 10⁻⁴ (the first update shrinks the observed variances ~10⁸-fold, beyond
    float32's 7 digits): the float32 Joseph form keeps every covariance positive definite and
    close to the float64 reference (measured: smallest eigenvalue ≥ 0.89 of the reference's,
    covariance error 0.29 on the correlation scale). Negative control: the standard form
    ``P − K C P`` loses the covariance entirely (error 1.0; it also reached zero eigenvalues)."""
    inputs, model, (ref_m, ref_p, _) = _long_run_inputs(3, 2000, p0_scale=1e4, r_scale=1e-4)
    m, p, _ = _kf_batch(*inputs, model, jnp.float32)
    np.testing.assert_allclose(m, ref_m, rtol=0, atol=1e-4 * np.abs(ref_m).max())
    eig = np.linalg.eigvalsh(p.astype(np.float64))
    ref_eig = np.linalg.eigvalsh(ref_p)
    assert np.all(eig > 0)
    assert np.min(eig[..., 0] / ref_eig[..., 0]) > 0.5
    assert _cov_error(p, ref_p) < 0.6
    _, p_std, _ = _kf_batch(*inputs, model, jnp.float32, update=_standard_form_update)
    assert _cov_error(p_std, ref_p) > 0.9


@pytest.mark.parametrize("n,m", [(1, 1), (2, 1), (3, 2), (4, 2), (4, 3), (4, 4), (5, 2)])
def test_kalman_scalar_form_equals_ekf_update(n, m, monkeypatch):
    """Random sizes up to n = m = 4 (and n = 5, the matrix form): kalman_predict/kalman_update in
    either form equal ``A x``, ``A P Aᵀ + Q`` and ekf_update with ``h(x) = C x`` (float64, 1e-12);
    an invalid observation leaves the prior, with zero log-likelihood and NIS."""
    monkeypatch.setattr(kalman, "_SCALAR_FORM_FLOAT64", True)
    rng = np.random.default_rng(n * 10 + m)

    def spd(k):
        x = rng.standard_normal((k, k))
        return x @ x.T + 0.5 * np.eye(k)

    a, p, q, c, r = rng.standard_normal((n, n)), spd(n), spd(n), rng.standard_normal((m, n)), spd(m)
    mean, z = rng.standard_normal(n), rng.standard_normal(m)
    with jax.enable_x64(True):
        # One program per test (created after the monkeypatch, so it traces the scalar form) rather than
        # one per eager operation; ``valid`` is a traced argument, as in a jitted kalman_update call.
        @jax.jit
        def compute(mean, p, a, q, z_, c_, r_, invalid):
            prior = kalman.kalman_predict(mean, p, a, q)
            got = kalman.kalman_update(prior.mean, prior.cov, z_, c_, r_)
            ref = kalman.ekf_update(prior.mean, prior.cov, z_, lambda x: c_ @ x, r_)
            skipped = kalman.kalman_update(prior.mean, prior.cov, jnp.full(m, jnp.nan), c_, r_, invalid)
            return prior, got, ref, skipped

        prior, got, ref, skipped = compute(mean, p, a, q, z, c, r, jnp.asarray(False))
        np.testing.assert_allclose(prior.mean, a @ mean, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(prior.cov, a @ p @ a.T + q, rtol=1e-12, atol=1e-12)
        for name in ("mean", "cov", "nis", "log_likelihood"):
            np.testing.assert_allclose(getattr(got, name), getattr(ref, name), rtol=1e-12, atol=1e-12, err_msg=name)
        assert bool(got.accepted) and not bool(got.cholesky_failed)
        np.testing.assert_array_equal(skipped.mean, prior.mean)
        np.testing.assert_array_equal(skipped.cov, prior.cov)
        assert float(skipped.log_likelihood) == 0.0 and float(skipped.nis) == 0.0 and not bool(skipped.accepted)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_kalman_update_singular_innovation_stays_finite(dtype):
    """``P = 0``, ``R = 0``: ``S = 0`` cannot be factorised; as in ekf_update the jittered diagonal
    stands in, the gain is zero and the prior comes back, finite."""
    with jax.enable_x64(dtype == jnp.float64):
        n, m = 4, 2
        mean = jnp.arange(n, dtype=dtype)
        c = jnp.eye(m, n, dtype=dtype)
        res = jax.jit(  # one program rather than one per eager operation
            lambda mean, c: kalman.kalman_update(
                mean, jnp.zeros((n, n), dtype), jnp.ones(m, dtype), c, jnp.zeros((m, m), dtype)
            )
        )(mean, c)
        assert res.mean.dtype == dtype
        for x in (res.mean, res.cov, res.nis, res.log_likelihood):
            assert np.all(np.isfinite(np.asarray(x)))
        np.testing.assert_allclose(res.mean, mean)
