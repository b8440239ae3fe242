"""PF-SLAM and PS-SLAM with landmark sensors other than the HF readers: range and bearing,
range-only beacons (Gaussian and Student-t), and a sensor written in the test.

The HF behaviour (the default sensor) is tested in test_pf_slam.py and test_hf_slam_runs.py; its
outputs are bitwise those of the filters before the sensor became a configuration field.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.models import landmarks as lm
from jaxnav.models import motion
from jaxnav.models import range_only as ro
from jaxnav.models.sensor import LandmarkSensor
from jaxnav.sim import landmark_world as lw
from jaxnav.sim import range_world as rw
from jaxnav.sim import trajectories as tr
from jaxnav.slam import pf_slam, ps_slam

ROOM = lw.square_room_landmarks(10.0, 8)
MOTION = motion.VelocityNoise(jnp.asarray([0.01, 0.005, 0.005, 0.01, 0.0, 0.0]), jnp.asarray([0.01, 0.01, 0.005]))
START = jnp.asarray([5.0, 2.0, 0.0])
CONTROLS = tr.loop_controls(400, speed=0.5, turn_rate=0.15, dt=0.25)  # two laps of a 3.3 m circle
RB_NOISE = lm.RangeBearingNoise(jnp.asarray([0.1, 0.02]))
RANGE_NOISE = ro.range_noise(0.1, bias=0.1, dof=4.0)
STILL = jnp.asarray([0.0, 0.0, 0.1])  # (v, ω, Δt): no motion
NO_MOTION = motion.VelocityNoise(jnp.zeros(6), jnp.zeros(3))


@jax.jit  # one program for every run's dead reckoning (a scan of a fresh lambda per call traces anew)
def _odometry(start, controls):
    model = motion.get_motion_model("velocity")
    return jax.lax.scan(lambda p, u: (model.mean(p, u),) * 2, start, controls)[1]


def _config(module, sensor, **kw):
    config_type = pf_slam.PFSLAMConfig if module is pf_slam else ps_slam.PSSLAMConfig
    extra = {"lag": 10} if module is ps_slam else {}
    base = dict(num_particles=300, num_tag_particles=100, max_tags=8, motion_model="velocity", sensor=sensor)
    return config_type(**{**base, **extra, **kw})


def _params(module, noise, motion_noise=MOTION):
    if module is pf_slam:
        return pf_slam.PFSLAMParams(motion_noise, noise)
    return ps_slam.PSSLAMParams(motion_noise, noise, jnp.float32(0.01))


def _errors(module, config, params, run, seed):
    state = module.init(jax.random.PRNGKey(seed), config, params, START)
    final, trace = module.run(jax.random.PRNGKey(seed + 1), state, config, params, run.controls, run.observations)
    estimates, seen = module.map_estimate(final)
    truth = np.asarray(run.true_poses)[:, :2]
    robot = np.linalg.norm(np.asarray(trace.estimate)[:, :2] - truth, axis=1).mean()
    odometry = np.linalg.norm(np.asarray(_odometry(START, run.controls))[:, :2] - truth, axis=1).mean()
    landmark = np.linalg.norm(np.asarray(estimates) - np.asarray(ROOM), axis=1)
    return robot, odometry, landmark, np.asarray(seen), final


@pytest.mark.parametrize("module", [pf_slam, ps_slam])
def test_range_bearing_slam_maps_a_room_and_beats_odometry(module):
    """Eight landmarks on the walls of a 10 m room, seen within 6 m (3.3 per step), σ = (0.1 m,
    0.02 rad), two laps of a circle. Measured (seeds 0 and 10): robot error 0.14 and 0.10 m (PF),
    0.19 and 0.09 m (PS) against odometry's 0.74 and 0.34 m; mean landmark error 0.21 and 0.18 m
    (PF), 0.25 and 0.16 m (PS). Bounds: robot error under half of odometry's, every landmark seen,
    mean landmark error under 0.4 m."""
    config = _config(module, lm.RANGE_BEARING_LANDMARK_SENSOR)
    params = _params(module, RB_NOISE)
    for seed in (0, 10):
        run = lw.simulate(jax.random.PRNGKey(seed), ROOM, START, CONTROLS, MOTION, RB_NOISE, max_range=6.0)
        robot, odometry, landmark, seen, _ = _errors(module, config, params, run, seed)
        assert seen.all()
        assert robot < 0.5 * odometry, (seed, robot, odometry)
        assert landmark.mean() < 0.4, (seed, landmark)


def test_range_only_beacons_start_on_a_ring_and_collapse_to_points():
    """A beacon seen once lies on a ring: after the first step every seen beacon's particles sit at
    the measured range minus the bias from the robot (within 4σ plus the start's spread) in every
    direction; after two laps they have collapsed. Measured (PF-SLAM, J = 300, mixture weighting,
    seed 0): robot error 0.19 m against odometry's 0.74 m, landmark errors 0.06–0.42 m (mean 0.23),
    the particles' spread (standard deviation per axis) 3.4 m after the first step and 0.0007 m at
    the end. Bounds: robot error under half of odometry's, mean landmark error under 0.5 m, final spread
    under a tenth of the first."""
    run = rw.simulate(jax.random.PRNGKey(0), ROOM, START, CONTROLS, MOTION, RANGE_NOISE, max_range=6.0)
    config = _config(
        pf_slam, ro.RANGE_ONLY_LANDMARK_SENSOR, num_tag_particles=300, recovery=False, robot_likelihood="mixture"
    )
    params = _params(pf_slam, RANGE_NOISE)
    state = pf_slam.init(jax.random.PRNGKey(0), config, params, START)
    first_obs = jax.tree_util.tree_map(lambda a: a[0], run.observations)
    after_one, info = pf_slam.step(jax.random.PRNGKey(5), state, config, params, run.controls[0], first_obs)
    seen = np.asarray(first_obs.mask)
    assert seen.sum() >= 2 and int(info.num_new) == seen.sum()
    pose = np.asarray(info.estimate)
    for b in np.flatnonzero(seen):
        offsets = np.asarray(after_one.tags.particles[b]) - pose[:2]
        radius = np.linalg.norm(offsets, axis=1)
        expected = float(first_obs.z[b, 0]) - 0.1
        assert np.all(np.abs(radius - expected) < 4 * 0.1 + 0.05), (b, radius.min(), radius.max(), expected)
        quadrant = np.floor((np.arctan2(offsets[:, 1], offsets[:, 0]) + math.pi) / (math.pi / 2)).astype(int)
        assert np.bincount(quadrant, minlength=4).min() > 0.15 * 300, b
    first_spread = np.asarray(after_one.tags.particles)[seen].std(axis=1).mean()

    robot, odometry, landmark, seen_end, final = _errors(pf_slam, config, params, run, 0)
    final_spread = np.asarray(final.tags.particles).std(axis=1).mean()
    assert seen_end.all()
    assert robot < 0.5 * odometry, (robot, odometry)
    assert landmark.mean() < 0.5, landmark
    assert final_spread < 0.1 * first_spread, (first_spread, final_spread)


def _ring_state(config, params, robot_xy, beacon_particles):
    state = pf_slam.init(jax.random.PRNGKey(0), config, params, jnp.zeros(3))
    tags = state.tags
    particles = jnp.asarray(beacon_particles, jnp.float32)
    tags = tags._replace(
        particles=tags.particles.at[2].set(particles),
        estimates=tags.estimates.at[2].set(particles.mean(0)),
        counts=tags.counts.at[2].set(1),
    )
    poses = jnp.asarray([[x, y, 0.0] for x, y in robot_xy], jnp.float32)
    return state._replace(poses=poses, tags=tags)


@pytest.mark.parametrize("sensor", [ro.RANGE_ONLY_LANDMARK_SENSOR, ro.RANGE_ONLY_T_LANDMARK_SENSOR])
def test_mixture_weighting_matches_the_hand_computed_predictive_density(sensor):
    """Two robot particles, a beacon held by three particles, one range of 2.0 m: the robot's
    log-weights are ``log Σ_j w_j p(z | x_i, m_j)`` normalised (not the density at the particles'
    mean, which here lies 1.5 m from every particle), and the log-likelihood increment is
    ``log Σ_i w_i Σ_j w_j p(z | x_i, m_j)``."""
    config = _config(pf_slam, sensor, num_particles=2, num_tag_particles=3, recovery=False, robot_likelihood="mixture")
    noise = ro.range_noise(0.2, bias=0.05, dof=3.0)
    params = _params(pf_slam, noise, NO_MOTION)
    robots = [(0.0, 0.0), (0.5, 0.0)]
    beacon = [(2.0, 0.0), (-2.0, 0.0), (0.0, 1.5)]
    state = _ring_state(config, params, robots, beacon)
    obs = ro.RangeObs(jnp.asarray([2, 0]), jnp.asarray([[2.05], [0.0]]), jnp.asarray([True, False]))
    kept = jax.tree_util.tree_map(jnp.copy, state)  # step donates its state
    _, info = pf_slam.step(jax.random.PRNGKey(1), state, config, params, STILL, obs)

    def density(e):
        u = e / 0.2
        if sensor is ro.RANGE_ONLY_LANDMARK_SENSOR:
            return np.exp(-0.5 * u * u) / (0.2 * math.sqrt(2 * math.pi))
        nu = 3.0
        c = math.gamma((nu + 1) / 2) / (math.gamma(nu / 2) * math.sqrt(nu * math.pi) * 0.2)
        return c * (1 + u * u / nu) ** (-(nu + 1) / 2)

    mix = np.array(
        [np.mean([density(2.05 - (np.hypot(mx - x, my - y) + 0.05)) for mx, my in beacon]) for x, y in robots]
    )
    np.testing.assert_allclose(float(info.log_likelihood), np.log(mix.mean()), rtol=1e-5)
    np.testing.assert_allclose(float(info.ess), 1.0 / np.sum((mix / mix.sum()) ** 2), rtol=1e-5)
    estimate_weighting = _config(pf_slam, sensor, num_particles=2, num_tag_particles=3, recovery=False)
    _, info_estimate = pf_slam.step(jax.random.PRNGKey(1), kept, estimate_weighting, params, STILL, obs)
    assert abs(float(info_estimate.log_likelihood) - np.log(mix.mean())) > 1.0


def _offset_density(points, pose, z, sd):
    """log N(z; R(θ)ᵀ(m − p), sd² I): a sensor that measures a landmark's position in the robot frame."""
    c, s = jnp.cos(pose[..., 2]), jnp.sin(pose[..., 2])
    dx, dy = points[..., 0] - pose[..., 0], points[..., 1] - pose[..., 1]
    ex, ey = c * dx + s * dy - z[0], -s * dx + c * dy - z[1]
    return -0.5 * (ex * ex + ey * ey) / sd**2 - 2 * jnp.log(sd) - math.log(2 * math.pi)


def _offset_initialise(key, pose, z, sd, num):
    c, s = jnp.cos(pose[2]), jnp.sin(pose[2])
    body = z + sd * jax.random.normal(key, (num, 2), pose.dtype)
    return jnp.stack([pose[0] + c * body[:, 0] - s * body[:, 1], pose[1] + s * body[:, 0] + c * body[:, 1]], -1)


OFFSET_SENSOR = LandmarkSensor(
    "relative_position",
    2,
    lambda obs, sd: obs.z,
    lambda points, pose, z, sd: _offset_density(points, pose, z, sd),
    lambda poses, point, z, sd: _offset_density(point, poses, z, sd),
    _offset_initialise,
)


def test_a_user_written_landmark_sensor_runs_in_pf_and_ps_slam():
    """A sensor written here in a few lines (the landmark's position in the robot frame, σ = 0.1 m;
    no ``locate``, so ``recovery=False``): PF-SLAM and PS-SLAM map the room with it. Measured (seed 3):
    mean landmark error 0.16 (PF) and 0.12 m (PS), robot 0.13 and 0.12 m against odometry's 0.47 m.
    Bounds: landmarks within 0.3 m on average, robot error under half of odometry's."""
    with pytest.raises(ValueError, match="recovery=True needs a sensor that can place the robot"):
        _config(pf_slam, OFFSET_SENSOR)
    rb = lw.simulate(jax.random.PRNGKey(3), ROOM, START, CONTROLS, MOTION, RB_NOISE, max_range=6.0)
    pose = rb.true_poses[:, None, :]
    z_true = jnp.stack(
        [
            jnp.cos(pose[..., 2]) * (ROOM[:, 0] - pose[..., 0]) + jnp.sin(pose[..., 2]) * (ROOM[:, 1] - pose[..., 1]),
            -jnp.sin(pose[..., 2]) * (ROOM[:, 0] - pose[..., 0]) + jnp.cos(pose[..., 2]) * (ROOM[:, 1] - pose[..., 1]),
        ],
        axis=-1,
    )
    z = z_true + 0.1 * jax.random.normal(jax.random.PRNGKey(4), z_true.shape)
    run = rb._replace(observations=lm.RangeBearingObs(rb.observations.ids, z, rb.observations.mask))
    for module in (pf_slam, ps_slam):
        config = _config(module, OFFSET_SENSOR, recovery=False)
        robot, odometry, landmark, seen, _ = _errors(module, config, _params(module, jnp.float32(0.1)), run, 3)
        assert seen.all() and landmark.mean() < 0.3, (module.__name__, landmark)
        assert robot < 0.5 * odometry, (module.__name__, robot, odometry)


def test_landmark_sensor_configuration_and_inputs_are_checked_by_name():
    with pytest.raises(ValueError, match="sensor must be a jaxnav.models.sensor.LandmarkSensor"):
        _config(pf_slam, lm.RANGE_BEARING_SENSOR)
    with pytest.raises(ValueError, match="landmark_dim"):
        _config(pf_slam, OFFSET_SENSOR._replace(landmark_dim=0), recovery=False)
    with pytest.raises(ValueError, match="robot_likelihood"):
        _config(pf_slam, lm.RANGE_BEARING_LANDMARK_SENSOR, robot_likelihood="mean")
    config = _config(ps_slam, ro.RANGE_ONLY_LANDMARK_SENSOR, num_particles=4, num_tag_particles=4)
    with pytest.raises(ValueError, match=r"params\.sensor must be RangeNoise"):
        ps_slam.init(jax.random.PRNGKey(0), config, _params(ps_slam, RB_NOISE), START)
    params = _params(ps_slam, RANGE_NOISE)
    with pytest.raises(ValueError, match=r"params\.sensor\.sd"):
        ps_slam.init(jax.random.PRNGKey(0), config, _params(ps_slam, RANGE_NOISE._replace(sd=jnp.float32(-1))), START)
    state = ps_slam.init(jax.random.PRNGKey(0), config, params, START)
    rb_obs = lm.RangeBearingObs(jnp.zeros(2, jnp.int32), jnp.ones((2, 2)), jnp.ones(2, bool))
    with pytest.raises(ValueError, match="detections must be a RangeObs"):
        ps_slam.step(jax.random.PRNGKey(1), state, config, params, STILL, rb_obs)
    bad_shape = ro.RangeObs(jnp.zeros(2, jnp.int32), jnp.ones((2, 2)), jnp.ones(2, bool))
    with pytest.raises(ValueError, match=r"observations\.z"):
        ps_slam.step(jax.random.PRNGKey(1), state, config, params, STILL, bad_shape)


def test_an_unusable_range_inside_a_callers_jit_is_dropped_and_counted():
    """Under the caller's ``jit`` the values cannot be refused: a NaN range in a set slot is
    dropped (the beacon is not initialised) and counted in ``info.num_ignored``; the other slot
    initialises its beacon."""
    config = _config(pf_slam, ro.RANGE_ONLY_LANDMARK_SENSOR, num_particles=8, num_tag_particles=8)
    params = _params(pf_slam, RANGE_NOISE)
    state = pf_slam.init(jax.random.PRNGKey(0), config, params, START)
    obs = ro.RangeObs(jnp.asarray([1, 4]), jnp.asarray([[jnp.nan], [3.0]]), jnp.asarray([True, True]))
    final, info = jax.jit(pf_slam.kernel, static_argnums=2)(jax.random.PRNGKey(1), state, config, params, STILL, obs)
    assert int(info.num_ignored) == 1 and int(info.num_new) == 1
    assert int(final.tags.counts[1]) == 0 and int(final.tags.counts[4]) == 1
    assert np.isfinite(np.asarray(final.tags.particles)).all()


@functools.partial(jax.jit, static_argnums=1)
def _density_checks(noise, heavy):
    """The quantities test_range_densities_are_normalised_and_differentiable checks, in one program."""
    e = jnp.linspace(-12.0, 12.0, 100_001)
    total = jnp.trapezoid(jnp.exp(ro.log_density(e, noise, heavy)), e)

    def loss(p):
        return jnp.sum(ro.log_density(jnp.asarray([0.05, -0.3, 1.2]) - p.bias, p, heavy))

    grads = jax.grad(loss)(noise)
    wide = noise._replace(dof=jnp.float32(1e8))
    near = jnp.linspace(-1.0, 1.0, 101)
    return total, grads, ro.log_density(near, wide, True), ro.log_density(near, wide, False)


@pytest.mark.parametrize("heavy", [False, True])
def test_range_densities_are_normalised_and_differentiable(heavy):
    """The residual density integrates to one (trapezoid on ±60σ, 10⁵ points); its log-likelihood has
    finite gradients in σ, the bias and ν (the parameters a calibration learns); Student-t with
    ν = 10⁸ is the Gaussian within ±5σ (to 2·10⁻⁵ in float32: its normaliser does not cancel)."""
    noise = ro.range_noise(0.2, bias=0.1, dof=2.5)
    total, grads, wide_t, wide_gauss = _density_checks(noise, heavy)
    total = float(total)
    assert abs(total - 1.0) < (2e-3 if heavy else 1e-5), total  # t(2.5) puts ~1e-3 beyond ±60σ
    assert all(np.isfinite(float(g)) for g in grads)
    assert (float(grads.dof) != 0.0) == heavy
    np.testing.assert_allclose(wide_t, wide_gauss, atol=2e-5)


@pytest.mark.parametrize("sensor", [ro.RANGE_ONLY_SENSOR, ro.RANGE_ONLY_T_SENSOR])
def test_mcl_localizes_with_ranges_to_known_beacons(sensor):
    """MCL with the range-only pose sensor on the known room (the bias known): measured (seed 2)
    mean error 0.041 m (Gaussian) and 0.042 m (Student-t) against odometry's 0.58 m; bound 0.2 m."""
    from jaxnav.localization import mcl

    run = rw.simulate(jax.random.PRNGKey(2), ROOM, START, CONTROLS, MOTION, RANGE_NOISE, max_range=6.0)
    config = mcl.MCLConfig(num_particles=500, motion_model="velocity", sensor=sensor)
    params = lm.LandmarkMapParams(MOTION, RANGE_NOISE, ROOM)
    state = mcl.init(jax.random.PRNGKey(0), config, params, START, jnp.asarray([0.1, 0.1, 0.05]))
    _, trace = mcl.run(jax.random.PRNGKey(1), state, config, params, run.controls, run.observations)
    error = np.linalg.norm(np.asarray(trace.estimate)[:, :2] - np.asarray(run.true_poses)[:, :2], axis=1)
    assert error.mean() < 0.2, error.mean()


def test_range_world_refuses_bad_arguments_by_name():
    with pytest.raises(ValueError, match="beacons"):
        rw.simulate(jax.random.PRNGKey(0), jnp.ones((3, 3)), START, CONTROLS[:5], MOTION, RANGE_NOISE)
    with pytest.raises(ValueError, match="max_range"):
        rw.simulate(jax.random.PRNGKey(0), ROOM, START, CONTROLS[:5], MOTION, RANGE_NOISE, max_range=-1.0)
    with pytest.raises(ValueError, match=r"noise\.dof"):
        rw.simulate(jax.random.PRNGKey(0), ROOM, START, CONTROLS[:5], MOTION, RANGE_NOISE._replace(dof=jnp.float32(0)))
    with pytest.raises(ValueError, match="key"):
        rw.simulate(None, ROOM, START, CONTROLS[:5], MOTION, RANGE_NOISE)
    run = rw.simulate(jax.random.PRNGKey(0), ROOM, START, CONTROLS[:5], MOTION, RANGE_NOISE, heavy_tailed=True)
    assert run.observations.z.shape == (5, 8, 1) and np.isfinite(np.asarray(run.observations.z)).all()
