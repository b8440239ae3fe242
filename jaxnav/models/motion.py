"""Motion models: velocity (unicycle), odometry and omnidirectional.

**Overview**

Each model offers

* ``mean(pose, control, params) -> pose`` — the deterministic motion
  ``g(u_t, x_{t-1})``; smooth, so the EKF linearises it
  with ``jax.jacfwd`` instead of hand-written Jacobians;
* ``sample(key, poses, control, params) -> poses`` — one noisy draw per pose,
  vectorised over any leading axes of ``poses [..., 3]`` (one call moves all
  particles; the noise is drawn as one array, not per-particle keys);
* ``process_cov(pose, control, params) -> [3, 3]`` — the covariance of
  ``sample`` linearised at ``pose``: ``V M Vᵀ + diag(pose_sd²)`` with ``M`` the
  covariance of the noisy control and ``V = ∂g/∂u`` from ``jax.jacfwd``
  (Thrun et al. Tab. 7.1 line 5), for the EKF, UKF and grid filters.

Poses are ``(x, y, θ)`` in metres and radians, θ wrapped to ``[-π, π)``.
Controls carry their own time step, so logs with irregular Δt need no extra
argument:

==================  ========================================  =====================
model               control ``u``                             reference
==================  ========================================  =====================
``velocity``        ``(v [m/s], ω [rad/s], Δt [s])``          Thrun et al. Tab. 5.3
``odometry``        ``(x̄, ȳ, θ̄, x̄', ȳ', θ̄')`` odometry poses  Thrun et al. Tab. 5.6
``omni``            ``(v_x, v_y, ω, Δt)``, world frame        [W] eq. 3.6
``omni_body``       ``(v_x, v_y, ω, Δt)``, robot frame        [W] eq. 3.6, rotated
differential drive  ``(v_right, v_left, Δt)`` wheel speeds    :func:`differential_drive`
==================  ========================================  =====================

The differential-drive model is built for a wheel base (``differential_drive(0.0785)``); it moves
along the velocity model's arc with ``v = (v_r + v_l)/2`` and ``ω = (v_r − v_l)/b``, the noise in
the wheel speeds.

Robots localised in 3-D, with poses ``(x, y, z, φ)``, move by an odometry increment
``dX = (dx, dy, dz, dφ)`` plus Gaussian noise ([A] App. F Alg. 8): :func:`increment_sample`
and :func:`increment_mean`.

Noise parameters are NamedTuple pytrees (differentiable, vmappable). The
``alphas`` follow Thrun et al.: each is a coefficient of a *variance*
(``Var[v̂ − v] = α₁v² + α₂ω²``). ``pose_sd`` adds independent Gaussian noise
to ``(x, y, θ)`` after the move (m, m, rad per step), which is how the
benchmark workload W2 states its noise.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import fastmath, rng
from jaxnav.core.validation import (
    all_finite_within,
    all_nonnegative,
    any_negative,
    as_array,
    check_magnitude,
    check_nonnegative,
    check_shape,
    first_index,
    is_concrete,
)
from jaxnav.core.weights import wrap_angle

__all__ = [
    "VelocityNoise",
    "OdometryNoise",
    "OmniNoise",
    "WheelNoise",
    "MotionModel",
    "VELOCITY",
    "ODOMETRY",
    "OMNI",
    "OMNI_BODY",
    "check_motion_model",
    "model_name",
    "velocity_mean",
    "velocity_sample",
    "odometry_mean",
    "odometry_sample",
    "odometry_control",
    "omni_mean",
    "omni_sample",
    "omni_body_mean",
    "omni_body_sample",
    "INCREMENT_FRAMES",
    "increment_mean",
    "increment_sample",
    "velocity_process_cov",
    "odometry_process_cov",
    "omni_process_cov",
    "omni_body_process_cov",
    "MODELS",
    "differential_drive",
    "get_motion_model",
    "validate_noise",
    "validate_controls",
    "noise_in_domain",
    "controls_in_domain",
]


class VelocityNoise(NamedTuple):
    """Noise of the velocity model.

    Attributes:
        alphas: ``[6]`` Thrun's α₁…α₆ (variance coefficients, dimensionless
            as written in Tab. 5.3: ``Var v̂ = α₁v² + α₂ω²``, ``Var ω̂ = α₃v² + α₄ω²``,
            ``Var γ̂ = α₅v² + α₆ω²``).
        pose_sd: ``[3]`` additive pose noise per step (m, m, rad).
    """

    alphas: jax.Array
    pose_sd: jax.Array


class OdometryNoise(NamedTuple):
    """Noise of the odometry model.

    Attributes:
        alphas: ``[4]`` Thrun's α₁…α₄ (Tab. 5.6): rotation noise from rotation
            (α₁) and translation (α₂); translation noise from translation (α₃)
            and rotation (α₄). Variance coefficients.
        pose_sd: ``[3]`` additive pose noise per step (m, m, rad).
    """

    alphas: jax.Array
    pose_sd: jax.Array


class OmniNoise(NamedTuple):
    """Noise of the omnidirectional model, [W] eq. 3.6: ``ε ~ N(0, σ)``.

    Attributes:
        sd: ``[3]`` standard deviation σ of the velocity noise ε
            (m/s, m/s, rad/s); the pose moves by ``ε·Δt``.
    """

    sd: jax.Array


class WheelNoise(NamedTuple):
    """Noise of the differential-drive model.

    Attributes:
        sd: ``[2]`` standard deviations of the right and left wheel speeds (m/s).
        pose_sd: ``[3]`` additive pose noise per step (m, m, rad).
    """

    sd: jax.Array
    pose_sd: jax.Array


# ---------------------------------------------------------------------------
# velocity (unicycle) model


def _arc(pose: jax.Array, v: jax.Array, w: jax.Array, gamma: jax.Array, dt: jax.Array) -> jax.Array:
    """Exact circular-arc motion, Thrun et al. eq. 5.9, in a form smooth at ω = 0.

    ``−sin θ + sin(θ + a) = 2 cos(θ + a/2) sin(a/2)`` with ``a = ωΔt`` gives
    ``Δx = vΔt·cos(θ + a/2)·sinc(a/2)``, which has no division by ω and so no
    special case (and finite gradients) when the robot drives straight.
    """
    x, y, th = pose[..., 0], pose[..., 1], pose[..., 2]
    a = w * dt
    chord = v * dt * _sinc_half(a)
    s, c = fastmath.sincos(th + 0.5 * a)
    return jnp.stack([x + chord * c, y + chord * s, wrap_angle(th + a + gamma * dt)], axis=-1)


def _sinc_half(a: jax.Array) -> jax.Array:
    """``sin(a/2) / (a/2)``, smooth through ``a = 0`` (Taylor ``1 − a²/24`` there)."""
    h = 0.5 * a
    small = jnp.abs(h) < 1e-3
    safe = jnp.where(small, 1.0, h)
    return jnp.where(small, 1.0 - h * h / 6.0, fastmath.sin(safe) / safe)


def _noise_sd(variance: jax.Array) -> jax.Array:
    """``√variance`` of a control's noise, with derivative 0 where the variance is 0 (a robot standing
    still, or α's that are zero) instead of ``√``'s infinite one, which would make every gradient
    with respect to the α's NaN. The values are ``jnp.sqrt``'s, bit for bit."""
    positive = variance > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, variance, 1.0)), 0.0)


def velocity_mean(pose: jax.Array, control: jax.Array, params: VelocityNoise | None = None) -> jax.Array:
    """Noise-free velocity motion ``g(u, x)`` (Thrun et al. eq. 5.9); ``u = (v, ω, Δt)``."""
    del params
    v, w, dt = control[..., 0], control[..., 1], control[..., 2]
    return _arc(pose, v, w, jnp.zeros_like(w), dt)


def velocity_sample(key: jax.Array, poses: jax.Array, control: jax.Array, params: VelocityNoise) -> jax.Array:
    """``sample_motion_model_velocity`` (Thrun et al. Tab. 5.3) for all ``poses [..., 3]``."""
    v, w, dt = control[..., 0], control[..., 1], control[..., 2]
    a = params.alphas
    k_ctrl, k_pose = jax.random.split(key)

    def noisy_controls() -> jax.Array:
        eps = rng.normal(k_ctrl, poses.shape[:-1] + (3,), poses.dtype)
        v2, w2 = v * v, w * w
        v_hat = v + eps[..., 0] * _noise_sd(a[0] * v2 + a[1] * w2)
        w_hat = w + eps[..., 1] * _noise_sd(a[2] * v2 + a[3] * w2)
        g_hat = eps[..., 2] * _noise_sd(a[4] * v2 + a[5] * w2)
        return _arc(poses, v_hat, w_hat, g_hat, dt)

    # With every α zero (pose noise only) the controls are exact: the arc's factor ``sinc(ωΔt/2)``
    # is then one number for all particles instead of a sine and a division per particle, and no
    # control noise is drawn. ``lax.cond`` decides at run time (under vmap over runs that share
    # ``params`` it stays a branch).
    moved = jax.lax.cond(jnp.any(a != 0), noisy_controls, lambda: velocity_mean(poses, control))
    return _add_pose_noise(k_pose, moved, params.pose_sd)


def _standard_normal_unless_zero(key: jax.Array, shape: tuple[int, ...], dtype, scales: jax.Array) -> jax.Array:
    """``N(0, 1)`` draws of ``shape``, or zeros when every entry of ``scales`` is 0.

    Drawing normals is the largest cost of a motion update on CPU (threefry),
    and a model whose noise is switched off (e.g. W2's pose-noise-only
    velocity model) should not pay for it. ``lax.cond`` skips the draw at run
    time; under ``vmap`` it becomes a select and both branches run, which is
    still correct.
    """
    return jax.lax.cond(
        jnp.any(scales != 0),
        lambda: rng.normal(key, shape, dtype),
        lambda: jnp.zeros(shape, dtype),
    )


def _add_pose_noise(key: jax.Array, poses: jax.Array, pose_sd: jax.Array) -> jax.Array:
    noisy = poses + _standard_normal_unless_zero(key, poses.shape, poses.dtype, pose_sd) * pose_sd
    return _wrap_heading(noisy)


# ---------------------------------------------------------------------------
# odometry model

_EPS_TRANS = 1e-9  # m; below this the heading of the translation is undefined


def _odometry_deltas(control: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``(δ_rot1, δ_trans, δ_rot2)`` of Thrun et al. Tab. 5.6 from two odometry poses.

    For a pure rotation (δ_trans ≈ 0) the first rotation is set to 0 and the
    whole turn goes to δ_rot2, with gradients kept finite.
    """
    dx = control[..., 3] - control[..., 0]
    dy = control[..., 4] - control[..., 1]
    d2 = dx * dx + dy * dy
    moving = d2 > _EPS_TRANS**2
    safe_dx = jnp.where(moving, dx, 1.0)
    safe_dy = jnp.where(moving, dy, 0.0)
    trans = jnp.where(moving, jnp.sqrt(jnp.where(moving, d2, 1.0)), 0.0)
    rot1 = jnp.where(moving, wrap_angle(jnp.arctan2(safe_dy, safe_dx) - control[..., 2]), 0.0)
    rot2 = wrap_angle(control[..., 5] - control[..., 2] - rot1)
    return rot1, trans, rot2


