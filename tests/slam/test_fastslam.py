"""FastSLAM 1.0 / 2.0 (jaxnav.slam.fastslam) on simulated landmark worlds."""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav import metrics
from jaxnav.core import fastmath, resampling
from jaxnav.models import hf_rfid, motion, observation
from jaxnav.models import landmarks as lm
from jaxnav.sim import landmark_world as lw
from jaxnav.sim import trajectories
from jaxnav.slam import fastslam as fs

LANDMARKS = lw.square_room_landmarks(10.0, 8)
MOTION = motion.VelocityNoise(jnp.asarray([0.01, 0.005, 0.005, 0.01, 0.0, 0.0]), jnp.asarray([0.01, 0.01, 0.005]))
SENSOR = lm.RangeBearingNoise(jnp.asarray([0.1, 0.03]))
X0 = jnp.asarray([5.0, 2.0, 0.0])
PARAMS = fs.FastSLAMParams(MOTION, SENSOR)
CHUNK = 84  # half a loop of loop_controls (0.0375 rad per step)
# Every simulation of the file is a prefix of one batch of SIM_RUNS runs of SIM_STEPS steps: one
# compiled simulator for all the tests (a new number of runs or steps would be a new program).
SIM_RUNS, SIM_STEPS = 8, 3 * CHUNK


def _world_runs(keys, motion_noise=MOTION, sensor=SENSOR):
    """SIM_RUNS runs (``keys [SIM_RUNS, 2]``) of SIM_STEPS steps of the landmark world, as NumPy arrays."""
    u = trajectories.loop_controls(SIM_STEPS)
    sims = jax.vmap(lambda k: lw.simulate(k, LANDMARKS, X0, u, motion_noise, sensor, max_range=6.0))(keys)
    return jax.tree_util.tree_map(np.asarray, sims)


def _sims(key, runs, steps, motion_noise=MOTION, sensor=SENSOR):
    """``runs`` simulated runs of ``steps`` steps (NumPy arrays), the first runs and steps of
    :func:`_world_runs`: the same draws as simulating them alone (``split(key, n)[:runs]`` is
    ``split(key, runs)``, and the simulator keys step ``t`` by ``split(key, T)[t]``)."""
    assert runs <= SIM_RUNS and steps <= SIM_STEPS
    sims = _world_runs(jax.random.split(key, SIM_RUNS), motion_noise, sensor)
    return jax.tree_util.tree_map(lambda x: x[:runs, :steps], sims)


# ``fs.init`` as one compiled program per configuration and argument shapes (eagerly, each of its
# operations is a program of its own, per shape); the host checks of its arguments are left out
# (test_bad_input_and_single_compilation calls ``fs.init`` itself for them).
_init = jax.jit(fs.init, static_argnums=1)
# range and bearing of landmarks ``[K, 2]`` from one pose ``[3]``
_predict = jax.jit(jax.vmap(lm.predict, in_axes=(None, 0)))


@pytest.mark.parametrize("version", [1, 2])
def test_map_and_pose_errors_shrink_as_data_accumulates(version, getkey):
    """Over 8 runs and three half-loops, the landmark error after the third is below the first,
    the landmark covariances shrink, and the pose error is far below dead reckoning's."""
    runs = 8
    sims = _sims(getkey(), runs, 3 * CHUNK)
    cfg = fs.FastSLAMConfig(num_particles=50, num_landmarks=8, version=version)
    keys = jax.random.split(getkey(), runs)

    @jax.jit
    def filt(keys, sims):
        def one(k, sim):
            def half_loop(state, chunk):
                i, controls, observations = chunk
                state, tr = fs.run(jax.random.fold_in(k, i), state, cfg, PARAMS, controls, observations)
                m, seen = fs.map_estimate(state)
                size = jnp.sum(jnp.exp(state.log_weights)[:, None] * jnp.trace(state.covs, axis1=-2, axis2=-1), axis=0)
                return state, (m, seen, size, tr.estimate)

            # the half-loops as one scan: the filter is compiled once, not once per half-loop
            chunks = jax.tree_util.tree_map(
                lambda x: x.reshape(3, CHUNK, *x.shape[1:]), (sim.controls, sim.observations)
            )
            return jax.lax.scan(half_loop, fs.init(k, cfg, PARAMS, X0), (jnp.arange(3), *chunks))[1]

        return jax.vmap(one)(keys, sims)

    stacked = jax.tree_util.tree_map(np.asarray, filt(keys, sims))  # fields [runs, 3, ...]
    out = [tuple(x[:, i] for x in stacked) for i in range(3)]
    first_seen = np.asarray(out[0][1])  # [runs, M]: compare the same landmarks across chunks
    assert first_seen.mean() > 0.8
    # The map's shape (error after rigid alignment, jaxnav.metrics.map_errors) sharpens with
    # data; the raw error also carries the frame drift fixed early on, so it is only bounded.
    aligned, raw = [], []
    for m, _, _, _ in out:
        errs = [metrics.map_errors(np.asarray(m)[r], LANDMARKS, first_seen[r]) for r in range(runs)]
        aligned.append(np.mean([float(e.aligned_rmse) for e in errs]))
        raw.append(np.mean([float(e.rmse) for e in errs]))
    assert aligned[2] < 0.75 * aligned[0], aligned
    assert max(raw) < 0.3, raw  # m; σ_r = 0.1 m, σ_φ·r ≈ 0.15 m at 5 m for one observation
    # every landmark's covariance trace shrinks between the first and the third half-loop
    assert np.all(np.asarray(out[2][2])[first_seen] < np.asarray(out[0][2])[first_seen])
    est = np.concatenate([np.asarray(o[3]) for o in out], axis=1)
    pos_err = np.linalg.norm(est[..., :2] - sims.true_poses[..., :2], axis=-1).mean()
    dr = np.asarray(_dead_reckoning(sims.controls))
    dr_err = np.linalg.norm(dr[..., :2] - sims.true_poses[..., :2], axis=-1).mean()
    assert pos_err < 0.5 * dr_err, (pos_err, dr_err)


