"""Commanded trajectories shared by the simulators: control sequences and their integration.

* :func:`loop_controls`: constant velocity-model controls ``(v, ω, Δt)``, a circle (the landmark
  world of :mod:`jaxnav.sim.landmark_world`, the demo and the classical filters' tests).
* :func:`rectangle_controls`: world-frame ``omni`` controls ``(v_x, v_y, ω, Δt)`` ([W] eq. 3.6)
  that drive a rectangle for some laps, as in [W] §3.4.1, optionally turning at the corners.
* :func:`random_controls`: a random trajectory at 0.1–0.4 m/s inside a box ([W] §3.4.2).
* :func:`integrate_controls`: the poses that a control sequence drives exactly (the ground truth
  of the tag-carpet simulator).

Units are SI (m, rad, s).
"""

from __future__ import annotations

import math
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import rng
from jaxnav.core.filter import check_key
from jaxnav.core.validation import check_nonnegative_int
from jaxnav.core.weights import wrap_angle
from jaxnav.models.motion import get_motion_model, omni_mean

__all__ = ["loop_controls", "rectangle_controls", "random_controls", "integrate_controls"]


def loop_controls(num_steps: int, speed: float = 0.5, turn_rate: float = 0.15, dt: float = 0.25) -> jax.Array:
    """Constant velocity-model controls ``[T, 3] = (v [m/s], ω [rad/s], Δt [s])``: a circle.

    ``num_steps`` is ``T``, an integer ≥ 0 (0 gives an empty ``[0, 3]`` sequence); anything else
    raises ``ValueError`` naming it.
    """
    num_steps = check_nonnegative_int("num_steps", num_steps)
    return jnp.tile(jnp.asarray([speed, turn_rate, dt], jnp.float32), (num_steps, 1))


def _check_speed(name: str, value) -> float:
    v = float(value)
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be a finite number > 0 m/s, got {value!r} ([W] drives at 0.1–0.4 m/s)")
    return v


def _check_dt(dt) -> float:
    d = float(dt)
    if not (math.isfinite(d) and d > 0):
        raise ValueError(f"dt must be a finite number > 0 s, got {dt!r}")
    return d


def rectangle_controls(
    width: float,
    height: float,
    speed: float = 0.2,
    dt: float = 0.1,
    laps: int = 3,
    start: tuple[float, float] = (0.0, 0.0),
    turn_at_corners: bool = True,
    turn_rate: float = math.pi / 4,
) -> tuple[jax.Array, jax.Array]:
    """The "predetermined" trajectory of [W] §3.4.1: a rectangle driven ``laps`` times.

    The robot starts at corner ``start`` heading +x (θ = 0) and drives
    counter-clockwise: +x for ``width``, +y for ``height``, −x, −y. Each edge
    takes ``n = max(1, round(L/(speed·Δt)))`` steps at speed ``L/(n·Δt)``
    (exactly ``speed`` when ``L`` is a multiple of ``speed·Δt``; otherwise within
    a relative ``1/(2n) ≤ speed·Δt/(2L − speed·Δt)``), so every lap closes exactly. With
    ``turn_at_corners`` the robot turns in place by +π/2 at each corner at
    about ``turn_rate`` rad/s (an integer number of steps; exactly π/2), so it
    always faces its direction of travel; otherwise it keeps θ = 0 and drives
    sideways (it is omnidirectional).

    Returns:
        ``(start_pose [3], controls [T, 4])``, rows ``(v_x, v_y, ω, Δt)`` in the
        world frame (the ``omni`` motion model).
    """
    w, h = float(width), float(height)
    if not (math.isfinite(w) and math.isfinite(h) and w > 0 and h > 0):
        raise ValueError(f"width and height must be finite numbers > 0 m, got {width!r}, {height!r}")
    v = _check_speed("speed", speed)
    d = _check_dt(dt)
    if isinstance(laps, bool) or not isinstance(laps, (int, np.integer)) or laps < 1:
        raise ValueError(f"laps must be a positive integer, got {laps!r}")
    rate = float(turn_rate)
    if turn_at_corners and not (math.isfinite(rate) and rate > 0):
        raise ValueError(f"turn_rate must be a finite number > 0 rad/s, got {turn_rate!r}")
    sx, sy = (float(a) for a in start)
    rows = []
    for length, (ux, uy) in zip((w, h, w, h), ((1, 0), (0, 1), (-1, 0), (0, -1))):
        n = max(1, int(round(length / (v * d))))
        spd = length / (n * d)
        rows.append(np.tile([ux * spd, uy * spd, 0.0, d], (n, 1)))
        if turn_at_corners:
            nt = max(1, int(math.ceil((math.pi / 2) / (rate * d) - 1e-9)))
            rows.append(np.tile([0.0, 0.0, (math.pi / 2) / (nt * d), d], (nt, 1)))
    lap = np.concatenate(rows, axis=0)
    controls = np.tile(lap, (int(laps), 1))
    dtype = jnp.result_type(float)  # float32, or float64 under x64
    return jnp.asarray([sx, sy, 0.0], dtype), jnp.asarray(controls, dtype)