def _apply_odometry(pose: jax.Array, rot1: jax.Array, trans: jax.Array, rot2: jax.Array) -> jax.Array:
    x, y, th = pose[..., 0], pose[..., 1], pose[..., 2]
    h = th + rot1
    s, c = fastmath.sincos(h)
    return jnp.stack([x + trans * c, y + trans * s, wrap_angle(h + rot2)], axis=-1)


def odometry_mean(pose: jax.Array, control: jax.Array, params: OdometryNoise | None = None) -> jax.Array:
    """Noise-free odometry motion: apply the relative motion between two odometry poses."""
    del params
    return _apply_odometry(pose, *_odometry_deltas(control))


def odometry_sample(key: jax.Array, poses: jax.Array, control: jax.Array, params: OdometryNoise) -> jax.Array:
    """``sample_motion_model_odometry`` (Thrun et al. Tab. 5.6) for all ``poses [..., 3]``."""
    rot1, trans, rot2 = _odometry_deltas(control)
    a = params.alphas
    k_ctrl, k_pose = jax.random.split(key)
    eps = _standard_normal_unless_zero(k_ctrl, poses.shape[:-1] + (3,), poses.dtype, a)
    r1, t2, r2 = rot1 * rot1, trans * trans, rot2 * rot2
    rot1_hat = rot1 - eps[..., 0] * _noise_sd(a[0] * r1 + a[1] * t2)
    trans_hat = trans - eps[..., 1] * _noise_sd(a[2] * t2 + a[3] * (r1 + r2))
    rot2_hat = rot2 - eps[..., 2] * _noise_sd(a[0] * r2 + a[1] * t2)
    moved = _apply_odometry(poses, rot1_hat, trans_hat, rot2_hat)
    return _add_pose_noise(k_pose, moved, params.pose_sd)


