"""EKF and UKF localization (jaxnav.localization.ekf / ukf) on simulated landmark worlds."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.core.kalman import chi2_gate
from jaxnav.localization import ekf, ukf
from jaxnav.models import landmarks as lm
from jaxnav.models import motion
from jaxnav.sim import landmark_world as lw
from jaxnav.sim import trajectories

LANDMARKS = lw.square_room_landmarks(10.0, 8)
MOTION = motion.VelocityNoise(jnp.asarray([0.01, 0.005, 0.005, 0.01, 0.0, 0.0]), jnp.asarray([0.01, 0.01, 0.005]))
SENSOR = lm.RangeBearingNoise(jnp.asarray([0.1, 0.03]))
X0 = jnp.asarray([5.0, 2.0, 0.0])
P0 = jnp.diag(jnp.asarray([0.01, 0.01, 0.001]))
STEPS = 150


def _simulate(key, steps=STEPS):
    u = trajectories.loop_controls(steps)
    x0 = X0 + jax.random.normal(jax.random.fold_in(key, 1), (3,)) * jnp.sqrt(jnp.diag(P0))
    return lw.simulate(key, LANDMARKS, x0, u, MOTION, SENSOR)


def _errors(estimate, truth):
    e = np.array(estimate - truth, np.float64)
    e[..., 2] = (e[..., 2] + np.pi) % (2 * np.pi) - np.pi
    return e


@pytest.mark.parametrize("module, config", [(ekf, ekf.EKFConfig()), (ukf, ukf.UKFConfig())])
def test_nees_and_nis_are_consistent(module, config, getkey):
    """NEES/NIS within χ² bounds (Bar-Shalom et al. 2001, §5.4).

    R = 40 independent runs. At each step the average NEES over runs, times
    R, is χ²(3R) if the filter is consistent; the two-sided 95 % interval
    must hold at ≥ 85 % of the steps (95 % expected; linearisation and the
    correlation between steps cost a little). The pooled NIS over every
    fused observation must be within the 99 % interval of χ²(2·count)/count.
    Negative control: the same filter told the sensor is 4× more precise
    than it is fails both checks.
    """
    runs = 40
    keys = jax.random.split(getkey(), runs)
    sims = jax.vmap(_simulate)(keys)
    params = ekf.KalmanParams(MOTION, SENSOR, LANDMARKS)
    overconfident = params._replace(sensor=lm.RangeBearingNoise(SENSOR.sd / 4))

    def filt(p, sim):
        return module.run(None, module.init(None, config, p, X0, P0), config, p, sim.controls, sim.observations)[1]

    lo, hi = chi2_gate(0.025, 3 * runs) / runs, chi2_gate(0.975, 3 * runs) / runs

    def checks(p):
        tr = jax.vmap(lambda s: filt(p, s))(sims)
        e = _errors(tr.estimate, sims.true_poses)
        nees = np.einsum("rti,rtij,rtj->rt", e, np.linalg.inv(np.asarray(tr.cov, np.float64)), e)
        anees = nees.mean(axis=0)
        frac = np.mean((anees >= lo) & (anees <= hi))
        count = int(np.sum(tr.accepted))
        mean_nis = float(np.sum(tr.nis)) / count
        nis_ok = chi2_gate(0.005, 2 * count) / count <= mean_nis <= chi2_gate(0.995, 2 * count) / count
        return frac, mean_nis, nis_ok

    frac, mean_nis, nis_ok = checks(params)
    assert frac >= 0.85, f"ANEES inside its 95% band at only {frac:.0%} of steps"
    assert nis_ok, f"mean NIS {mean_nis:.3f} outside the χ² band around 2"
    frac_bad, mean_nis_bad, nis_ok_bad = checks(overconfident)
    assert frac_bad < 0.5 and not nis_ok_bad, (frac_bad, mean_nis_bad)


def test_ekf_and_ukf_agree_on_mildly_nonlinear_problem(getkey):
    sim = _simulate(getkey())
    params = ekf.KalmanParams(MOTION, SENSOR, LANDMARKS)
    a = ekf.run(
        None, ekf.init(None, ekf.EKFConfig(), params, X0, P0), ekf.EKFConfig(), params, sim.controls, sim.observations
    )[1]
    b = ukf.run(
        None, ukf.init(None, ukf.UKFConfig(), params, X0, P0), ukf.UKFConfig(), params, sim.controls, sim.observations
    )[1]
    pos_err = np.linalg.norm(np.asarray(a.estimate[:, :2] - sim.true_poses[:, :2]), axis=1)
    diff = np.linalg.norm(np.asarray(a.estimate[:, :2] - b.estimate[:, :2]), axis=1)
    # the two approximations differ by far less than their error against the truth
    assert diff.max() < 0.1 * pos_err.mean(), (diff.max(), pos_err.mean())
    assert not bool(np.any(b.cholesky_failed))


def test_step_loop_equals_run(getkey):
    sim = _simulate(getkey(), steps=20)
    params = ekf.KalmanParams(MOTION, SENSOR, LANDMARKS)
    cfg = ekf.EKFConfig()
    state = ekf.init(None, cfg, params, X0, P0)
    final, trace = ekf.run(None, state, cfg, params, sim.controls, sim.observations)
    for t in range(20):
        obs_t = jax.tree_util.tree_map(lambda x: x[t], sim.observations)
        state, info = ekf.step(None, state, cfg, params, sim.controls[t], obs_t)
        np.testing.assert_allclose(info.estimate, trace.estimate[t], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(state.cov, final.cov, rtol=1e-4, atol=1e-8)


@pytest.mark.parametrize("module, config_type", [(ekf, ekf.EKFConfig), (ukf, ukf.UKFConfig)])
def test_gating_rejects_range_outliers(module, config_type, getkey):
    """10 % of observations get +2 m of range (20 σ): gated filters count and drop them."""
    sim = _simulate(getkey())
    obs = sim.observations
    outlier = jax.random.uniform(getkey(), obs.mask.shape) < 0.1
    z = obs.z.at[..., 0].add(jnp.where(outlier, 2.0, 0.0))
    bad = obs._replace(z=z)
    params = ekf.KalmanParams(MOTION, SENSOR, LANDMARKS)
    gated_cfg = config_type(gate_probability=0.999)
    plain_cfg = config_type()
    s0 = module.init(None, plain_cfg, params, X0, P0)
    gated = module.run(None, s0, gated_cfg, params, sim.controls, bad)[1]
    plain = module.run(None, s0, plain_cfg, params, sim.controls, bad)[1]
    err = lambda tr: np.sqrt(np.mean(np.sum(_errors(tr.estimate, sim.true_poses)[:, :2] ** 2, axis=1)))  # noqa: E731
    n_out = int(np.sum(outlier & obs.mask))
    n_gated = int(np.sum(gated.num_gated))
    # every 20σ outlier fails a 99.9 % gate; a few good ones (0.1 %) may too
    assert n_out <= n_gated <= n_out + 0.01 * int(np.sum(obs.mask)) + 3
    assert err(gated) < 0.5 * err(plain), (err(gated), err(plain))
    assert err(gated) < 0.06


def test_unknown_ids_are_ignored_and_counted(getkey):
    sim = _simulate(getkey(), steps=10)
    ids = sim.observations.ids.at[:, 0].set(99).at[:, 1].set(-1)
    obs = sim.observations._replace(ids=ids, z=sim.observations.z.at[:, 0].set(jnp.nan))
    params = ekf.KalmanParams(MOTION, SENSOR, LANDMARKS)
    cfg = ekf.EKFConfig()
    tr = ekf.run(None, ekf.init(None, cfg, params, X0, P0), cfg, params, sim.controls, obs)[1]
    expected = np.sum(np.asarray(obs.mask[:, :2]), axis=1)
    np.testing.assert_array_equal(tr.num_ignored, expected)
    assert np.all(np.isfinite(np.asarray(tr.estimate)))


def test_bad_input_is_rejected():
    params = ekf.KalmanParams(MOTION, SENSOR, LANDMARKS)
    cfg = ekf.EKFConfig()
    with pytest.raises(ValueError, match="positive definite"):
        ekf.init(None, cfg, params, X0, jnp.asarray([[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]]))
    with pytest.raises(ValueError, match="symmetric"):
        ekf.init(None, cfg, params, X0, jnp.asarray([[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]))
    with pytest.raises(ValueError, match="VelocityNoise"):
        ekf.init(None, cfg, params._replace(motion=motion.OmniNoise(jnp.ones(3))), X0, P0)
    with pytest.raises(ValueError, match="gate probability"):
        ekf.EKFConfig(gate_probability=1.5)
    with pytest.raises(ValueError, match="n \\+ λ"):
        ukf.UKFConfig(alpha=0.1, kappa=-4.0)
    with pytest.raises(ValueError, match="motion_model"):
        ukf.UKFConfig(motion_model="teleport")
    state = ekf.init(None, cfg, params, X0, P0)
    obs = lm.RangeBearingObs(jnp.zeros((5, 2), jnp.int32), jnp.zeros((5, 2, 2)), jnp.ones((5, 2), bool))
    with pytest.raises(ValueError, match="same number of steps"):
        ekf.run(None, state, cfg, params, jnp.zeros((4, 3)), obs)


def test_run_compiles_once(getkey):
    params = ekf.KalmanParams(MOTION, SENSOR, LANDMARKS)
    cfg = ekf.EKFConfig(gate_probability=0.99)
    s0 = ekf.init(None, cfg, params, X0, P0)
    a = _simulate(getkey(), steps=30)
    ekf.run(None, s0, cfg, params, a.controls, a.observations)
    before = ekf.run.trace_count()
    b = _simulate(getkey(), steps=30)
    ekf.run(None, s0, cfg, params._replace(sensor=lm.RangeBearingNoise(SENSOR.sd * 2)), b.controls, b.observations)
    assert ekf.run.trace_count() == before
