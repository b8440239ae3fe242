"""EKF-SLAM (jaxnav.slam.ekf_slam) on a simulated landmark world.

World: 12 landmarks on the border of a 10 m room; the robot drives a circle of
radius 2.5 m (v = 0.5 m/s, ω = 0.2 rad/s, Δt = 0.25 s: one lap ≈ 126 steps)
twice (T = 260), seeing landmarks within 6 m in its front half-plane, so the
map fills up over the first lap. R = 30 seeded runs, filtered once by a
module fixture that most tests share.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.core import kalman
from jaxnav.core.kalman import chi2_gate
from jaxnav.localization import ekf
from jaxnav.models import landmarks as lm
from jaxnav.models import motion
from jaxnav.sim import landmark_world as lw
from jaxnav.sim import trajectories
from jaxnav.slam import ekf_slam

M = 12
LANDMARKS = lw.square_room_landmarks(10.0, M)
MOTION = motion.VelocityNoise(jnp.asarray([0.01, 0.005, 0.005, 0.01, 0.0, 0.0]), jnp.asarray([0.01, 0.01, 0.005]))
SENSOR = lm.RangeBearingNoise(jnp.asarray([0.1, 0.03]))
X0 = jnp.asarray([5.0, 2.5, 0.0])
P0 = jnp.diag(jnp.asarray([1e-4, 1e-4, 1e-5]))
STEPS = 260  # two laps
LAP = 126
RUNS = 30
CONFIG = ekf_slam.EKFSLAMConfig(num_landmarks=M)
PARAMS = ekf_slam.EKFSLAMParams(MOTION, SENSOR)


def _simulate(key):
    u = trajectories.loop_controls(STEPS, speed=0.5, turn_rate=0.2, dt=0.25)
    x0 = X0 + jax.random.normal(jax.random.fold_in(key, 1), (3,)) * jnp.sqrt(jnp.diag(P0))
    return lw.simulate(key, LANDMARKS, x0, u, MOTION, SENSOR, max_range=6.0, fov=np.pi)


def _stack(trees):
    return jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *trees)


def _unstack(tree, r):
    return jax.tree_util.tree_map(lambda x: x[r], tree)


def _run_batch(sims, params=PARAMS, state=None, observations=None):
    """EKF-SLAM over every run of ``sims``, stacked.

    A loop of ``run`` calls (one compilation shared by every test):
    :func:`test_vmap_over_runs_matches_loop_and_ignores_unknown_ids` checks
    that ``jax.vmap(run)`` gives the same, but the batched program takes
    longer to compile.
    """
    s0 = ekf_slam.init(None, CONFIG, params, X0, P0) if state is None else state
    obs = sims.observations if observations is None else observations
    runs = [
        ekf_slam.run(None, s0, CONFIG, params, sims.controls[r], _unstack(obs, r))
        for r in range(sims.controls.shape[0])
    ]
    return _stack(runs)


def _pose_errors(estimate, truth):
    e = np.array(estimate - truth, np.float64)
    e[..., 2] = (e[..., 2] + np.pi) % (2 * np.pi) - np.pi
    return e


@pytest.fixture(scope="module")
def batch():
    sims = _stack([_simulate(k) for k in jax.random.split(jax.random.PRNGKey(20240601), RUNS)])
    final, trace = _run_batch(sims)
    return sims, final, trace


def test_map_and_pose_improve_with_data(batch):
    sims, final, trace = batch
    seen = np.asarray(trace.seen)  # [R, T, M]
    assert seen[:, -1].all(), "every landmark is in view at some point of a lap"
    # landmarks are added progressively, not all at the first step
    assert 0 < seen[:, 0].sum(axis=1).max() < M
    np.testing.assert_array_equal(np.asarray(trace.num_new).sum(axis=1), M)

    # map error after two laps < after half a lap, over the landmarks known at half a lap
    err = np.linalg.norm(np.asarray(trace.landmarks - LANDMARKS), axis=-1)  # [R, T, M]
    half = LAP // 2
    known = seen[:, half]
    rmse_half = np.sqrt(np.mean(err[:, half][known] ** 2))
    rmse_end = np.sqrt(np.mean(err[:, -1][known] ** 2))
    assert rmse_end < rmse_half, (rmse_end, rmse_half)

    # Dissanayake et al. (2001) Thm. 1: the determinant of a landmark's covariance never
    # grows once it is in the map (prediction leaves the map block alone, each update
    # subtracts a PSD term). Tolerance: float32 round-off (measured ratio ≤ 1 − 6e-8).
    det = np.linalg.det(np.asarray(trace.landmark_cov, np.float64))
    both = seen[:, 1:] & seen[:, :-1]
    assert np.max((det[:, 1:] / det[:, :-1])[both]) <= 1.0 + 1e-5
    first = np.take_along_axis(det, seen.argmax(axis=1)[:, None, :], axis=1)[:, 0]
    shrink = det[:, -1] / first
    assert np.all(shrink < 1.0) and np.median(shrink) < 0.1, np.quantile(shrink, [0.5, 1.0])

    # the pose error in the second half of lap 2 (loop closed, map refined) is below
    # that of the second half of lap 1 (measured 0.11 m vs 0.15 m)
    e = _pose_errors(trace.estimate, sims.true_poses)
    sq = np.sum(e[..., :2] ** 2, axis=-1)
    lap1 = np.sqrt(np.mean(sq[:, half:LAP]))
    lap2 = np.sqrt(np.mean(sq[:, LAP + half : 2 * LAP]))
    assert lap2 < lap1, (lap2, lap1)


def _consistency(sims, final, trace):
    """Fraction of steps with pose ANEES in its 95 % band, and the joint map NEES per run at the end."""
    e = _pose_errors(trace.estimate, sims.true_poses)
    nees = np.einsum("rti,rtij,rtj->rt", e, np.linalg.inv(np.asarray(trace.pose_cov, np.float64)), e)
    lo, hi = chi2_gate(0.025, 3 * RUNS) / RUNS, chi2_gate(0.975, 3 * RUNS) / RUNS
    frac = float(np.mean((nees.mean(axis=0) >= lo) & (nees.mean(axis=0) <= hi)))
    em = np.asarray(final.mean[:, 3:] - LANDMARKS.reshape(-1), np.float64)
    pm = np.asarray(final.cov[:, 3:, 3:], np.float64)
    map_nees = float(np.mean(np.einsum("ri,rij,rj->r", em, np.linalg.inv(pm), em)))
    return frac, map_nees


def test_estimates_are_consistent(batch):
    """NEES within χ² bounds (Bar-Shalom et al. 2001, §5.4).

    Pose: the ANEES over R runs, times R, is χ²(3R) if the filter is
    consistent; it must be in the two-sided 95 % interval at ≥ 85 % of the
    steps (measured 97 %). Map: at the end, the NEES of all 2M landmark
    coordinates under the *joint* map covariance (the landmark errors are
    correlated through the pose) is χ²(2M) per run; the mean over R runs must
    be inside the 99 % interval of χ²(2MR)/R. EKF-SLAM is known to become
    overconfident over long runs with large heading uncertainty (Bailey et
    al. 2006); here (two laps, heading sd ≤ 2.2°) it is not yet.
    Negative control: a filter told the sensor is 4× more precise fails both.
    """
    sims, final, trace = batch
    frac, map_nees = _consistency(sims, final, trace)
    dof = 2 * M
    lo, hi = chi2_gate(0.005, dof * RUNS) / RUNS, chi2_gate(0.995, dof * RUNS) / RUNS
    assert frac >= 0.85, f"pose ANEES inside its 95% band at only {frac:.0%} of steps"
    assert lo <= map_nees <= hi, (map_nees, lo, hi)  # measured 23.4 in [20.9, 27.4]

    overconfident = PARAMS._replace(sensor=lm.RangeBearingNoise(SENSOR.sd / 4))
    frac_bad, map_nees_bad = _consistency(sims, *_run_batch(sims, overconfident))
    assert frac_bad < 0.5 and map_nees_bad > hi, (frac_bad, map_nees_bad)  # measured 0.4 %, 333


def test_beats_dead_reckoning(batch):
    """Pose RMSE well below dead reckoning (the motion model's mean chained over the controls)."""
    sims, _, trace = batch
    model = motion.get_motion_model("velocity")
    _, dead = jax.lax.scan(lambda x, u: (model.mean(x, u),) * 2, X0, sims.controls[0])
    slam = np.sqrt(np.mean(np.sum(_pose_errors(trace.estimate, sims.true_poses)[..., :2] ** 2, -1), axis=1))
    dr = np.sqrt(np.mean(np.sum(_pose_errors(dead[None], sims.true_poses)[..., :2] ** 2, -1), axis=1))
    # measured: SLAM 0.11 m, dead reckoning 0.54 m, SLAM better in all 30 runs
    assert np.mean(slam) < 0.5 * np.mean(dr), (np.mean(slam), np.mean(dr))
    assert np.sum(slam < dr) >= RUNS - 2


def test_known_map_reduces_to_ekf_localization(batch):
    """All landmarks initialised with covariance σ_m² I: EKF-SLAM → EKF localization as σ_m → 0.

    The gap is first order in σ_m²/σ_z² (here 1e-8 / 1e-2); measured 1.4e-6 m,
    the float32 floor. Negative control: σ_m = 1 m gives a gap > 5 cm.
    """
    sims, _, _ = batch
    p = ekf.KalmanParams(MOTION, SENSOR, LANDMARKS)
    cfg = ekf.EKFConfig()
    s0 = ekf.init(None, cfg, p, X0, P0)
    loc = _stack([ekf.run(None, s0, cfg, p, sims.controls[r], _unstack(sims.observations, r))[1] for r in range(RUNS)])

    def gap(var, runs):
        state = ekf_slam.init(None, CONFIG, PARAMS, X0, P0, LANDMARKS, var * jnp.eye(2))
        np.testing.assert_array_equal(state.seen, True)
        tr = _run_batch(_unstack(sims, slice(0, runs)), state=state)[1]
        d = np.abs(_pose_errors(tr.estimate, loc.estimate[:runs])).max()
        dc = np.abs(np.asarray(tr.pose_cov - loc.cov[:runs])).max() / np.abs(np.asarray(loc.cov)).max()
        return d, dc, tr

    d, dc, tr = gap(1e-8, RUNS)
    assert d < 1e-4 and dc < 1e-4, (d, dc)
    assert int(np.sum(tr.num_new)) == 0
    d_bad, _, _ = gap(1.0, 5)
    assert d_bad > 0.05, d_bad


def test_vmap_over_runs_matches_loop_and_ignores_unknown_ids(batch):
    """Slots 0 and 1 carry ids 99 and −1 with NaN measurements at every step.

    They are counted, never read, and landmarks 0 and 1 (observed only through
    those slots) stay unseen with their placeholder entries untouched. Under
    ``vmap`` the filter's ``lax.switch`` over slot kinds becomes a select that
    evaluates every branch, so this is also where a NaN from an unused branch
    would show; the vmapped runs must equal the loop of ``run`` calls.
    """
    sims, _, _ = batch
    few = 4
    sims = _unstack(sims, slice(0, few))
    obs = sims.observations
    ids = obs.ids.at[..., 0].set(99).at[..., 1].set(-1)
    z = obs.z.at[..., 0, :].set(jnp.nan).at[..., 1, :].set(jnp.nan)
    mask = obs.mask.at[..., :2].set(True)
    bad = obs._replace(ids=ids, z=z, mask=mask)
    s0 = ekf_slam.init(None, CONFIG, PARAMS, X0, P0)
    final, trace = jax.vmap(lambda u, o: ekf_slam.run(None, s0, CONFIG, PARAMS, u, o))(sims.controls, bad)
    np.testing.assert_array_equal(trace.num_ignored, 2)
    assert np.all(np.isfinite(np.asarray(final.mean))) and np.all(np.isfinite(np.asarray(final.cov)))
    seen = np.asarray(final.seen)
    assert not seen[:, :2].any() and seen[:, 2:].all()
    cov = np.asarray(final.cov)
    np.testing.assert_array_equal(final.mean[:, 3:7], 0.0)
    np.testing.assert_array_equal(cov[:, 3:7, 3:7], np.broadcast_to(ekf_slam.UNSEEN_VARIANCE * np.eye(4), (few, 4, 4)))
    np.testing.assert_array_equal(cov[:, 3:7, :3], 0.0)
    np.testing.assert_array_equal(cov[:, 3:7, 7:], 0.0)

    lfinal, ltrace = _run_batch(sims, observations=bad)
    np.testing.assert_array_equal(ltrace.num_ignored, 2)
    np.testing.assert_array_equal(lfinal.seen, final.seen)
    np.testing.assert_allclose(trace.estimate, ltrace.estimate, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(final.cov, lfinal.cov, rtol=1e-3, atol=1e-6)


def test_sequential_slots_match_dense_reference():
    """One step with zero motion equals a dense EKF on the full state, slot by slot (float64).

    The step's slots: landmark 1 (in the map), landmark 2 first seen and then
    re-observed in the same step, landmark 0 with a 5 m range outlier (gated
    at 0.999), landmark 1 again, and an unknown id with NaN measurements.
    Reference: new landmarks by ``Σ ← T Σ Tᵀ + E J_z R J_zᵀ Eᵀ`` (T puts
    ``J_x`` on the new rows), known ones by :func:`jaxnav.core.kalman.ekf_update`
    with the Jacobian of ``h`` taken over all ``3 + 2M`` entries.
    """
    with jax.enable_x64(True):
        m, n = 4, 11
        cfg = ekf_slam.EKFSLAMConfig(num_landmarks=m, gate_probability=0.999)
        params = ekf_slam.EKFSLAMParams(
            motion.VelocityNoise(jnp.zeros(6), jnp.zeros(3)), lm.RangeBearingNoise(jnp.asarray([0.1, 0.05]))
        )
        prior = jnp.asarray([[3.0, 1.0], [0.0, 4.0], [-2.0, -2.0], [5.0, 5.0]])
        s0 = ekf_slam.init(
            None,
            cfg,
            params,
            jnp.asarray([0.2, 0.1, 0.3]),
            jnp.diag(jnp.asarray([0.05, 0.04, 0.01])),
            prior,
            0.2 * jnp.eye(2),
            jnp.asarray([True, True, False, False]),
        )
        assert s0.mean.dtype == jnp.float64
        ids = jnp.asarray([1, 2, 2, 0, 1, 7], jnp.int32)
        z = jnp.asarray([[3.9, 1.0], [2.9, -2.6], [3.0, -2.5], [7.8, -0.1], [4.0, 1.05], [np.nan, np.nan]])
        obs = lm.RangeBearingObs(ids, z, jnp.ones(6, bool))
        state, info = ekf_slam.step(None, s0, cfg, params, jnp.asarray([0.0, 0.0, 0.25]), obs)

        r = jnp.diag(params.sensor.sd**2)

        @jax.jit
        def reference(mean, cov, z):
            seen = [True, True, False, False]
            for j, zj in zip([1, 2, 2, 0, 1], z[:5]):  # slot 5 (id 7) is not in the map
                sl = slice(3 + 2 * j, 5 + 2 * j)
                if not seen[j]:
                    jx, jz = jax.jacfwd(lm.inverse, argnums=(0, 1))(mean[:3], zj)
                    t = jnp.eye(n).at[sl].set(0.0).at[sl, :3].set(jx)
                    e = jnp.zeros((n, 2)).at[sl].set(jnp.eye(2))
                    cov = t @ cov @ t.T + e @ jz @ r @ jz.T @ e.T
                    mean = mean.at[sl].set(lm.inverse(mean[:3], zj))
                    seen[j] = True
                else:
                    h = lambda x, j=j: lm.predict(x[:3], x[3 + 2 * j : 5 + 2 * j])  # noqa: E731
                    res = kalman.ekf_update(
                        mean, cov, zj, h, r, gate=cfg.gate, state_angle_dims=(2,), obs_angle_dims=(1,)
                    )
                    mean, cov = res.mean, res.cov
            return mean, cov

        mean, cov = reference(s0.mean, s0.cov, z)
        np.testing.assert_allclose(state.mean, mean, rtol=0, atol=1e-12)
        np.testing.assert_allclose(state.cov, cov, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(state.seen, [True, True, True, False])
        np.testing.assert_array_equal(info.accepted, [True, False, True, False, True, False])
        assert (int(info.num_new), int(info.num_ignored), int(info.num_gated)) == (1, 1, 1)
        assert float(info.nis[3]) > cfg.gate and float(info.nis[1]) == 0.0
        assert np.isfinite(float(info.log_likelihood))


def test_covariance_stays_symmetric_positive_definite(batch):
    """float32, 260 steps × 12 slots: the joint covariance stays exactly symmetric and PD.

    Measured smallest eigenvalue 1.1e-4, far above float32 round-off of the
    entries (~1e-9); the final state passes the filter's own host validation.
    """
    _, final, trace = batch
    cov = np.asarray(final.cov)
    assert cov.dtype == np.float32
    np.testing.assert_array_equal(cov, np.swapaxes(cov, 1, 2))
    assert np.linalg.eigvalsh(cov.astype(np.float64)).min() > 1e-6
    assert np.linalg.eigvalsh(np.asarray(trace.pose_cov, np.float64)).min() > 0
    assert np.linalg.eigvalsh(np.asarray(trace.landmark_cov, np.float64)).min() > 0
    for r in range(RUNS):
        ekf_slam.validate_state(CONFIG, PARAMS, jax.tree_util.tree_map(lambda x: x[r], final))


def test_run_compiles_once(batch):
    """``step`` and ``run`` share ``_step``; ``step`` itself is checked against the dense reference above."""
    sims, final, _ = batch
    run0 = _unstack(sims, 0)
    s0 = ekf_slam.init(None, CONFIG, PARAMS, X0, P0)
    again = ekf_slam.run(None, s0, CONFIG, PARAMS, run0.controls, run0.observations)[0]
    np.testing.assert_array_equal(again.mean, final.mean[0])  # deterministic: same input, same bits

    # new data and new parameter values with the same shapes: no retrace
    before = ekf_slam.run.trace_count()
    run1 = jax.tree_util.tree_map(lambda x: x[1], sims)
    other = PARAMS._replace(sensor=lm.RangeBearingNoise(SENSOR.sd * 2))
    ekf_slam.run(None, ekf_slam.init(None, CONFIG, other, X0, 2 * P0), CONFIG, other, run1.controls, run1.observations)
    assert ekf_slam.run.trace_count() == before


def test_bad_input_is_rejected():
    with pytest.raises(ValueError, match="positive definite"):
        ekf_slam.init(None, CONFIG, PARAMS, X0, jnp.asarray([[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]]))
    with pytest.raises(ValueError, match="symmetric"):
        ekf_slam.init(None, CONFIG, PARAMS, X0, jnp.asarray([[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]))
    with pytest.raises(ValueError, match="positive definite"):
        ekf_slam.init(None, CONFIG, PARAMS, X0, P0, LANDMARKS, -jnp.eye(2))
    with pytest.raises(ValueError, match="landmark_cov"):
        ekf_slam.init(None, CONFIG, PARAMS, X0, P0, LANDMARKS)
    with pytest.raises(ValueError, match="landmarks must have shape"):
        ekf_slam.init(None, CONFIG, PARAMS, X0, P0, LANDMARKS[:3], jnp.eye(2))
    with pytest.raises(ValueError, match="VelocityNoise"):
        ekf_slam.init(None, CONFIG, PARAMS._replace(motion=motion.OmniNoise(jnp.ones(3))), X0, P0)
    with pytest.raises(ValueError, match="num_landmarks"):
        ekf_slam.EKFSLAMConfig(num_landmarks=0)
    with pytest.raises(ValueError, match="gate probability"):
        ekf_slam.EKFSLAMConfig(gate_probability=1.5)
    with pytest.raises(ValueError, match="motion_model"):
        ekf_slam.EKFSLAMConfig(motion_model="teleport")
    state = ekf_slam.init(None, CONFIG, PARAMS, X0, P0)
    with pytest.raises(ValueError, match="state.mean"):
        ekf_slam.step(
            None,
            state,
            ekf_slam.EKFSLAMConfig(num_landmarks=M + 1),
            PARAMS,
            jnp.zeros(3),
            lm.RangeBearingObs(jnp.zeros(2, jnp.int32), jnp.zeros((2, 2)), jnp.ones(2, bool)),
        )
    obs = lm.RangeBearingObs(jnp.zeros((5, 2), jnp.int32), jnp.zeros((5, 2, 2)), jnp.ones((5, 2), bool))
    with pytest.raises(ValueError, match="same number of steps"):
        ekf_slam.run(None, state, CONFIG, PARAMS, jnp.zeros((4, 3)), obs)