def odometry_control(previous_odometry_pose: jax.Array, odometry_pose: jax.Array) -> jax.Array:
    """Pack two odometry readings into the ``odometry`` model's control ``[6]``."""
    return jnp.concatenate([jnp.asarray(previous_odometry_pose), jnp.asarray(odometry_pose)], axis=-1)


# ---------------------------------------------------------------------------
# omnidirectional model, [W] eq. 3.6


def _wrap_heading(pose: jax.Array) -> jax.Array:
    """``pose`` with θ wrapped to ``[-π, π)``, built by concatenation: under ``vmap`` XLA:CPU turns
    ``.at[..., 2].set`` into a scatter that copies the whole particle array, and even unbatched it
    takes a large share of the W2 motion step."""
    return jnp.concatenate([pose[..., :2], wrap_angle(pose[..., 2:3])], axis=-1)


def omni_mean(pose: jax.Array, control: jax.Array, params: OmniNoise | None = None) -> jax.Array:
    """[W] eq. 3.6 without noise: ``x_t = x_{t−1} + V·Δt`` with ``V = (v_x, v_y, ω)`` in the world frame."""
    del params
    dt = control[..., 3:4]
    new = pose + control[..., :3] * dt
    return _wrap_heading(new)


def omni_sample(key: jax.Array, poses: jax.Array, control: jax.Array, params: OmniNoise) -> jax.Array:
    """[W] eq. 3.6: ``x_t = x_{t−1} + V·Δt + ε·Δt``, ``ε ~ N(0, σ)``, V in the world frame."""
    dt = control[..., 3:4]
    eps = rng.normal(key, poses.shape, poses.dtype) * params.sd
    new = poses + (control[..., :3] + eps) * dt
    return _wrap_heading(new)


