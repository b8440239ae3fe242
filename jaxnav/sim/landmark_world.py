"""Simulated range-bearing landmark worlds (data for MCL, EKF, SLAM tests and the demo).

A robot moves with a motion model from :mod:`jaxnav.models.motion` under
commanded controls; its true path is a noisy draw of that model, and at every
step it measures range and bearing to every landmark within ``max_range`` and
inside its field of view. The filter receives the *commanded* controls and the
noisy measurements, the usual simulation protocol of Thrun et al. ch. 5–6.

Everything is a pure function of a key, so a Monte Carlo study vmaps
:func:`simulate` over keys.
"""

from __future__ import annotations

import math
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import rng
from jaxnav.core.filter import check_key
from jaxnav.core.validation import check_magnitude, check_positive, check_shape, float_array, is_concrete
from jaxnav.core.weights import wrap_angle
from jaxnav.models import landmarks as lm
from jaxnav.models.motion import get_motion_model, validate_controls, validate_noise

__all__ = ["SimulatedRun", "square_room_landmarks", "simulate", "check_drive", "in_one_dtype"]


class SimulatedRun(NamedTuple):
    """A simulated sequence of ``T`` steps.

    Attributes:
        true_poses: ``[T, 3]`` pose after each step's motion (m, m, rad).
        controls: ``[T, control_dim]`` commanded controls given to the filter.
        observations: :class:`~jaxnav.models.landmarks.RangeBearingObs` with
            leading axis ``T`` and one slot per landmark (``K = M``).
    """

    true_poses: jax.Array
    controls: jax.Array
    observations: lm.RangeBearingObs


def square_room_landmarks(size: float = 10.0, num: int = 8) -> jax.Array:
    """``num`` landmarks evenly spaced along the border of a ``size`` × ``size`` m room.

    With ``num = 8`` they sit at the four corners and the four mid-walls, the
    layout of benchmark W2.
    """
    if num < 1 or size <= 0:
        raise ValueError(f"need num >= 1 and size > 0, got num={num}, size={size}")
    s = jnp.arange(num) * (4.0 * size / num)  # arc length along the perimeter
    side = jnp.floor(s / size)
    t = s - side * size
    x = jnp.select([side == 0, side == 1, side == 2], [t, jnp.full_like(t, size), size - t], 0.0)
    y = jnp.select([side == 0, side == 1, side == 2], [0.0 * t, t, jnp.full_like(t, size)], size - t)
    return jnp.stack([x, y], axis=-1)


def simulate(
    key: jax.Array,
    landmarks: jax.Array,
    initial_pose: jax.Array,
    controls: jax.Array,
    motion_noise: Any,
    sensor_noise: lm.RangeBearingNoise,
    motion_model: str = "velocity",
    max_range: float | jax.Array = math.inf,
    fov: float | jax.Array = 2.0 * math.pi,
) -> SimulatedRun:
    """Simulate a robot driving ``controls`` among ``landmarks [M, 2]``.

    Args:
        key: PRNG key.
        landmarks: ``[M, 2]`` landmark positions (m).
        initial_pose: ``[3]`` pose before the first control.
        controls: ``[T, control_dim]`` commanded controls of ``motion_model``.
        motion_noise: noise params of the motion model (the *true* process noise).
        sensor_noise: range-bearing noise (the *true* measurement noise).
        motion_model: a name in :data:`jaxnav.models.motion.MODELS`.
        max_range: detection range (m); landmarks farther away are masked out.
        fov: full field of view (rad) centred on the heading.

    The arguments are checked on the host as a filter's are (``ValueError`` naming the argument):
    landmarks ``[M, 2]`` and a start pose ``[3]`` finite and at most
    :data:`~jaxnav.core.validation.MAX_MAGNITUDE`, controls ``[T, control_dim]`` of the model with
    ``Δt ≥ 0``, the model's noise and a range-bearing noise, ``max_range > 0`` and
    ``0 < fov ≤ 2π``. Lists are accepted as arrays. Jitted; the same shapes never retrace.

    The floating-point arrays (landmarks, pose, controls, noise levels) are promoted to one dtype,
    ``jnp.result_type`` of them all: float32 controls with float64 landmarks under
    ``jax_enable_x64`` simulate in float64, and the run's arrays come out in it.
    """
    check_key(key)
    landmarks, initial_pose, controls = check_drive(
        "landmarks", landmarks, initial_pose, controls, motion_model, motion_noise, max_range
    )
    lm.validate_noise(sensor_noise, "sensor_noise")
    check_positive("fov", fov)
    if is_concrete(fov) and np.any(np.asarray(fov) > 2.0 * math.pi + 1e-6):
        raise ValueError(f"fov must be in (0, 2π] rad, got {np.asarray(fov)}")
    landmarks, initial_pose, controls, motion_noise, sensor_noise = in_one_dtype(
        landmarks, initial_pose, controls, motion_noise, sensor_noise
    )
    return _simulate(key, landmarks, initial_pose, controls, motion_noise, sensor_noise, motion_model, max_range, fov)


