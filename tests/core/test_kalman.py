"""Kalman core (jaxnav.core.kalman): EKF = UKF = exact Kalman filter = filterpy on a linear model.

The linear-Gaussian model is W4's: a 4-D constant-velocity state
``(x, y, vx, vy)``, 2-D position observations. For a linear model the EKF's
Jacobians are the matrices themselves and the unscented transform is exact,
so all three must give the exact Kalman posterior; float64 agreement to 1e-9
(relative) is a rounding-level check, float32 to 1e-4.
"""

from __future__ import annotations

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
    with jax.enable_x64(True):
        m, p, ll = _jax_run(zs, kind, jnp.float64)
    np.testing.assert_allclose(m, ref_m, rtol=1e-9, atol=1e-11)
    np.testing.assert_allclose(p, ref_p, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(ll, ref_ll, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("kind", ["ekf", "ukf"])
def test_linear_gaussian_float32_equals_exact_kf(kind):
    zs = _simulate(1, 200)
    with jax.enable_x64(True):
        ref_m, ref_p, ref_ll = _jax_run(zs, "kf", jnp.float64)
    m, p, ll = _jax_run(zs, kind, jnp.float32)
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
        joint = kalman.ekf_update(mean, cov, z, lambda x: c @ x, r)

        def h(x, aux):
            row, _ = aux
            return (row @ x)[None]

        rows = (c, jnp.diag(r))
        g = kalman.Gaussian(mean, cov)
        for k in range(2):
            res = kalman.ekf_update(
                g.mean, g.cov, z[k : k + 1], h, jnp.diag(r)[k][None, None], (rows[0][k], rows[1][k])
            )
            g = kalman.Gaussian(res.mean, res.cov)
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
        seq = kalman.ekf_update_sequential(mean, cov, zs, h, r, landmarks, valid=valid, obs_angle_dims=(1,))
        g = kalman.Gaussian(mean, cov)
        for k in (0, 2):
            res = kalman.ekf_update(g.mean, g.cov, zs[k], h, r, landmarks[k], obs_angle_dims=(1,))
            g = kalman.Gaussian(res.mean, res.cov)
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
    res = kalman.ekf_update(mean, cov, z, h, r, m, obs_angle_dims=(1,))
    assert float(res.nis) < 1.0
    unwrapped = kalman.ekf_update(mean, cov, z, h, r, m)
    assert float(unwrapped.nis) > 1000.0  # negative control: without wrapping the innovation is ~2π


def test_gate_rejects_outlier_and_reports_it():
    _, _, c, r = (jnp.asarray(m, jnp.float32) for m in _model(np.float32))
    mean, cov = jnp.zeros(4), jnp.eye(4)
    gate = kalman.chi2_gate(0.99, 2)
    good = kalman.ekf_update(mean, cov, jnp.asarray([0.5, -0.5]), lambda x: c @ x, r, gate=gate)
    bad = kalman.ekf_update(mean, cov, jnp.asarray([50.0, 0.0]), lambda x: c @ x, r, gate=gate)
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
    res = kalman.ukf_update(jnp.zeros(2), cov, jnp.asarray([0.3]), lambda x: x[:1], jnp.eye(1) * 0.1, weights=weights)
    assert bool(res.cholesky_failed)
    assert np.all(np.isfinite(res.mean)) and np.all(np.isfinite(res.cov))
    ok = kalman.ukf_update(
        jnp.zeros(2), jnp.eye(2), jnp.asarray([0.3]), lambda x: x[:1], jnp.eye(1) * 0.1, weights=weights
    )
    assert not bool(ok.cholesky_failed)


def test_ukf_heading_mean_across_pi():
    """Sigma points of a heading at π spread over ±π; the predicted mean must stay at π, not 0."""
    weights = kalman.sigma_weights(3)
    mean = jnp.asarray([0.0, 0.0, math.pi - 1e-3])
    cov = jnp.diag(jnp.asarray([0.01, 0.01, 0.04]))
    prior, failed = kalman.ukf_predict(mean, cov, lambda x: x, jnp.zeros((3, 3)), weights, state_angle_dims=(2,))
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