def _body_to_world(poses: jax.Array, v_body: jax.Array) -> jax.Array:
    s, c = fastmath.sincos(poses[..., 2])
    vx, vy = v_body[..., 0], v_body[..., 1]
    return jnp.stack([c * vx - s * vy, s * vx + c * vy, v_body[..., 2] * jnp.ones_like(c)], axis=-1)


def omni_body_mean(pose: jax.Array, control: jax.Array, params: OmniNoise | None = None) -> jax.Array:
    """[W] eq. 3.6 with ``V`` measured in the robot frame (rotated by θ_{t−1}), no noise."""
    del params
    dt = control[..., 3:4]
    new = pose + _body_to_world(pose, control[..., :3]) * dt
    return _wrap_heading(new)


def omni_body_sample(key: jax.Array, poses: jax.Array, control: jax.Array, params: OmniNoise) -> jax.Array:
    """[W] eq. 3.6 with robot-frame ``V``: the noisy body velocity ``V + ε`` is rotated by θ_{t−1}."""
    dt = control[..., 3:4]
    eps = rng.normal(key, poses.shape, poses.dtype) * params.sd
    new = poses + _body_to_world(poses, control[..., :3] + eps) * dt
    return _wrap_heading(new)


# ---------------------------------------------------------------------------
# pose increments in 3-D: (x, y, z, φ) moved by an odometry increment ([A] App. F Alg. 8)