@jax.jit
def _dead_reckoning(controls):
    def one(controls):
        def body(x, u):
            x = motion.velocity_mean(x, u)
            return x, x

        return jax.lax.scan(body, X0, controls)[1]

    return jax.vmap(one)(controls)


def test_fastslam2_proposal_keeps_particles_alive_with_accurate_sensor(getkey):
    """The point of FastSLAM 2.0 (Montemerlo et al. 2003): with a sensor much more precise than
    the motion, sampling poses from the motion model (1.0) leaves almost every particle with a
    negligible weight (ESS ≈ 1 of 20), while the observation-driven proposal keeps most of them.
    Over 8 runs the mean ESS of 2.0 must exceed 3× that of 1.0, at no loss of accuracy (pose
    error within 1.5× of 1.0's; both are dominated by the map's frame error from the first step).
    The simulation and the filters use independent keys: with JAX's partitionable threefry
    ``split(k, T)[t] == fold_in(k, t)``, so reusing the simulator's key would hand one particle
    the true motion noise."""
    noisy = motion.VelocityNoise(jnp.asarray([0.05, 0.01, 0.01, 0.05, 0.0, 0.0]), jnp.asarray([0.03, 0.03, 0.02]))
    sharp = lm.RangeBearingNoise(jnp.asarray([0.02, 0.005]))
    params = fs.FastSLAMParams(noisy, sharp)
    runs, steps = 8, 120
    sims = _sims(getkey(), runs, steps, noisy, sharp)
    keys = jax.random.split(getkey(), runs)
    ess, errors = {}, {}
    for version in (1, 2):
        cfg = fs.FastSLAMConfig(num_particles=20, num_landmarks=8, version=version)

        def one(k, sim):
            return fs.run(k, fs.init(k, cfg, params, X0), cfg, params, sim.controls, sim.observations)[1]

        tr = jax.jit(jax.vmap(one))(keys, sims)
        ess[version] = float(np.mean(np.asarray(tr.ess)[:, 1:]))
        est = np.asarray(tr.estimate)
        errors[version] = np.linalg.norm(est[..., :2] - sims.true_poses[..., :2], axis=-1).mean()
    assert ess[2] > 3 * ess[1], ess
    assert errors[2] < 1.5 * errors[1], errors


def test_known_map_prior_tracks_pose(getkey):
    """With the true map loaded (tiny covariance) FastSLAM reduces to localization: error near the sensor's."""
    sims = _sims(getkey(), 1, 100)
    sim = jax.tree_util.tree_map(lambda x: x[0], sims)
    cfg = fs.FastSLAMConfig(num_particles=200, num_landmarks=8)
    covs = np.broadcast_to(1e-6 * np.eye(2, dtype=np.float32), (8, 2, 2))
    state = _init(getkey(), cfg, PARAMS, X0, landmark_means=LANDMARKS, landmark_covs=covs)
    _, tr = fs.run(getkey(), state, cfg, PARAMS, sim.controls, sim.observations)
    err = np.linalg.norm(np.asarray(tr.estimate)[:, :2] - sim.true_poses[:, :2], axis=1)
    assert err.mean() < 0.06, err.mean()
    assert int(np.sum(np.asarray(tr.num_new))) == 0