def check_drive(
    points_name: str,
    points: Any,
    initial_pose: Any,
    controls: Any,
    motion_model: Any,
    motion_noise: Any,
    max_range: Any,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Host-side checks shared by the simulators of a robot among points (``ValueError`` naming the
    argument): the points ``[M, 2]`` and the start ``[3]`` finite and at most
    :data:`~jaxnav.core.validation.MAX_MAGNITUDE`, controls of the motion model, its noise, and
    ``max_range > 0`` (``inf``: no limit). Returns ``(points, initial_pose, controls)`` as float arrays."""
    points = float_array(points_name, points)
    check_shape(points_name, points, (None, 2))
    check_magnitude(points_name, points)
    initial_pose = float_array("initial_pose", initial_pose)
    check_shape("initial_pose", initial_pose, (3,))
    check_magnitude("initial_pose", initial_pose)
    controls = float_array("controls", validate_controls("controls", controls, motion_model, time_axis=True))
    validate_noise(motion_model, motion_noise, "motion_noise")
    if is_concrete(max_range) and not np.all(np.asarray(max_range, float) > 0):  # inf: no limit
        raise ValueError(f"max_range must be > 0 m (inf for no limit), got {max_range!r}")
    return points, initial_pose, controls


def in_one_dtype(*trees: Any) -> tuple[Any, ...]:
    """``trees`` with every leaf converted to ``jnp.result_type`` of them all (float32 controls with
    float64 points under ``jax_enable_x64`` give float64 throughout)."""
    dtype = jnp.result_type(*jax.tree_util.tree_leaves(trees))
    return jax.tree_util.tree_map(lambda x: jnp.asarray(x, dtype), trees)


@partial(jax.jit, static_argnames=("motion_model",))
def _simulate(key, landmarks, initial_pose, controls, motion_noise, sensor_noise, motion_model, max_range, fov):
    model = get_motion_model(motion_model)
    m = landmarks.shape[0]

    def body(pose, inputs):
        k, u = inputs
        k_move, k_obs = jax.random.split(k)
        pose = model.sample(k_move, pose, u, motion_noise)
        exact = lm.predict(pose[None, :], landmarks)
        noise = rng.normal(k_obs, exact.shape, exact.dtype) * sensor_noise.sd
        z = exact + noise
        z = z.at[:, 1].set(wrap_angle(z[:, 1]))
        visible = (exact[:, 0] <= max_range) & (jnp.abs(exact[:, 1]) <= 0.5 * fov)
        obs = lm.RangeBearingObs(jnp.arange(m, dtype=jnp.int32), z, visible)
        return pose, (pose, obs)

    keys = jax.random.split(key, controls.shape[0])
    _, (poses, obs) = jax.lax.scan(body, jnp.asarray(initial_pose, controls.dtype), (keys, controls))
    return SimulatedRun(poses, controls, obs)