INCREMENT_FRAMES = ("world", "body")
"""Frames of :func:`increment_sample`'s ``(dx, dy)``, as given ([A]'s ``X + dX``) or in the robot frame."""


def increment_mean(poses: jax.Array, increment: jax.Array, frame: str = "world") -> jax.Array:
    """``X_t = X_{t−1} + dX_t`` for poses ``[N, 4] = (x, y, z, φ)`` (m, m, m, rad) and ``dX [4]``.

    With ``frame="body"`` the planar part ``(dx, dy)`` is measured in the robot frame and rotated by
    each pose's yaw φ_{t−1}; ``dz`` and ``dφ`` are added as they are. φ is wrapped to ``[−π, π)``.
    """
    return _increment(poses, increment, jnp.zeros_like(poses), frame)


def increment_sample(
    key: jax.Array, poses: jax.Array, increment: jax.Array, sd: jax.Array, frame: str = "world"
) -> jax.Array:
    """[A] Alg. 8 line 13: ``X_t ~ N(X_{t−1} + dX_t, diag(sd²))`` for poses ``[N, 4] = (x, y, z, φ)``.

    ``sd [4]`` (m, m, m, rad per step) is the noise of the move; ``frame`` as :func:`increment_mean`
    (the noise is added in the world frame either way).
    """
    noise = rng.normal(key, poses.shape, poses.dtype) * sd
    return _increment(poses, increment, noise, frame)


def _increment(poses: jax.Array, increment: jax.Array, noise: jax.Array, frame: str) -> jax.Array:
    if frame not in INCREMENT_FRAMES:
        raise ValueError(f"frame must be one of {INCREMENT_FRAMES}, got {frame!r}")
    if frame == "body":
        c, s = jnp.cos(poses[:, 3]), jnp.sin(poses[:, 3])
        dxy = jnp.stack([c * increment[0] - s * increment[1], s * increment[0] + c * increment[1]], axis=-1)
    else:
        dxy = jnp.broadcast_to(increment[:2], (poses.shape[0], 2))
    return jnp.concatenate(
        [
            poses[:, :2] + dxy + noise[:, :2],
            poses[:, 2:3] + increment[2] + noise[:, 2:3],
            wrap_angle(poses[:, 3:4] + increment[3] + noise[:, 3:4]),
        ],
        axis=-1,
    )


# ---------------------------------------------------------------------------
# linearised process noise (for Kalman and grid filters)


def _linearised_cov(g: Callable[[jax.Array], jax.Array], u_noisy: jax.Array, m_diag: jax.Array) -> jax.Array:
    """``V diag(m) Vᵀ`` with ``V = ∂g/∂u`` at ``u_noisy`` (jax.jacfwd; wrapping θ has derivative 1)."""
    v = jax.jacfwd(g)(u_noisy)
    return (v * m_diag) @ v.T


def velocity_process_cov(pose: jax.Array, control: jax.Array, params: VelocityNoise) -> jax.Array:
    """Linearised covariance of :func:`velocity_sample` at ``pose [3]`` (Thrun et al. Tab. 7.1 lines 3–5)."""
    v, w, dt = control[0], control[1], control[2]
    a = params.alphas
    v2, w2 = v * v, w * w
    m = jnp.stack([a[0] * v2 + a[1] * w2, a[2] * v2 + a[3] * w2, a[4] * v2 + a[5] * w2])
    g = lambda u: _arc(pose, u[0], u[1], u[2], dt)  # noqa: E731
    return _linearised_cov(g, jnp.stack([v, w, jnp.zeros_like(w)]), m) + jnp.diag(params.pose_sd**2)