def test_new_landmarks_duplicates_and_unknown_ids(getkey):
    """Slot bookkeeping: first sightings initialise (counted once even if seen twice in one step),
    out-of-map ids are ignored and counted, NaN in masked slots is harmless."""
    cfg = fs.FastSLAMConfig(num_particles=16, num_landmarks=4)
    state = _init(getkey(), cfg, PARAMS, X0)
    lms = np.asarray([[7.0, 2.0], [5.0, 5.0], [2.0, 3.0], [8.0, 8.0]], np.float32)
    z = np.asarray(_predict(X0, lms))
    ids = np.asarray([0, 0, 1, 7, -2, 2], np.int32)
    zs = np.stack([z[0], z[0] + np.float32([0.05, 0.0]), z[1], z[1], z[1], np.full(2, np.nan, np.float32)])
    mask = np.asarray([True, True, True, True, True, False])
    control = np.asarray([0.0, 0.0, 0.1], np.float32)
    state, info = fs.step(getkey(), state, cfg, PARAMS, control, lm.RangeBearingObs(ids, zs, mask))
    assert int(info.num_new) == 2 and int(info.num_ignored) == 2
    np.testing.assert_array_equal(np.asarray(state.seen), [True, True, False, False])
    # landmark 0 was initialised from z[0] and then updated by the second, 5 cm longer, range
    m0 = np.asarray(state.means)[:, 0].mean(axis=0)
    assert 7.01 < m0[0] < 7.04 and abs(m0[1] - 2.0) < 0.02  # the mean of 2.00 m and 2.05 m ranges
    assert np.all(np.isfinite(np.asarray(state.means))) and np.all(np.isfinite(np.asarray(state.log_weights)))


@partial(jax.jit, static_argnums=0)
def _init_in_every_particle(om, r, poses, z):
    return jax.vmap(lambda p: fs.landmark_init(om, r, p, z))(poses)


@partial(jax.jit, static_argnums=0)
def _ekf_in_every_particle(om, r, poses, means, covs, z):
    return jax.vmap(lambda p, mu, c: fs.landmark_ekf(om, r, p, mu, c, z))(poses, means, covs)


def _sequential_reference(om, r, poses, means, covs, seen, obs, m):
    """The landmark update written the plain way: slot after slot on whole maps (host loop; each
    slot's initialisation or EKF update of every particle is one compiled call)."""
    means, covs, seen = np.array(means), np.array(covs), np.array(seen)
    loglik = np.zeros(poses.shape[0], np.float32)
    num_new = 0
    for k in range(obs.ids.shape[0]):
        j = int(obs.ids[k])
        if not bool(obs.mask[k]) or not 0 <= j < m:
            continue
        if not bool(seen[j]):
            mu, cov = _init_in_every_particle(om, r, poses, obs.z[k])
            seen[j] = True
            num_new += 1
        else:
            u = _ekf_in_every_particle(om, r, poses, means[:, j], covs[:, j], obs.z[k])
            mu, cov, loglik = u.mean, u.cov, loglik + np.asarray(u.log_likelihood)
        means[:, j], covs[:, j] = mu, cov
    return means, covs, seen, loglik, num_new


# the scan that gives the derivatives (it has no lanes: jitted once for all of them)
_in_order_range_bearing = jax.jit(lambda *a: fs.update_landmarks_in_order(observation.RANGE_BEARING, *a))


@pytest.fixture(scope="module")
def slot_case():
    """The landmark update's inputs and the slot-after-slot reference (the same for every lane count)."""
    n, m = 8, 6
    om, r = observation.RANGE_BEARING, jnp.diag(SENSOR.sd**2)
    rng = np.random.default_rng(3)
    # (in float32 throughout, as jax.numpy computes them)
    poses = jnp.asarray(np.asarray(X0) + rng.normal(0, 0.05, (n, 3)).astype(np.float32))
    lms = rng.uniform(0, 10, (m, 2)).astype(np.float32)
    means = jnp.asarray(lms + rng.normal(0, 0.1, (n, m, 2)).astype(np.float32))
    covs = jnp.asarray(
        np.float32(0.02) * np.eye(2, dtype=np.float32) * rng.uniform(0.5, 2, (n, m, 1, 1)).astype(np.float32)
    )
    seen = jnp.asarray([True, True, True, False, False, True])
    ids = np.asarray([3, 0, 3, 9, 1, 0, 4, 2, 0, 5, -1, 1], np.int32)
    mask = np.asarray([True, True, True, True, True, True, True, True, True, False, True, True])
    z = np.asarray(_predict(X0, lms[np.clip(ids, 0, m - 1)])) + np.asarray(rng.normal(0, 0.05, (12, 2)), np.float32)
    z = np.where(mask[:, None], z, np.float32(np.nan))
    obs = lm.RangeBearingObs(jnp.asarray(ids), jnp.asarray(z), jnp.asarray(mask))
    valid, safe_ids, _ = fs.slot_valid(obs, m)
    inputs = (r, poses, means, covs, seen, obs, valid, safe_ids)
    return n, m, om, inputs, _sequential_reference(om, r, poses, means, covs, seen, obs, m)


