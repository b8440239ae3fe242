"""Motion models: noise-free means against closed forms, sampling statistics, gradients."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxnav.models import motion


def test_velocity_mean_matches_thrun_arc():
    """Thrun et al. eq. 5.9: x' = x − (v/ω) sin θ + (v/ω) sin(θ + ωΔt), etc."""
    pose = jnp.asarray([1.0, 2.0, 0.3])
    v, w, dt = 0.7, 0.4, 0.5
    got = motion.velocity_mean(pose, jnp.asarray([v, w, dt]))
    r = v / w
    want = [
        1.0 - r * math.sin(0.3) + r * math.sin(0.3 + w * dt),
        2.0 + r * math.cos(0.3) - r * math.cos(0.3 + w * dt),
        0.3 + w * dt,
    ]
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)


def test_velocity_mean_straight_line_and_finite_gradient_at_zero_turn():
    pose = jnp.asarray([0.0, 0.0, math.pi / 2])
    got = motion.velocity_mean(pose, jnp.asarray([2.0, 0.0, 0.5]))
    np.testing.assert_allclose(got, [0.0, 1.0, math.pi / 2], atol=1e-6)
    jac = jax.jacfwd(motion.velocity_mean, argnums=(0, 1))(pose, jnp.asarray([2.0, 0.0, 0.5]))
    assert all(np.all(np.isfinite(j)) for j in jac)


def test_odometry_mean_reproduces_the_odometry_displacement():
    """Starting at the first odometry pose, the mean motion lands on the second."""
    prev = jnp.asarray([1.0, -1.0, 0.4])
    cur = jnp.asarray([1.5, -0.2, 1.3])
    got = motion.odometry_mean(prev, motion.odometry_control(prev, cur))
    np.testing.assert_allclose(got, cur, atol=1e-6)
    # In another frame the same relative motion is applied.
    start = jnp.asarray([0.0, 0.0, 0.0])
    got2 = motion.odometry_mean(start, motion.odometry_control(prev, cur))
    d = np.linalg.norm(np.asarray(cur[:2] - prev[:2]))
    np.testing.assert_allclose(np.linalg.norm(np.asarray(got2[:2])), d, rtol=1e-6)
    np.testing.assert_allclose(got2[2], 0.9, atol=1e-6)


def test_odometry_pure_rotation_has_finite_gradients():
    prev = jnp.asarray([1.0, 1.0, 0.0])
    cur = jnp.asarray([1.0, 1.0, 0.5])
    ctrl = motion.odometry_control(prev, cur)
    np.testing.assert_allclose(motion.odometry_mean(prev, ctrl), cur, atol=1e-6)
    jac = jax.jacfwd(motion.odometry_mean, argnums=(0, 1))(prev, ctrl)
    assert all(np.all(np.isfinite(j)) for j in jac)


def test_omni_is_eq_3_6_in_world_frame_and_rotated_in_body_frame():
    pose = jnp.asarray([1.0, 1.0, math.pi / 2])
    u = jnp.asarray([0.2, 0.1, 0.3, 2.0])
    np.testing.assert_allclose(motion.omni_mean(pose, u), [1.4, 1.2, math.pi / 2 + 0.6], atol=1e-6)
    # Body frame: heading +90°, so forward (x_body) is world +y.
    np.testing.assert_allclose(motion.omni_body_mean(pose, u), [1.0 - 0.2, 1.0 + 0.4, math.pi / 2 + 0.6], atol=1e-6)


@pytest.mark.parametrize("name", sorted(motion.MODELS))
def test_sample_is_centred_on_mean_with_small_noise_and_vectorised(name):
    model = motion.MODELS[name]
    controls = {
        "velocity": jnp.asarray([0.5, 0.2, 0.1]),
        "odometry": jnp.asarray([0.0, 0.0, 0.0, 0.05, 0.01, 0.02]),
        "omni": jnp.asarray([0.3, -0.1, 0.2, 0.1]),
        "omni_body": jnp.asarray([0.3, -0.1, 0.2, 0.1]),
    }
    noise = {
        "velocity": motion.VelocityNoise(jnp.full((6,), 0.01), jnp.asarray([0.01, 0.01, 0.005])),
        "odometry": motion.OdometryNoise(jnp.full((4,), 0.01), jnp.asarray([0.01, 0.01, 0.005])),
        "omni": motion.OmniNoise(jnp.asarray([0.1, 0.1, 0.05])),
        "omni_body": motion.OmniNoise(jnp.asarray([0.1, 0.1, 0.05])),
    }[name]
    pose = jnp.asarray([1.0, 2.0, 0.5])
    poses = jnp.tile(pose, (20000, 1))
    out = jax.jit(model.sample)(jax.random.PRNGKey(0), poses, controls[name], noise)
    assert out.shape == poses.shape
    mean = model.mean(pose, controls[name], noise)
    sd = np.std(np.asarray(out), axis=0)
    assert np.all(sd > 0)
    # The sample mean is within 5 standard errors of the noise-free motion
    # (all noises here are small, so the nonlinear bias is far below that).
    np.testing.assert_array_less(np.abs(np.mean(out, axis=0) - mean), 5 * sd / math.sqrt(20000) + 1e-4)