def odometry_process_cov(pose: jax.Array, control: jax.Array, params: OdometryNoise) -> jax.Array:
    """Linearised covariance of :func:`odometry_sample` at ``pose [3]`` (Thrun et al. Tab. 5.6 noise, Tab. 7.1 form)."""
    rot1, trans, rot2 = _odometry_deltas(control)
    a = params.alphas
    r1, t2, r2 = rot1 * rot1, trans * trans, rot2 * rot2
    m = jnp.stack([a[0] * r1 + a[1] * t2, a[2] * t2 + a[3] * (r1 + r2), a[0] * r2 + a[1] * t2])
    g = lambda u: _apply_odometry(pose, u[0], u[1], u[2])  # noqa: E731
    return _linearised_cov(g, jnp.stack([rot1, trans, rot2]), m) + jnp.diag(params.pose_sd**2)


def omni_process_cov(pose: jax.Array, control: jax.Array, params: OmniNoise) -> jax.Array:
    """Covariance of :func:`omni_sample`: ``diag(σ² Δt²)`` ([W] eq. 3.6; exact, the model is linear)."""
    del pose
    return jnp.diag((params.sd * control[3]) ** 2)


def omni_body_process_cov(pose: jax.Array, control: jax.Array, params: OmniNoise) -> jax.Array:
    """Covariance of :func:`omni_body_sample`: the body-frame noise rotated by θ_{t−1} (exact)."""
    dt = control[3]
    g = lambda u: _body_to_world(pose, u) * dt  # noqa: E731
    return _linearised_cov(g, control[:3], params.sd**2)


# ---------------------------------------------------------------------------
# registry


class MotionModel(NamedTuple):
    """A motion model's functions and metadata (see the module docstring)."""

    name: str
    control_dim: int
    mean: Callable[..., jax.Array]
    sample: Callable[..., jax.Array]
    noise_type: type
    validate: Callable[[object], None]
    process_cov: Callable[..., jax.Array]
    dt_index: int | None = None  # where the control holds its time step Δt (s), if it has one


def _validate_velocity(params: VelocityNoise) -> None:
    check_shape("motion noise alphas", params.alphas, (6,))
    check_shape("motion noise pose_sd", params.pose_sd, (3,))
    _check_noise_values(alphas=params.alphas, pose_sd=params.pose_sd)


def _validate_odometry(params: OdometryNoise) -> None:
    check_shape("motion noise alphas", params.alphas, (4,))
    check_shape("motion noise pose_sd", params.pose_sd, (3,))
    _check_noise_values(alphas=params.alphas, pose_sd=params.pose_sd)


def _validate_omni(params: OmniNoise) -> None:
    check_shape("motion noise sd", params.sd, (3,))
    _check_noise_values(sd=params.sd)


def _check_noise_values(**fields: object) -> None:
    for field, value in fields.items():
        check_nonnegative(f"motion noise {field}", value)
        check_magnitude(f"motion noise {field}", value)


VELOCITY = MotionModel(
    "velocity", 3, velocity_mean, velocity_sample, VelocityNoise, _validate_velocity, velocity_process_cov, 2
)
"""The velocity (unicycle) model of Thrun et al. Tab. 5.3, whose control is ``(v [m/s], ω [rad/s], Δt [s])``."""
ODOMETRY = MotionModel(
    "odometry", 6, odometry_mean, odometry_sample, OdometryNoise, _validate_odometry, odometry_process_cov
)
"""The odometry model of Thrun et al. Tab. 5.6, whose control is two odometry poses ``(x̄, ȳ, θ̄, x̄', ȳ', θ̄')``."""
OMNI = MotionModel("omni", 4, omni_mean, omni_sample, OmniNoise, _validate_omni, omni_process_cov, 3)
"""The omnidirectional model of [W] eq. 3.6, whose control is ``(v_x, v_y, ω, Δt)`` in the world frame."""
OMNI_BODY = MotionModel(
    "omni_body", 4, omni_body_mean, omni_body_sample, OmniNoise, _validate_omni, omni_body_process_cov, 3
)
"""The omnidirectional model whose control ``(v_x, v_y, ω, Δt)`` has its velocity in the robot frame."""