@pytest.mark.parametrize("lanes", [1, 2, 3, 12])
def test_landmark_update_equals_slot_after_slot_whatever_the_parallel_slots(lanes, slot_case, getkey):
    """Vectorised first observations plus the loop for the rest (repeats, overflow) give what
    applying the slots one after the other gives: new landmarks, repeats of new and of mapped
    landmarks (three times), unknown ids and masked NaN slots, for 1, 2, 3 and all lanes."""
    n, m, om, inputs, (ref_means, ref_covs, ref_seen, ref_ll, ref_new) = slot_case
    means, covs = inputs[2], inputs[3]
    fast = jax.jit(lambda *a: fs.update_landmarks(om, *a, lanes))
    for update in (fast, _in_order_range_bearing):
        upd, new_seen, ll, num_new = update(*inputs)
        got_means, got_covs = fs.write_rows(means, covs, upd, jnp.arange(n))
        np.testing.assert_allclose(got_means, ref_means, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(got_covs, ref_covs, rtol=1e-4, atol=1e-8)
        np.testing.assert_array_equal(new_seen, ref_seen)
        np.testing.assert_allclose(ll, ref_ll, rtol=1e-5, atol=1e-4)
        assert int(num_new) == ref_new == 2
    # the reference itself moved landmarks 0 (three observations), 1, 2, 3 and left the masked 5 alone
    means = np.asarray(means)
    assert not np.allclose(ref_means[:, [0, 1, 2, 3]], means[:, [0, 1, 2, 3]]) and np.array_equal(
        ref_means[:, 5], means[:, 5]
    )


def test_write_rows_gives_each_particle_its_ancestors_rows(getkey):
    """The step's updated rows land in the resampled maps: particle ``n`` gets row ``ancestors[n]``
    of every slot that writes, slots writing ``M`` are dropped, other landmarks keep the copied maps."""
    n, m, k = 6, 5, 4
    rng = np.random.default_rng(0)
    means = jnp.asarray(rng.normal(size=(n, m, 2)), jnp.float32)
    covs = jnp.asarray(rng.normal(size=(n, m, 2, 2)), jnp.float32)
    rows_mu = jnp.asarray(rng.normal(size=(k, n, 2)), jnp.float32)
    rows_cov = jnp.asarray(rng.normal(size=(k, n, 2, 2)), jnp.float32)
    write = jnp.asarray([3, m, 0, m], jnp.int32)
    ancestors = jnp.asarray([2, 2, 0, 5, 1, 1], jnp.int32)
    got_mu, got_cov = fs.write_rows(means, covs, fs.SlotUpdates(write, rows_mu, rows_cov), ancestors)
    want_mu, want_cov = np.array(means), np.array(covs)
    for slot, j in enumerate(np.asarray(write)):
        if j < m:
            want_mu[:, j] = np.asarray(rows_mu)[slot][np.asarray(ancestors)]
            want_cov[:, j] = np.asarray(rows_cov)[slot][np.asarray(ancestors)]
    np.testing.assert_array_equal(got_mu, want_mu)
    np.testing.assert_array_equal(got_cov, want_cov)
    assert not np.array_equal(want_mu[:, 3], np.asarray(means)[:, 3])


def test_footprint_closed_form_equals_the_generic_ekf(getkey):
    """HF_FOOTPRINT's closed-form landmark update and initialisation give what the generic EKF
    (Jacobians by autodiff, Cholesky factorisations, the noise rotated with the heading) gives, in
    float64 to 1e-10, for the footprint's isotropic noise (which the closed form relies on: it
    skips the rotation); a model without the hooks falls back to the generic path."""
    from jaxnav.models import hf_rfid

    generic = observation.HF_FOOTPRINT._replace(update=None, initialise=None)
    assert observation.HF_FOOTPRINT.update is not None and generic.update is None
    with jax.enable_x64(True):
        n = 64

        @jax.jit  # the inputs in one program (eagerly, each operation would be one)
        def draw(k_pose, k_mean, k_cov, k_z):
            poses = jax.random.uniform(k_pose, (n, 3), jnp.float64, -3.0, 3.0)
            means = poses[:, :2] + jax.random.normal(k_mean, (n, 2), jnp.float64) * 0.05
            a = jax.random.normal(k_cov, (n, 2, 2), jnp.float64) * 0.02
            covs = a @ jnp.swapaxes(a, 1, 2) + 1e-5 * jnp.eye(2)
            zs = jax.random.normal(k_z, (n, 2), jnp.float64) * 0.05
            return poses, means, covs, zs

        poses, means, covs, zs = draw(getkey(), getkey(), getkey(), getkey())
        r = hf_rfid.footprint_cov(hf_rfid.reader_params(0.06))
        r = jnp.asarray(r, jnp.float64)
        update = lambda om: jax.jit(jax.vmap(lambda p, m, c, z: fs.landmark_ekf(om, r, p, m, c, z)))  # noqa: E731
        got, ref = update(observation.HF_FOOTPRINT)(poses, means, covs, zs), update(generic)(poses, means, covs, zs)
        for field in ("mean", "cov", "nis", "log_likelihood"):
            np.testing.assert_allclose(getattr(got, field), getattr(ref, field), rtol=1e-10, atol=1e-12, err_msg=field)
        # not a comparison of two no-ops
        assert np.all(np.abs(np.asarray(got.mean) - np.asarray(means)).sum(-1) > 1e-6)
        init = lambda om: jax.jit(jax.vmap(lambda p, z: fs.landmark_init(om, r, p, z)))  # noqa: E731
        for g, f in zip(init(observation.HF_FOOTPRINT)(poses, zs), init(generic)(poses, zs)):
            np.testing.assert_allclose(g, f, rtol=1e-10, atol=1e-14)


@pytest.mark.parametrize("map_copy", ["gather", "in_place"])
def test_log_likelihood_gradient_matches_finite_differences(map_copy, getkey):
    """Reverse-mode gradients through ``run`` (the slot loop and the in-place map copy have
    data-dependent trip counts; their custom JVPs make them differentiable) agree with central
    differences of the summed log-likelihood in float64, with resampling at every step. With the
    ``"naive"`` estimator: for a fixed key it is the derivative of the function computed, which is what
    central differences see; the default ``"score"`` adds the resampling's score, which they cannot."""
    from jax.test_util import check_grads

    steps = 15
    sim = jax.tree_util.tree_map(lambda x: x[0], _sims(getkey(), 1, steps))  # float32, as in every test
    with jax.enable_x64(True):
        sim = jax.tree_util.tree_map(lambda x: x.astype(np.float64) if np.issubdtype(x.dtype, np.floating) else x, sim)
        cfg = fs.FastSLAMConfig(
            num_particles=16, num_landmarks=8, resampling="systematic", map_copy=map_copy, gradient="naive"
        )
        motion_noise = jax.tree_util.tree_map(lambda x: np.asarray(x, np.float64), MOTION)
        k_init, k_run = getkey(), getkey()

        @jax.jit  # init with run: its operations are not compiled one by one (and again for the derivatives)
        def loss(sd):
            params = fs.FastSLAMParams(motion_noise, lm.RangeBearingNoise(sd))
            state = fs.init(k_init, cfg, params, jnp.asarray(X0, jnp.float64))
            _, trace = fs.run.jitted(k_run, state, cfg, params, sim.controls, sim.observations)
            return jnp.sum(trace.log_likelihood)

        sd = jnp.asarray([0.1, 0.03], jnp.float64)
        assert bool(jnp.all(jnp.isfinite(jax.grad(loss)(sd))))
        check_grads(loss, (sd,), order=1, modes=["rev", "fwd"], eps=1e-6, rtol=1e-4, atol=1e-4)


def _robot_frame_model():
    """A second sensor, position of the landmark in the robot frame (the HF-RFID kind of measurement)."""

    def mean(pose, landmark):
        s, c = fastmath.sincos(pose[2])
        d = landmark - pose[:2]
        return jnp.stack([c * d[0] + s * d[1], -s * d[0] + c * d[1]])

    def inverse(pose, z):
        s, c = fastmath.sincos(pose[2])
        return pose[:2] + jnp.stack([c * z[0] - s * z[1], s * z[0] + c * z[1]])

    class Noise(tuple):
        pass

    return observation.ObservationModel(
        "robot_frame_xy", 2, 2, mean, inverse, lambda sd: jnp.diag(sd**2), (), lambda sd: None
    )


def _isotropic_footprint_model():
    """HF_FOOTPRINT (closed-form update, pose-free covariances) with an isotropic noise ``sd² I``
    given directly, so that it runs on the range-bearing world's robot-frame positions."""
    return observation.HF_FOOTPRINT._replace(
        name="isotropic_footprint", noise_cov=lambda sd: sd * sd * jnp.eye(2), validate=lambda sd: None
    )


# one instance for the file: the configurations that name it are equal, and share their programs
ISOTROPIC_FOOTPRINT = _isotropic_footprint_model()


@jax.jit
def _robot_frame_z(true_poses, key, sd):
    rel = jax.vmap(lambda x: jax.vmap(lambda m: hf_rfid.robot_frame(x, m))(LANDMARKS))(true_poses)
    return rel + jax.random.normal(key, rel.shape) * sd


def _robot_frame_sim(key, steps, sd):
    """Controls and observations of the landmark world seen as robot-frame positions with noise ``sd``
    (NumPy arrays): the first ``steps`` steps of a run of :func:`_world_runs` and of its noise."""
    assert steps <= SIM_STEPS
    k_sim, k_noise = jax.random.split(key)
    truth = _world_runs(np.broadcast_to(np.asarray(k_sim), (SIM_RUNS, *k_sim.shape)))  # run 0: simulate(k_sim)
    truth = jax.tree_util.tree_map(lambda x: x[0], truth)
    z = np.asarray(_robot_frame_z(truth.true_poses, k_noise, np.broadcast_to(np.asarray(sd, np.float32), (2,))))
    truth = jax.tree_util.tree_map(lambda x: x[:steps], truth)
    return truth.controls, truth.observations._replace(z=z[:steps])


def test_generic_observation_model(getkey):
    """FastSLAM maps a world observed through a different sensor model supplied by the caller."""
    om = _robot_frame_model()
    sd = jnp.asarray([0.05, 0.05])
    u, obs = _robot_frame_sim(getkey(), 150, sd)
    cfg = fs.FastSLAMConfig(num_particles=50, num_landmarks=8, observation_model=om)
    params = fs.FastSLAMParams(MOTION, sd)
    final, tr = fs.run(getkey(), _init(getkey(), cfg, params, X0), cfg, params, u, obs)
    m, seen = fs.map_estimate(final)
    err = np.linalg.norm(np.asarray(m) - np.asarray(LANDMARKS), axis=1)[np.asarray(seen)]
    assert np.asarray(seen).all() and err.mean() < 0.15, err


@pytest.mark.parametrize("num_landmarks, steps, unroll", [(8, 12, 1), (100, 13, 2)])
def test_step_loop_equals_run(num_landmarks, steps, unroll, getkey):
    """``run`` (one step per scan iteration for small maps, two for gathered maps of at least
    UNROLL_MIN_FLOATS per particle, with an odd step count) equals a loop of ``step``."""
    sims = _sims(getkey(), 1, steps)
    sim = jax.tree_util.tree_map(lambda x: x[0], sims)
    cfg = fs.FastSLAMConfig(num_particles=32, num_landmarks=num_landmarks, version=2)
    assert fs.run_unroll(cfg) == unroll
    key = getkey()
    init_key = getkey()
    final, trace = fs.run(key, _init(init_key, cfg, PARAMS, X0), cfg, PARAMS, sim.controls, sim.observations)
    estimates = np.asarray(trace.estimate)
    state = _init(init_key, cfg, PARAMS, X0)
    for t in range(steps):
        obs_t = jax.tree_util.tree_map(lambda x: x[t], sim.observations)
        state, info = fs.step(jax.random.fold_in(key, t), state, cfg, PARAMS, sim.controls[t], obs_t)
        np.testing.assert_allclose(info.estimate, estimates[t], rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(state.means, final.means, rtol=1e-4, atol=1e-4)


def test_bad_input_and_single_compilation(getkey):
    with pytest.raises(ValueError, match="version"):
        fs.FastSLAMConfig(version=3)
    with pytest.raises(ValueError, match="observation_model"):
        fs.FastSLAMConfig(observation_model="sonar")
    # test_known_map_prior_tracks_pose's shapes: its compiled run is reused
    cfg = fs.FastSLAMConfig(num_particles=200, num_landmarks=8)
    with pytest.raises(ValueError, match="sensor.sd"):
        fs.init(getkey(), cfg, fs.FastSLAMParams(MOTION, lm.RangeBearingNoise(jnp.asarray([0.1, -1.0]))), X0)
    state = _init(getkey(), cfg, PARAMS, X0)
    a, b = (jax.tree_util.tree_map(lambda x: x[0], _sims(getkey(), 1, 100)) for _ in range(2))
    with pytest.raises(ValueError, match="same number of steps"):
        fs.run(getkey(), state, cfg, PARAMS, a.controls[:5], a.observations)
    fs.run(getkey(), state, cfg, PARAMS, a.controls, a.observations)
    before = fs.run.trace_count()
    fs.run(
        getkey(), state, cfg, PARAMS._replace(sensor=lm.RangeBearingNoise(SENSOR.sd * 2)), b.controls, b.observations
    )
    assert fs.run.trace_count() == before


def test_in_place_map_copy_equals_gather(getkey, monkeypatch):
    """Large maps (≥ IN_PLACE_MIN_FLOATS floats per particle) are resampled by the in-place row
    copy; the step's result must equal the plain-gather path bit for bit (same key, same state)."""
    m = 600  # 600 · 6 floats per particle ≥ 3072: the in-place path
    cfg = fs.FastSLAMConfig(num_particles=24, num_landmarks=m)
    rng = np.random.default_rng(0)
    means = rng.uniform(0, 10, (m, 2)).astype(np.float32)
    state = _init(getkey(), cfg, PARAMS, X0, jnp.asarray([0.05, 0.05, 0.02]), landmark_means=means)
    # give every particle a different map so that a wrong copy shows
    state = state._replace(means=np.asarray(state.means) + rng.normal(0, 0.05, state.means.shape).astype(np.float32))
    ids = np.asarray([3, 77, 500, 599, 3], np.int32)
    obs = lm.RangeBearingObs(ids, _predict(X0, means[ids]), np.ones(5, bool))
    key, control = getkey(), jnp.asarray([0.3, 0.1, 0.25])
    paths = []  # per trace, whether it copies in place

    def step():
        def kernel(key, state, config, params, control, obs):  # a new function each time: traced after the patch too
            paths.append(fs._copies_in_place(config))
            return fs.kernel(key, state, config, params, control, obs)

        return jax.jit(kernel, static_argnames="config")(key, state, cfg, PARAMS, control, obs)

    in_place, info = step()
    assert bool(info.resampled)
    ancestors_moved = not np.array_equal(np.asarray(in_place.means), np.asarray(state.means))
    monkeypatch.setattr(fs, "IN_PLACE_MIN_FLOATS", 10**9)
    gathered, _ = step()
    assert paths == [True, False]  # the two paths were compiled, not one program run twice
    for a, b in zip(in_place, gathered):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert ancestors_moved


def test_map_copy_choice_gives_the_same_maps_and_bad_choices_are_refused(getkey):
    """``map_copy="gather"`` (for vmapped batch runs) and ``"in_place"`` copy the same maps, also on
    small maps where "auto" would gather; every scheme's ancestors are sorted, so every scheme may copy in place.
    With the ``"naive"`` gradient: the default's score term (a gather of the log-weights, zero in value)
    changes how XLA:CPU fuses the two programs at the suite's optimisation level 0, which then round a
    heading differently in the last bit (with XLA's defaults they agree); the copies are compared here."""
    m = 40
    rng = np.random.default_rng(1)
    means = rng.uniform(0, 10, (m, 2)).astype(np.float32)
    ids = np.asarray([1, 7, 33], np.int32)
    obs = lm.RangeBearingObs(ids, _predict(X0, means[ids]), np.ones(3, bool))
    key, k0, control = getkey(), getkey(), jnp.asarray([0.3, 0.1, 0.25])
    out = {}
    for mode in ("gather", "in_place"):
        cfg = fs.FastSLAMConfig(num_particles=16, num_landmarks=m, map_copy=mode, gradient="naive")
        state = _init(k0, cfg, PARAMS, X0, jnp.asarray([0.05, 0.05, 0.02]), landmark_means=means)
        state = state._replace(
            means=np.asarray(state.means) + rng.normal(0, 0.05, state.means.shape).astype(np.float32)
        )
        out[mode] = jax.jit(fs.kernel, static_argnames="config")(key, state, cfg, PARAMS, control, obs)[0]
        rng = np.random.default_rng(1)  # the same perturbation for both modes
        rng.uniform(0, 10, (m, 2))
    for a, b in zip(out["gather"], out["in_place"]):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    # Every scheme returns sorted ancestors, so every scheme may copy in place.
    assert set(resampling.SCHEMES) <= set(resampling.SORTED_SCHEMES)
    for scheme in resampling.SCHEMES:
        fs.FastSLAMConfig(map_copy="in_place", resampling=scheme)
    with pytest.raises(ValueError, match="map_copy"):
        fs.FastSLAMConfig(map_copy="copy")


@pytest.mark.parametrize("version, map_copy", [(1, "gather"), (1, "in_place"), (2, "gather")])
def test_shared_covariances_filter_like_per_particle_ones(version, map_copy, getkey):
    """With a pose-free covariance update, FastSLAM's one covariance per landmark ("shared", the
    default for such models) gives the filter of per-particle covariances: every particle's
    covariance equals the shared one, and poses, maps and estimates agree over 80 steps
    with resampling at every step."""
    om = ISOTROPIC_FOOTPRINT
    sd = jnp.asarray(0.05)
    u, obs = _robot_frame_sim(getkey(), 80, sd)
    params = fs.FastSLAMParams(MOTION, sd)
    key, k0 = getkey(), getkey()
    out = {}
    for cov in ("per_particle", "shared"):
        cfg = fs.FastSLAMConfig(
            num_particles=32, num_landmarks=8, version=version, observation_model=om, map_copy=map_copy, covariance=cov
        )
        # init reads the sizes, the model and the covariance layout only: one init program per layout
        init_cfg = fs.FastSLAMConfig(num_particles=32, num_landmarks=8, observation_model=om, covariance=cov)
        state = _init(k0, init_cfg, params, X0, jnp.asarray([0.02, 0.02, 0.01]))
        out[cov] = fs.run(key, state, cfg, params, u, obs)
    (pp, pp_trace), (sh, sh_trace) = out["per_particle"], out["shared"]
    assert pp.covs.shape == (32, 8, 2, 2) and sh.covs.shape == (8, 2, 2)
    assert np.all(np.asarray(sh.seen)) and np.any(np.asarray(sh_trace.resampled))
    np.testing.assert_allclose(pp.covs, np.broadcast_to(np.asarray(sh.covs), pp.covs.shape), rtol=1e-5, atol=1e-10)
    assert np.sum(np.asarray(sh.covs)[:, 0, 0] < 0.5 * 0.05**2) >= 4  # most landmarks updated past the initial R
    for a, b in ((pp.poses, sh.poses), (pp.means, sh.means), (pp_trace.estimate, sh_trace.estimate)):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(pp_trace.log_likelihood, sh_trace.log_likelihood, rtol=1e-4, atol=1e-3)


def test_shared_covariance_gradient_matches_finite_differences(getkey):
    """Reverse and forward-mode gradients of the summed log-likelihood through ``run`` with
    shared covariances (and the in-place copy of the means alone) agree with central differences
    (the ``"naive"`` estimator, as in :func:`test_log_likelihood_gradient_matches_finite_differences`)."""
    from jax.test_util import check_grads

    u, obs = _robot_frame_sim(getkey(), 15, 0.05)  # float32, as in every test
    with jax.enable_x64(True):
        u, obs = u.astype(np.float64), obs._replace(z=obs.z.astype(np.float64))
        cfg = fs.FastSLAMConfig(
            num_particles=16,
            num_landmarks=8,
            observation_model=ISOTROPIC_FOOTPRINT,
            map_copy="in_place",
            gradient="naive",
        )
        assert cfg.shared_covariance
        motion_noise = jax.tree_util.tree_map(lambda x: np.asarray(x, np.float64), MOTION)
        k_init, k_run = getkey(), getkey()

        @jax.jit  # init with run: its operations are not compiled one by one (and again for the derivatives)
        def loss(sd):
            params = fs.FastSLAMParams(motion_noise, sd)
            state = fs.init(k_init, cfg, params, jnp.asarray(X0, jnp.float64))
            _, trace = fs.run.jitted(k_run, state, cfg, params, u, obs)
            return jnp.sum(trace.log_likelihood)

        sd = jnp.asarray(0.05, jnp.float64)
        assert bool(jnp.isfinite(jax.grad(loss)(sd)))
        check_grads(loss, (sd,), order=1, modes=["rev", "fwd"], eps=1e-6, rtol=1e-4, atol=1e-4)


def test_covariance_choice_resolves_and_bad_choices_are_refused(getkey):
    """ "auto" shares the covariances for HF_FOOTPRINT only; "shared" is refused for a model whose
    covariance update reads the pose; a state of the other layout is refused."""
    assert fs.FastSLAMConfig(observation_model="hf_footprint").shared_covariance
    assert not fs.FastSLAMConfig(observation_model="hf_footprint", covariance="per_particle").shared_covariance
    assert not fs.FastSLAMConfig(observation_model="range_bearing").shared_covariance
    cfg = fs.FastSLAMConfig(num_landmarks=10, observation_model="hf_footprint")
    assert cfg.map_floats == 10 * 2
    assert (
        fs.FastSLAMConfig(num_landmarks=10, covariance="per_particle", observation_model="hf_footprint").map_floats
        == 60
    )
    with pytest.raises(ValueError, match="pose_free_covariance"):
        fs.FastSLAMConfig(observation_model="range_bearing", covariance="shared")
    with pytest.raises(ValueError, match="covariance"):
        fs.FastSLAMConfig(covariance="diagonal")
    om = ISOTROPIC_FOOTPRINT
    params = fs.FastSLAMParams(MOTION, jnp.asarray(0.05))
    shared = fs.FastSLAMConfig(num_particles=8, num_landmarks=8, observation_model=om)
    per_particle = fs.FastSLAMConfig(num_particles=8, num_landmarks=8, observation_model=om, covariance="per_particle")
    state = _init(getkey(), per_particle, params, X0)
    u, obs = _robot_frame_sim(getkey(), 3, 0.05)
    with pytest.raises(ValueError, match="state.covs"):
        fs.run(getkey(), state, shared, params, u, obs)
    # a model that claims pose-free covariances but rotates its noise with the heading
    liar = _robot_frame_model()._replace(name="liar", pose_free_covariance=True)
    cfg = fs.FastSLAMConfig(num_particles=8, num_landmarks=8, observation_model=liar)
    liar_params = fs.FastSLAMParams(MOTION, jnp.asarray([0.05, 0.02]))
    with pytest.raises(ValueError, match="declares pose_free_covariance"):
        fs.run(getkey(), _init(getkey(), cfg, liar_params, X0), cfg, liar_params, u, obs)