def test_omni_sample_noise_scales_with_dt():
    """[W] eq. 3.6: the noise enters as ε·Δt, so its sd is σ·Δt."""
    sd = jnp.asarray([0.2, 0.1, 0.05])
    poses = jnp.zeros((50000, 3))
    out = motion.omni_sample(jax.random.PRNGKey(1), poses, jnp.asarray([0.0, 0.0, 0.0, 0.5]), motion.OmniNoise(sd))
    np.testing.assert_allclose(np.std(np.asarray(out), axis=0), np.asarray(sd) * 0.5, rtol=0.03)


def test_means_are_differentiable():
    pose = jnp.asarray([0.5, -0.3, 0.2])
    check_grads(
        lambda p: motion.velocity_mean(p, jnp.asarray([0.5, 0.3, 0.2])),
        (pose,),
        order=1,
        modes=["fwd", "rev"],
        atol=1e-2,
        rtol=1e-2,
    )
    check_grads(
        lambda p: motion.omni_body_mean(p, jnp.asarray([0.5, 0.3, 0.2, 0.1])),
        (pose,),
        order=1,
        modes=["fwd", "rev"],
        atol=1e-2,
        rtol=1e-2,
    )


def test_unknown_model_name():
    with pytest.raises(ValueError, match="motion model 'teleport' is unknown"):
        motion.get_motion_model("teleport")


@pytest.mark.parametrize(
    "name, control, noise",
    [
        (
            "velocity",
            [0.8, 0.4, 0.5],
            motion.VelocityNoise(
                jnp.asarray([0.01, 0.005, 0.005, 0.01, 0.002, 0.002]), jnp.asarray([0.01, 0.02, 0.01])
            ),
        ),
        (
            "odometry",
            [0.0, 0.0, 0.1, 0.3, 0.2, 0.5],
            motion.OdometryNoise(jnp.asarray([0.01, 0.01, 0.02, 0.01]), jnp.asarray([0.01, 0.01, 0.01])),
        ),
        ("omni", [0.2, -0.1, 0.3, 0.5], motion.OmniNoise(jnp.asarray([0.05, 0.02, 0.04]))),
        ("omni_body", [0.2, -0.1, 0.3, 0.5], motion.OmniNoise(jnp.asarray([0.05, 0.02, 0.04]))),
    ],
)
def test_process_cov_matches_sample_covariance(name, control, noise, getkey):
    """``process_cov`` is the linearised covariance of ``sample``: with small noise the
    sample covariance of 200k draws agrees within Monte Carlo error (a few % of each σ²)."""
    model = motion.MODELS[name]
    pose = jnp.asarray([1.0, -2.0, 0.7])
    u = jnp.asarray(control)
    draws = model.sample(getkey(), jnp.broadcast_to(pose, (200_000, 3)), u, noise)
    mean = model.mean(pose, u)
    d = draws - mean
    d = d.at[:, 2].set(motion.wrap_angle(d[:, 2]))
    empirical = np.cov(np.asarray(d, np.float64).T)
    q = np.asarray(model.process_cov(pose, u, noise))
    np.testing.assert_allclose(q, q.T, atol=1e-9)
    scale = np.sqrt(np.outer(np.diag(empirical), np.diag(empirical)))
    # correlation-scale tolerance: 200k draws give ~0.3% sampling error; 5% allows linearisation error
    np.testing.assert_array_less(np.abs(q - empirical) / scale, 0.05)


def test_increment_moves_xyz_yaw_poses_in_the_world_or_the_body_frame():
    """[A] Alg. 8 line 13: ``X + dX`` (world), or ``(dx, dy)`` rotated by each pose's yaw (body); φ wrapped."""
    poses = jnp.asarray([[1.0, 2.0, 0.5, 0.0], [0.0, 0.0, 1.0, math.pi / 2], [0.0, 0.0, 0.0, 3.0]])
    dx = jnp.asarray([0.1, 0.0, 0.02, 0.5])
    world = np.asarray(motion.increment_mean(poses, dx, "world"))
    np.testing.assert_allclose(world[:, :3], np.asarray(poses[:, :3]) + [0.1, 0.0, 0.02], atol=1e-7)
    np.testing.assert_allclose(world[2, 3], 3.5 - 2 * math.pi, atol=1e-6)  # wrapped to [−π, π)
    body = np.asarray(motion.increment_mean(poses, dx, "body"))
    np.testing.assert_allclose(body[1, :2], [0.0, 0.1], atol=1e-7)  # facing +y: forward is +y
    np.testing.assert_allclose(body[0], world[0], atol=1e-7)  # facing +x: the frames agree
    with pytest.raises(ValueError, match="frame"):
        motion.increment_mean(poses, dx, "robot")