# ---------------------------------------------------------------------------
# differential drive: wheel speeds


def _wheel_arc(pose: jax.Array, right: jax.Array, left: jax.Array, dt: jax.Array, wheel_base: float) -> jax.Array:
    return _arc(pose, 0.5 * (right + left), (right - left) / wheel_base, jnp.zeros_like(right), dt)


def _validate_wheels(params: WheelNoise) -> None:
    check_shape("motion noise sd", params.sd, (2,))
    check_shape("motion noise pose_sd", params.pose_sd, (3,))
    _check_noise_values(sd=params.sd, pose_sd=params.pose_sd)


@functools.cache
def differential_drive(wheel_base: float) -> MotionModel:
    """The differential-drive model of a robot whose wheels are ``wheel_base`` metres apart: control
    ``(v_right [m/s], v_left [m/s], Δt [s])``, noise :class:`WheelNoise`. The pose moves along the arc
    of the velocity model (Thrun et al. eq. 5.9) with ``v = (v_r + v_l)/2`` and ``ω = (v_r − v_l)/b``;
    ``sample`` draws each wheel's speed ``v + N(0, σ²)``, then adds the pose noise. Cached: one wheel
    base gives one (hashable) model, so a filter's configuration with it compiles once."""
    if not (isinstance(wheel_base, (int, float)) and np.isfinite(wheel_base) and wheel_base > 0):
        raise ValueError(f"wheel_base must be a positive number of metres, got {wheel_base!r}")
    b = float(wheel_base)

    def mean(pose: jax.Array, control: jax.Array, params: WheelNoise | None = None) -> jax.Array:
        del params
        return _wheel_arc(pose, control[..., 0], control[..., 1], control[..., 2], b)

    def sample(key: jax.Array, poses: jax.Array, control: jax.Array, params: WheelNoise) -> jax.Array:
        k_wheels, k_pose = jax.random.split(key)
        eps = _standard_normal_unless_zero(k_wheels, poses.shape[:-1] + (2,), poses.dtype, params.sd) * params.sd
        moved = _wheel_arc(poses, control[..., 0] + eps[..., 0], control[..., 1] + eps[..., 1], control[..., 2], b)
        return _add_pose_noise(k_pose, moved, params.pose_sd)

    def process_cov(pose: jax.Array, control: jax.Array, params: WheelNoise) -> jax.Array:
        g = lambda u: _wheel_arc(pose, u[0], u[1], control[2], b)  # noqa: E731
        return _linearised_cov(g, control[:2], params.sd**2) + jnp.diag(params.pose_sd**2)

    return MotionModel(f"differential_drive({b:g} m)", 3, mean, sample, WheelNoise, _validate_wheels, process_cov, 2)


MODELS: dict[str, MotionModel] = {m.name: m for m in (VELOCITY, ODOMETRY, OMNI, OMNI_BODY)}
"""The built-in motion models by name (``"velocity"``, ``"odometry"``, ``"omni"``, ``"omni_body"``; table in
the module docstring). A filter's ``motion_model`` takes a name or a :class:`MotionModel`, built-in or
a user's own."""


def get_motion_model(model: str | MotionModel) -> MotionModel:
    """The motion model ``model``: a :class:`MotionModel` as it is, or the one of :data:`MODELS` by name."""
    if isinstance(model, MotionModel):
        return model
    try:
        return MODELS[model]
    except (KeyError, TypeError):
        raise ValueError(
            f"motion model {model!r} is unknown; choose one of {sorted(MODELS)} or pass a "
            "jaxnav.models.motion.MotionModel"
        ) from None