@partial(jax.jit, static_argnames=("num_steps",))
def _random_controls(key, lo, hi, speed_lo, speed_hi, dt, start_pose, turn_rate, heading_time, num_steps):
    margin = 1.001 * speed_hi * dt
    inner_lo, inner_hi = lo + margin, hi - margin

    def body(carry, t):
        pose, waypoint, speed = carry
        k_w, k_s = jax.random.split(jax.random.fold_in(key, t))
        d = waypoint - pose[:2]
        dist = jnp.sqrt(jnp.sum(d * d))
        arrived = dist < speed * dt
        waypoint = jnp.where(arrived, rng.uniform(k_w, (2,), lo.dtype, inner_lo, inner_hi), waypoint)
        speed = jnp.where(arrived, rng.uniform(k_s, (), lo.dtype, speed_lo, speed_hi), speed)
        d = waypoint - pose[:2]
        dist = jnp.sqrt(jnp.sum(d * d))
        safe = jnp.where(dist > 0, dist, 1.0)
        vel = jnp.where(dist > 0, speed * d / safe, jnp.stack([speed, jnp.zeros_like(speed)]))
        # heading turns smoothly (bounded rate) towards the direction of travel
        err = wrap_angle(jnp.arctan2(vel[1], vel[0]) - pose[2])
        omega = jnp.clip(err / jnp.maximum(heading_time, dt), -turn_rate, turn_rate)
        u = jnp.stack([vel[0], vel[1], omega, dt])
        return (omni_mean(pose, u), waypoint, speed), u

    init = (start_pose, start_pose[:2], speed_lo)
    _, controls = jax.lax.scan(body, init, jnp.arange(num_steps))
    return controls


def random_controls(
    key: jax.Array,
    bounds: tuple[float, float, float, float] = (0.0, 0.0, 2.0, 2.0),
    num_steps: int = 1000,
    speed_range: tuple[float, float] = (0.1, 0.4),
    dt: float = 0.1,
    start: tuple[float, float] | None = None,
    turn_rate: float = 1.0,
    heading_time: float = 0.5,
) -> tuple[jax.Array, jax.Array]:
    """The random trajectory of [W] §3.4.2: straight runs between random waypoints.

    Waypoints are uniform in ``bounds`` shrunk by ``speed_max·Δt``; the robot
    drives straight at a speed uniform in ``speed_range`` (m/s; [W]: 0.1–0.4)
    and draws a new waypoint and speed when it is within one step of the
    current one. Every position stays inside ``bounds``: the path runs on
    segments between points of the box and overshoots a waypoint by less than
    one step. The heading (an omnidirectional robot need not face its direction
    of travel) turns towards the direction of travel at ``err/heading_time``,
    at most ``turn_rate`` rad/s, so it changes smoothly.

    Args:
        key: PRNG key.
        bounds: ``(xmin, ymin, xmax, ymax)`` (m).
        num_steps: ``T``, an integer ≥ 0 (0 gives an empty ``[0, 4]`` sequence).
        speed_range: ``(min, max)`` speed (m/s), ``0 < min ≤ max``.
        dt: step (s).
        start: ``(x, y)`` start inside ``bounds``; default the centre. Start heading 0.
        turn_rate: largest ``|ω|`` (rad/s).
        heading_time: time constant of the heading (s).

    Returns:
        ``(start_pose [3], controls [T, 4])`` rows ``(v_x, v_y, ω, Δt)``, world frame.
    """
    check_key(key)
    try:
        xmin, ymin, xmax, ymax = (float(b) for b in bounds)
    except (TypeError, ValueError):
        raise ValueError(f"bounds must be (xmin, ymin, xmax, ymax) in m, got {bounds!r}") from None
    num_steps = check_nonnegative_int("num_steps", num_steps)
    lo_s = _check_speed("speed_range[0]", speed_range[0])
    hi_s = _check_speed("speed_range[1]", speed_range[1])
    if hi_s < lo_s:
        raise ValueError(f"speed_range must be (min, max) with min ≤ max, got {speed_range!r}")
    d = _check_dt(dt)
    margin = 1.001 * hi_s * d
    if not (xmax - xmin > 2 * margin and ymax - ymin > 2 * margin):
        raise ValueError(f"bounds {bounds!r} are too small: each side must exceed 2·speed_max·dt = {2 * margin:g} m")
    if start is None:
        start = (0.5 * (xmin + xmax), 0.5 * (ymin + ymax))
    sx, sy = (float(a) for a in start)
    if not (xmin <= sx <= xmax and ymin <= sy <= ymax):
        raise ValueError(f"start {start!r} must lie inside bounds {bounds!r}")
    rate = float(turn_rate)
    if not (math.isfinite(rate) and rate > 0):
        raise ValueError(f"turn_rate must be a finite number > 0 rad/s, got {turn_rate!r}")
    ht = float(heading_time)
    if not (math.isfinite(ht) and ht > 0):
        raise ValueError(f"heading_time must be a finite number > 0 s, got {heading_time!r}")
    dtype = jnp.result_type(float)  # float32, or float64 under x64
    f = lambda v: jnp.asarray(v, dtype)  # noqa: E731
    start_pose = f([sx, sy, 0.0])
    controls = _random_controls(
        key, f([xmin, ymin]), f([xmax, ymax]), f(lo_s), f(hi_s), f(d), start_pose, f(rate), f(ht), int(num_steps)
    )
    return start_pose, controls


def integrate_controls(start_pose: jax.Array, controls: jax.Array, motion_model: str = "omni") -> jax.Array:
    """``[T, 3]`` poses after each control row, integrated with the noise-free model (``omni`` or ``omni_body``)."""
    if motion_model not in ("omni", "omni_body"):
        raise ValueError(f"motion_model must be 'omni' or 'omni_body', got {motion_model!r}")
    mean = get_motion_model(motion_model).mean

    def body(pose, u):
        pose = mean(pose, u)
        return pose, pose

    _, poses = jax.lax.scan(body, jnp.asarray(start_pose, controls.dtype), controls)
    return poses
