"""Trajectories shared by the simulators: control sequences, their integration, and UHF reader paths.

* :func:`loop_controls`: constant velocity-model controls ``(v, ω, Δt)``, a circle (the landmark
  world of :mod:`jaxnav.sim.landmark_world`, the demo and the classical filters' tests).
* :func:`rectangle_controls`: world-frame ``omni`` controls ``(v_x, v_y, ω, Δt)`` ([W] eq. 3.6)
  that drive a rectangle for some laps, as in [W] §3.4.1, optionally turning at the corners.
* :func:`random_controls`: a random trajectory at 0.1–0.4 m/s inside a box ([W] §3.4.2).
* :func:`integrate_controls`: the poses that a control sequence drives exactly (the ground truth
  of the tag-carpet simulator).
* :func:`line_path`, :func:`lawnmower_path`: poses ``(x, y, z, ψ)`` of a UHF-RFID reader antenna
  (the paths of :mod:`jaxnav.sim.uhf_reader` and of the UHF experiments).

**Paths of a UHF reader**

:func:`line_path` is the straight pass of [A] Fig. 5.2 (distance to the tag
first decreasing, then increasing). One straight line cannot localise a tag
in 3D: every distance to points of a line is unchanged by a rotation about
the line, so a circle of positions fits (the antenna pattern breaks this only
coarsely). Parallel passes whose cross-section offsets ``(y, z)`` are
**not collinear** (:func:`lawnmower_path` with ≥ 2 depths and ≥ 2 heights)
remove it: the range profile along each pass gives ``x`` and the
perpendicular distance to that pass, and three perpendicular distances to
non-collinear points of the ``(y, z)`` plane fix ``(y, z)`` (two leave a
mirror image). With an unknown phase offset the phase gives range
*differences* along each pass, whose curvature still fixes the perpendicular
distance, so the argument holds for phase-only localization too.

Units are SI (m, rad, s).
"""

from __future__ import annotations

import math
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import rng
from jaxnav.core.filter import check_key
from jaxnav.core.validation import check_finite, check_nonnegative_int, check_positive_int, check_shape
from jaxnav.core.weights import wrap_angle
from jaxnav.models.motion import check_motion_model, get_motion_model, omni_mean

__all__ = [
    "loop_controls",
    "rectangle_controls",
    "random_controls",
    "integrate_controls",
    "DEFAULT_READER_HEIGHT",
    "line_path",
    "lawnmower_path",
]

DEFAULT_READER_HEIGHT = 1.0
"""Reader antenna height (m) when a path is given in 2D (ours)."""


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


def integrate_controls(start_pose: jax.Array, controls: jax.Array, motion_model: Any = "omni") -> jax.Array:
    """``[T, 3]`` poses after each control row, integrated with the noise-free model (a name in
    :data:`jaxnav.models.motion.MODELS` or a motion model): dead reckoning, or the path a control
    sequence drives exactly."""
    check_motion_model("motion_model", motion_model)
    mean = get_motion_model(motion_model).mean

    def body(pose, u):
        pose = mean(pose, u)
        return pose, pose

    _, poses = jax.lax.scan(body, jnp.asarray(start_pose, controls.dtype), controls)
    return poses


# --------------------------------------------------------------------------------------
# Paths of a UHF reader (host-side NumPy)
# --------------------------------------------------------------------------------------


def _point3(name: str, p: Any, height: float | None) -> np.ndarray:
    v = np.asarray(p, np.float64)
    if v.shape not in ((2,), (3,)):
        raise ValueError(f"{name} must have shape (2,) or (3,), got {v.shape}")
    check_finite(name, v)
    if v.shape == (2,):
        v = np.append(v, DEFAULT_READER_HEIGHT if height is None else float(height))
    elif height is not None:
        v = v.copy()
        v[2] = float(height)
    if v[2] < 0:
        raise ValueError(f"{name} z (height above the ground z = 0) must be ≥ 0, got {v[2]}")
    return v