def check_motion_model(name: str, model: object) -> None:
    """Configuration check: ``model`` is a name in :data:`MODELS` or a :class:`MotionModel` whose
    functions are callable; raises ``ValueError`` naming the field ``name``."""
    if isinstance(model, MotionModel):
        for field in ("mean", "sample", "validate", "process_cov"):
            if not callable(getattr(model, field)):
                raise ValueError(f"{name}.{field} of motion model {model.name!r} must be callable")
        return
    if not isinstance(model, str) or model not in MODELS:
        raise ValueError(f"{name} must be one of {sorted(MODELS)} or a jaxnav.models.motion.MotionModel, got {model!r}")


def model_name(model: str | MotionModel) -> str:
    """The name of ``model`` (a name or a :class:`MotionModel`), for messages."""
    return model.name if isinstance(model, MotionModel) else model


def validate_noise(name: str | MotionModel, params: object, argument: str = "params.motion") -> None:
    """Host-side check that ``params`` is the noise type of motion model ``name`` and is valid.

    Raises ``ValueError`` naming ``argument``, the model and the expected type.
    """
    model = get_motion_model(name)
    if not isinstance(params, model.noise_type):
        raise ValueError(
            f"{argument} must be a {model.noise_type.__name__} for motion model {model.name!r}, "
            f"got {type(params).__name__}"
        )
    model.validate(params)


def noise_in_domain(name: str | MotionModel, params: object) -> jax.Array:
    """``bool[]``, traceable: every noise level of motion model ``name``'s ``params`` (α's, σ's) is
    finite and in ``[0, MAX_MAGNITUDE]``, the value checks of :func:`validate_noise` as a ``jnp``
    expression for use inside a ``jit`` (a negative α makes ``√(α₁v² + α₂ω²)`` NaN)."""
    get_motion_model(name)
    return jnp.all(jnp.stack([all_nonnegative(leaf) for leaf in jax.tree_util.tree_leaves(params)]))


def controls_in_domain(controls: jax.Array, model: str | MotionModel) -> jax.Array:
    """``bool[]``, traceable: ``controls [..., dim]`` of motion model ``model`` are finite, at most
    :data:`~jaxnav.core.validation.MAX_MAGNITUDE` in magnitude, with ``Δt ≥ 0`` s where the control
    carries a time step: the value checks of :func:`validate_controls` as a ``jnp`` expression."""
    spec = get_motion_model(model)
    ok = all_finite_within(controls)
    if spec.dt_index is not None:
        ok = ok & jnp.all(controls[..., spec.dt_index] >= 0)
    return ok


def validate_controls(name: str, controls: object, model: str | MotionModel, time_axis: bool) -> object:
    """Host-side check of controls of motion model ``model`` (``[T, dim]`` with ``time_axis``, else
    ``[dim]``), named ``name``: the model's dimension, finite values of at most
    :data:`~jaxnav.core.validation.MAX_MAGNITUDE` (m, s, rad), and a time step ``Δt ≥ 0`` s where
    the control carries one (a negative Δt would run the motion backwards in time). Returns the
    controls, a list or tuple converted to an array. Values are skipped for tracers.
    """
    spec = get_motion_model(model)
    controls = as_array(name, controls)
    check_shape(name, controls, ((None,) if time_axis else ()) + (spec.control_dim,))
    check_magnitude(name, controls)
    if spec.dt_index is not None and is_concrete(controls):
        dt = np.asarray(controls)[..., spec.dt_index]
        if any_negative(dt):
            where = first_index(dt < 0) + (spec.dt_index,)
            raise ValueError(
                f"{name} holds a negative time step Δt (column {spec.dt_index} of a {spec.name!r} control), the "
                f"first {float(np.asarray(controls)[where]):g} s at index {where}"
            )
    return controls