def test_increment_sample_is_the_mean_plus_gaussian_noise_of_sd(getkey):
    poses = jnp.zeros((100_000, 4))
    dx = jnp.asarray([0.1, -0.2, 0.0, 0.1])
    sd = jnp.asarray([0.01, 0.02, 0.005, 0.03])
    np.testing.assert_array_equal(
        motion.increment_sample(getkey(), poses, dx, jnp.zeros(4)), motion.increment_mean(poses, dx)
    )
    draws = np.asarray(motion.increment_sample(getkey(), poses, dx, sd, "body"), np.float64)
    np.testing.assert_allclose(draws.mean(axis=0), np.asarray(dx), atol=4 * float(sd.max()) / math.sqrt(100_000))
    np.testing.assert_allclose(draws.std(axis=0), np.asarray(sd), rtol=0.02)  # 100k draws: ~0.2 % error on σ


def test_velocity_sample_with_zero_alphas_is_the_exact_arc_plus_pose_noise():
    """Pose noise only (every α zero): the controls are exact, so the draw is the noise-free arc plus the
    pose noise, the same as with control noise of zero size, for a turning, a straight and a spinning
    robot; and the gradient in the α is finite there (the branch with control noise is not taken)."""
    poses = jax.random.normal(jax.random.key(0), (500, 3)) * 3.0
    pose_sd = jnp.asarray([0.02, 0.02, 0.01])
    for control in ([0.5, 0.1, 0.1], [0.5, 0.0, 0.1], [0.0, 1.3, 0.25]):
        control = jnp.asarray(control)
        noise = motion.VelocityNoise(jnp.zeros(6), pose_sd)
        drawn = motion.velocity_sample(jax.random.key(3), poses, control, noise)
        _, k_pose = jax.random.split(jax.random.key(3))
        expected = motion._add_pose_noise(k_pose, motion.velocity_mean(poses, control), pose_sd)
        np.testing.assert_allclose(drawn, expected, rtol=0, atol=2e-6)
        tiny = motion.velocity_sample(
            jax.random.key(3), poses, control, motion.VelocityNoise(jnp.full(6, 1e-30), pose_sd)
        )
        np.testing.assert_allclose(tiny, expected, rtol=0, atol=2e-6)

    def spread(alphas):
        moved = motion.velocity_sample(
            jax.random.key(4), poses, jnp.asarray([0.5, 0.1, 0.1]), motion.VelocityNoise(alphas, pose_sd)
        )
        return jnp.sum(moved[:, 0])

    assert np.all(np.isfinite(jax.grad(spread)(jnp.zeros(6))))


def test_differential_drive_moves_along_the_arc_of_its_wheel_speeds(getkey):
    """``v = (v_r + v_l)/2``, ``ω = (v_r − v_l)/b`` on the velocity model's arc; ``sample`` is centred on
    it and its covariance is ``process_cov`` (200k draws, as the built-in models); one wheel base
    gives one cached model; a bad wheel base or noise is refused by name."""
    model = motion.differential_drive(0.157)
    assert motion.differential_drive(0.157) is model and model.control_dim == 3 and model.dt_index == 2
    pose = jnp.asarray([1.0, -2.0, 0.7])
    u = jnp.asarray([0.30, 0.20, 0.5])
    expected = motion.velocity_mean(pose, jnp.asarray([0.25, 0.10 / 0.157, 0.5]))
    np.testing.assert_allclose(model.mean(pose, u), expected, atol=1e-6)
    noise = motion.WheelNoise(jnp.asarray([0.02, 0.03]), jnp.asarray([0.005, 0.005, 0.01]))
    draws = model.sample(getkey(), jnp.broadcast_to(pose, (200_000, 3)), u, noise)
    d = np.asarray(draws - expected, np.float64)
    empirical = np.cov(d.T)
    q = np.asarray(model.process_cov(pose, u, noise))
    scale = np.sqrt(np.outer(np.diag(empirical), np.diag(empirical)))
    np.testing.assert_array_less(np.abs(q - empirical) / scale, 0.05)
    # centred to 1 mm: the heading noise (0.11 rad over the step) bends the mean chord by about 0.2 mm
    np.testing.assert_array_less(np.abs(d.mean(axis=0)), 1e-3)
    still = motion.WheelNoise(jnp.zeros(2), jnp.zeros(3))
    np.testing.assert_allclose(model.sample(getkey(), pose[None], u, still)[0], expected, atol=1e-6)
    for bad in (0.0, -1.0, float("nan"), "wide"):
        with pytest.raises(ValueError, match="wheel_base"):
            motion.differential_drive(bad)
    with pytest.raises(ValueError, match="motion noise sd"):
        motion.validate_noise(model, motion.WheelNoise(jnp.zeros(3), jnp.zeros(3)))
    with pytest.raises(ValueError, match="must be a WheelNoise"):
        motion.validate_noise(model, motion.OmniNoise(jnp.zeros(3)))