def line_path(
    start: Any,
    end: Any,
    num_steps: int,
    heading: float | None = None,
    height: float | None = None,
    facing: Any = None,
) -> np.ndarray:
    """Reader poses ``[T, 4]`` ``(x, y, z, ψ)`` evenly spaced on the segment ``start → end`` ([A] Fig. 5.2).

    Args:
        start, end: ``[2]`` (x, y) or ``[3]`` (x, y, z) positions (m).
        num_steps: ``T ≥ 2`` poses, both ends included.
        heading: constant boresight yaw ``ψ`` (rad). Default: perpendicular to
            the motion (a side-looking antenna), toward the side of ``facing``
            if given, else to the left of the direction of travel
            (``atan2(Δy, Δx) + π/2``).
        height: reader height (m); overrides the z of 3D points; default
            :data:`DEFAULT_READER_HEIGHT` for 2D points.
        facing: optional ``[2]``/``[3]`` point (e.g. the tag) the antenna should face.

    Returns float32 ``[T, 4]``.
    """
    num_steps = check_positive_int("num_steps", num_steps)
    if num_steps < 2:
        raise ValueError(f"num_steps must be ≥ 2 (a line has two ends), got {num_steps}")
    a = _point3("start", start, height)
    b = _point3("end", end, height)
    d = b - a
    if np.hypot(d[0], d[1]) <= 1e-12 and heading is None:
        raise ValueError("start and end have the same (x, y): give an explicit heading")
    if heading is None:
        psi = math.atan2(d[1], d[0]) + math.pi / 2.0
        if facing is not None:
            f = np.asarray(facing, np.float64)
            if f.shape not in ((2,), (3,)):
                raise ValueError(f"facing must have shape (2,) or (3,), got {f.shape}")
            check_finite("facing", f)
            side = d[0] * (f[1] - a[1]) - d[1] * (f[0] - a[0])  # > 0: facing point on the left
            if side < 0:
                psi -= math.pi
        psi = math.atan2(math.sin(psi), math.cos(psi))
    else:
        check_finite("heading", heading)
        psi = float(heading)
    s = np.linspace(0.0, 1.0, num_steps)[:, None]
    xyz = a + s * d
    return np.concatenate([xyz, np.full((num_steps, 1), psi)], axis=1).astype(np.float32)


def lawnmower_path(
    x_range: Any,
    y_values: Any,
    z_values: Any,
    steps_per_pass: int,
    heading: float = math.pi / 2,
    connect: bool = True,
) -> np.ndarray:
    """Boustrophedon of parallel passes along x at every ``(y, z)`` offset: poses ``[T, 4]``.

    Passes run along ``x`` from ``x_range[0]`` to ``x_range[1]`` and back,
    alternately, at each depth ``y`` (inner loop, snaking) and height ``z``
    (outer loop). The boresight keeps the yaw ``heading`` (default ``π/2``:
    facing +y, so tags should lie at larger y than the passes). For 3D
    observability give ≥ 2 depths and ≥ 2 heights (non-collinear ``(y, z)``
    offsets; module docstring, "Paths of a UHF reader").

    Args:
        x_range: ``(x_start, x_end)`` (m).
        y_values, z_values: ``[Ny]``, ``[Nz]`` pass offsets (m); ``z ≥ 0``.
        steps_per_pass: poses per pass (≥ 2), ends included.
        heading: constant yaw (rad).
        connect: add straight connector moves between passes, sampled at the
            pass spacing (the reader keeps reading while it moves over); with
            False consecutive passes are simply concatenated.

    Returns float32 ``[T, 4]``; ``T = Ny·Nz·steps_per_pass`` plus the connectors.
    """
    xr = np.asarray(x_range, np.float64)
    check_shape("x_range", xr, (2,))
    check_finite("x_range", xr)
    if xr[0] == xr[1]:
        raise ValueError(f"x_range must have two different ends, got {xr.tolist()}")
    ys = np.atleast_1d(np.asarray(y_values, np.float64))
    zs = np.atleast_1d(np.asarray(z_values, np.float64))
    check_shape("y_values", ys, (None,))
    check_shape("z_values", zs, (None,))
    if ys.size < 1 or zs.size < 1:
        raise ValueError("y_values and z_values must hold at least one offset each")
    check_finite("y_values", ys)
    check_finite("z_values", zs)
    if np.any(zs < 0):
        raise ValueError(f"z_values (reader heights) must be ≥ 0, got {zs.tolist()}")
    steps = check_positive_int("steps_per_pass", steps_per_pass)
    if steps < 2:
        raise ValueError(f"steps_per_pass must be ≥ 2, got {steps}")
    check_finite("heading", heading)
    spacing = abs(xr[1] - xr[0]) / (steps - 1)
    segs: list[np.ndarray] = []
    n = 0
    for iz, z in enumerate(zs):
        y_order = ys if iz % 2 == 0 else ys[::-1]
        for y in y_order:
            x0, x1 = (xr[0], xr[1]) if n % 2 == 0 else (xr[1], xr[0])
            p = np.stack([np.linspace(x0, x1, steps), np.full(steps, y), np.full(steps, z)], axis=1)
            if connect and segs:
                prev = segs[-1][-1]
                gap = np.linalg.norm(p[0] - prev)
                m = int(math.ceil(gap / spacing - 1e-9)) - 1
                if m > 0:
                    f = np.arange(1, m + 1)[:, None] / (m + 1)
                    segs.append(prev + f * (p[0] - prev))
            segs.append(p)
            n += 1
    xyz = np.concatenate(segs, axis=0)
    return np.concatenate([xyz, np.full((xyz.shape[0], 1), float(heading))], axis=1).astype(np.float32)
