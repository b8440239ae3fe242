"""Simulated drives under an IR emitter ceiling: true path, odometry and receiver detections ([W] §5.4).

**Overview**

The data of the IR experiments of [W] §5.4 in simulation:

1. **Path** (host-side, :func:`polyline_path`): the robot drives a polyline
   of waypoints at constant speed (200 mm/s in [W] §5.4.1), sampled every
   ``dt`` seconds, looping over a closed polyline as often as needed. The
   heading is held constant (``0``: "the orientation of the robot was
   maintained at 0 [rad]", [W] §5.4.2) or, with ``[K, 3]`` waypoints,
   interpolated along each segment (the trajectory with rotations of
   [W] §5.4.3). The robot follows the path exactly: the path *is* the
   ground truth.
2. **Odometry** (:func:`simulate`): the robot-frame velocities
   ``(v_x, v_y, ω)`` that move the truth from one sample to the next (the
   ``omni_body`` model of :mod:`jaxnav.models.motion`, [W] eq. 3.6 with the
   velocity measured on the robot), corrupted by a scale error and white
   noise (:class:`OdometryError`):
   ``u_odo = u_true · (1 + scale) + N(0, sd²)`` while the robot moves,
   and exactly zero while it stands still (the stays at the marked spots of
   [W] §5.4.2: encoders that do not turn read nothing). [W] gives no odometry
   figures; the defaults were chosen so that dead reckoning from the known
   start pose drifts by about [W]'s "odometry only" error (108 mm mean over
   the 70 spots of Table 5.2) over one 60 s lap (measured in
   ``tests/localization/test_ir_mcl.py``).
3. **Detections**: at every step, one receiver window per receiver at the
   true pose, through the physical receiver simulator and its FFT decoder,
   :func:`jaxnav.sim.ir_receiver.detect` (called inside the ``lax.scan``),
   so that a change of the emitter–receiver height in the receiver
   parameters changes the voltages the filter sees ([W] Table 5.3).

Keys: step ``t`` (``0 … T−1``) draws its odometry noise from
``fold_in(k_odo, t)`` and its receiver window from ``fold_in(k_det, t)``,
with ``k_odo, k_det = split(key)``; two simulations with one key and
different receiver parameters share every draw ("same seeds").

Units: m, rad, s, V. Shapes are fixed: ``T`` steps, ``R`` receivers.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import rng
from jaxnav.core.filter import check_key
from jaxnav.core.validation import (
    check_finite,
    check_magnitude,
    check_nonnegative,
    check_positive,
    check_positive_int,
    check_shape,
    is_concrete,
)
from jaxnav.core.weights import wrap_angle
from jaxnav.models import ir
from jaxnav.models.motion import omni_body_mean
from jaxnav.sim import ir_receiver

__all__ = [
    "EXPERIMENT_REPEATED_ROWS",
    "EXPERIMENT_UNIQUE_NAMES",
    "experiment_layout",
    "unique11_layout",
    "OdometryError",
    "DEFAULT_ODOMETRY_ERROR",
    "IRRun",
    "EXPERIMENT_WAYPOINTS",
    "experiment_waypoints",
    "ROTATION_WAYPOINTS",
    "layout_area",
    "polyline_path",
    "spot_grid",
    "SpotTour",
    "spot_tour",
    "body_controls",
    "simulate",
    "dead_reckoning",
]


# ---------------------------------------------------------------------------
# the emitter layouts of [W] §5.4


EXPERIMENT_REPEATED_ROWS = ((1, 2, 4, 5), (4, 5, 1, 2))
EXPERIMENT_UNIQUE_NAMES = ("39", "67", "68")


def experiment_layout(pitch: float = 0.80, origin: Sequence[float] = (0.4, 0.4)) -> ir.EmitterLayout:
    """The experimental layout of [W] §5.4 (Fig. 5.9): 8 repeated + 3 unique emitters.

    [W] gives the counts (3 unique-ID arrays, 8 repeated-ID LEDs with 4
    repeated IDs, 7 microcontrollers, 0.80 m between emitters of one type,
    unique arrays at the centres of squares of four) but no coordinates or
    code assignment. Our choice: a 4 × 2 block of repeated emitters at
    ``origin + pitch·(i, j)``, ``i = 0…3``, ``j = 0, 1`` (default origin
    (0.4, 0.4) m: the block spans x 0.4–2.8 m, y 0.4–1.2 m, and [W]'s start
    point (300, 800) mm lies at its left edge), with the three unique arrays at
    the centres of the three squares. Repeated codes: row ``j = 0`` carries
    1, 2, 4, 5 and row ``j = 1`` carries 4, 5, 1, 2 (left to right), so all
    neighbours differ and each ID is used twice, ≥ 1.79 m apart. Unique IDs
    ``39`` ([W]'s example, §5.1), ``67`` and ``68``: pairs (the 4-LED array of
    Fig. 5.2a can drive two LEDs per code) sharing no code with the repeated
    LEDs.

    Indices: repeated ``0–7`` row-major (``j·4 + i``), unique ``8–10`` left to right.
    """
    check_positive("pitch", pitch)
    if float(pitch) < ir.CONFLICT_RADIUS:
        raise ValueError(
            f"pitch must be at least conflict_radius = {ir.CONFLICT_RADIUS} m (jaxnav.models.ir, "
            f"'Decodability'), got {pitch}"
        )
    org = np.asarray(origin, dtype=np.float64)
    check_shape("origin", org, (2,))
    check_finite("origin", org)
    p = float(pitch)
    positions, sets = [], []
    for j in range(2):
        for i in range(4):
            positions.append(org + p * np.array([i, j]))
            sets.append((EXPERIMENT_REPEATED_ROWS[j][i],))
    for i, name in enumerate(EXPERIMENT_UNIQUE_NAMES):
        positions.append(org + p * np.array([i + 0.5, 0.5]))
        sets.append(name)
    return ir.make_layout(np.array(positions), sets)


def unique11_layout(pitch: float = 0.80, origin: Sequence[float] = (0.4, 0.4)) -> ir.EmitterLayout:
    """The 11-unique-ID configuration of [W] §5.4.1 / Table 5.2 ("11 unique IDs").

    The same 11 positions (and indices) as :func:`experiment_layout` ("the
    same interval between the emitters as the proposed system"), every
    emitter a unique pair of codes ([W] lists none): in emitter order, the
    first unused pair in canonical order sharing no code with an emitter
    closer than :data:`jaxnav.models.ir_layouts.CONFLICT_RADIUS` — ``12 13 14 15 16 17 18 19`` on the 8
    lattice points, ``45 25 23`` at the centres.
    """
    base = experiment_layout(pitch=pitch, origin=origin)
    pos = np.asarray(base.positions, np.float64)
    return ir.make_layout(pos, ir.assign_unique_sets(pos, [None] * pos.shape[0], 2, ir.CONFLICT_RADIUS))


class OdometryError(NamedTuple):
    """Odometry corruption ``u_odo = u_true · (1 + scale) + N(0, sd²)`` per step.

    Attributes:
        sd: ``[3]`` white-noise sd of the measured robot-frame velocities
            ``(v_x [m/s], v_y [m/s], ω [rad/s])``.
        scale: ``[3]`` relative scale error of each velocity (dimensionless;
            e.g. a wheel radius 2 % too small reads 2 % too far).
    """

    sd: jax.Array
    scale: jax.Array


DEFAULT_ODOMETRY_ERROR = OdometryError(
    sd=np.array([0.03, 0.03, 0.03], np.float32), scale=np.array([0.04, -0.04, 0.0], np.float32)
)
"""Odometry error of the simulated IR drives, our choice as [W] gives no odometry figures.

0.03 m/s, 0.03 m/s, 0.03 rad/s white noise, +4 % / −4 % scale on v_x / v_y. Dead reckoning from the known start then drifts by ~0.1 m on average (~0.2 m at
worst) over a 60 s lap of :data:`EXPERIMENT_WAYPOINTS` at 0.2 m/s, the size of [W]'s "odometry only"
row of Table 5.2 (108 mm mean, 189 mm max)."""


class IRRun(NamedTuple):
    """A simulated drive of ``T`` steps.

    Attributes:
        initial_pose: ``[3]`` true pose before the first step (m, m, rad).
        true_poses: ``[T, 3]`` true pose at each step, after its motion.
        controls: ``[T, 4]`` measured odometry ``(v_x, v_y, ω, Δt)`` in the
            robot frame (m/s, m/s, rad/s, s): the ``omni_body`` control that
            moves ``true_poses[t−1]`` to ``true_poses[t]``, corrupted.
        true_controls: ``[T, 4]`` the same without corruption.
        detections: :class:`~jaxnav.models.ir.IRDetection` with leading
            axis ``T`` (``mask``/``valid``/``voltage`` ``[T, R]``,
            ``amplitude`` ``[T, R, 9]``), read at ``true_poses[t]``.
    """

    initial_pose: jax.Array
    true_poses: jax.Array
    controls: jax.Array
    true_controls: jax.Array
    detections: ir.IRDetection


EXPERIMENT_WAYPOINTS = np.array(
    [[0.3, 0.8], [2.9, 0.8], [2.9, 1.2], [0.3, 1.2], [0.3, 0.4], [2.9, 0.4], [2.9, 0.8]], np.float64
)
"""Closed loop (m) under :func:`experiment_layout` (default origin and pitch).

[W] Fig. 5.10 draws the predetermined trajectory but gives no coordinates
besides the start, (300, 800) mm. Ours starts there, drives east under the
three unique arrays (y = 0.8 m), back west under the upper repeated row
(y = 1.2 m), east under the lower row (y = 0.4 m) and back to the start
along y = 0.8 m (the loop closes from the last waypoint to the first):
12.0 m, one lap in 60 s at 0.2 m/s. It passes under all 11 emitters."""


def experiment_waypoints(start: int = 0) -> np.ndarray:
    """:data:`EXPERIMENT_WAYPOINTS` rotated to start at waypoint ``start`` (a copy, ``[7, 2]``, m).

    ``start = 4`` begins at (0.3, 0.4) m under the lower repeated row, so the
    robot sees repeated IDs before the first unique one.
    """
    k = EXPERIMENT_WAYPOINTS.shape[0]
    if isinstance(start, bool) or not isinstance(start, (int, np.integer)) or not 0 <= start < k:
        raise ValueError(f"start must be a waypoint index in 0–{k - 1}, got {start!r}")
    return np.roll(EXPERIMENT_WAYPOINTS, -int(start), axis=0).copy()


ROTATION_WAYPOINTS = np.array(
    [
        [0.3, 0.8, 0.0],  # E
        [1.2, 0.8, 0.0],
        [1.2, 0.8, np.pi / 2],  # 1st turn
        [1.2, 0.4, np.pi / 2],
        [1.2, 0.4, np.pi],  # 2nd
        [2.0, 0.4, np.pi],
        [2.0, 0.4, -np.pi / 2],  # 3rd
        [2.0, 1.2, -np.pi / 2],
        [2.0, 1.2, np.pi / 4],  # 4th
        [2.8, 1.2, np.pi / 4],
        [2.8, 1.2, -3 * np.pi / 4],  # 5th
        [2.8, 0.8, -3 * np.pi / 4],  # K
    ],
    np.float64,
)
"""Open path from E to K with five turns on the spot (m, m, rad), under :func:`experiment_layout`.

[W] §5.4.3 (Fig. 5.14) drives "from E point to K point" and changes the
orientation "five times at the marked points", without coordinates. Ours
(the robot is holonomic: it drives sideways or backwards as its heading
requires): E = (0.3, 0.8) m at heading 0, east under the first unique
array, then turns of +π/2, +π/2, +π/2 (to −π/2), +3π/4 (to π/4) and
π (to −3π/4) at (1.2, 0.8), (1.2, 0.4), (2.0, 0.4), (2.0, 1.2) and
(2.8, 1.2), ending at K = (2.8, 0.8): 4.1 m and 10.2 rad of turning, 41 s at
0.2 m/s and 0.5 rad/s (:func:`polyline_path` with ``closed=False``)."""


def layout_area(layout: ir.EmitterLayout, margin: float = 0.4) -> tuple[float, float, float, float]:
    """``(x_min, x_max, y_min, y_max)`` (m): the emitters' bounding box grown by ``margin``.

    With the default 0.4 m (half the 0.80 m pitch) and
    :func:`experiment_layout` this is (0, 3.2, 0, 1.6) m:
    the area over which the filter's particles start uniform ([W] §5.2).
    """
    check_nonnegative("margin", margin)
    p = np.asarray(layout.positions, np.float64)
    check_shape("layout.positions", p, (None, 2))
    lo = p.min(axis=0) - float(margin)
    hi = p.max(axis=0) + float(margin)
    if not np.all(hi > lo):
        raise ValueError("the area is empty: give a positive margin for a layout of one emitter")
    return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])


def polyline_path(
    waypoints: Any,
    speed: float = 0.2,
    dt: float = 0.1,
    num_steps: int = 600,
    closed: bool = True,
    heading: float = 0.0,
) -> np.ndarray:
    """True poses ``[T + 1, 3]`` (m, m, rad) along ``waypoints`` at constant ``speed`` (host-side).

    Args:
        waypoints: ``[K, 2]`` positions (m), or ``[K, 3]`` with a heading (rad)
            at each waypoint, interpolated along each segment the short way
            round (a segment of zero length is a turn on the spot, taking
            ``|Δθ| / ω_max`` with ``ω_max = 0.5`` rad/s).
        speed: m/s (0.2 in [W] §5.4.1; 0.1–0.3 in §5.4.4).
        dt: sample period (s).
        num_steps: ``T``; the path loops over the polyline as often as needed.
        closed: with True the last waypoint joins the first; with False the
            robot stops at the last waypoint (and stays there).
        heading: constant heading (rad) for ``[K, 2]`` waypoints.

    Returns:
        ``poses[0]`` is the first waypoint; ``poses[t]`` the pose ``t·dt`` later.
    """
    wp = np.asarray(waypoints, np.float64)
    if wp.ndim != 2 or wp.shape[1] not in (2, 3) or wp.shape[0] < 2:
        raise ValueError(f"waypoints must have shape (K, 2) or (K, 3) with K ≥ 2, got {wp.shape}")
    check_finite("waypoints", wp)
    check_positive("speed", speed)
    check_positive("dt", dt)
    num_steps = check_positive_int("num_steps", num_steps)
    check_finite("heading", heading)
    if wp.shape[1] == 2:
        wp = np.concatenate([wp, np.full((wp.shape[0], 1), float(heading))], axis=1)
    if closed:
        wp = np.concatenate([wp, wp[:1]], axis=0)
    # segment durations: translation at `speed`, a turn on the spot at 0.5 rad/s
    d_xy = np.linalg.norm(np.diff(wp[:, :2], axis=0), axis=1)
    d_th = np.abs(np.asarray(wrap_angle(np.diff(wp[:, 2]))))
    dur = np.where(d_xy > 1e-12, d_xy / float(speed), d_th / 0.5)
    if not np.any(dur > 0):
        raise ValueError("waypoints do not move: every segment has zero length and no turn")
    t_knots = np.concatenate([[0.0], np.cumsum(dur)])
    lap = t_knots[-1]
    t = np.arange(num_steps + 1) * float(dt)
    t = np.mod(t, lap) if closed else np.minimum(t, lap)
    seg = np.clip(np.searchsorted(t_knots, t, side="right") - 1, 0, len(dur) - 1)
    frac = np.where(dur[seg] > 0, (t - t_knots[seg]) / np.where(dur[seg] > 0, dur[seg], 1.0), 1.0)
    a, b = wp[seg], wp[seg + 1]
    xy = a[:, :2] + frac[:, None] * (b[:, :2] - a[:, :2])
    th = np.asarray(wrap_angle(a[:, 2] + frac * np.asarray(wrap_angle(b[:, 2] - a[:, 2]))))
    return np.concatenate([xy, th[:, None]], axis=1).astype(np.float32)


def spot_grid(
    nx: int = 14, ny: int = 5, x: tuple[float, float] = (0.3, 2.9), y: tuple[float, float] = (0.4, 1.2)
) -> np.ndarray:
    """``[ny · nx, 2]`` marked spots (m) on a regular grid, row by row (y outer, x inner).

    [W] §5.4.2 marks 70 spots (Fig. 5.12, no coordinates). Ours: the default
    14 × 5 grid, 0.2 m apart, over x ∈ [0.3, 2.9] m and y ∈ [0.4, 1.2] m,
    the band under :func:`experiment_layout` the emitters
    cover (rows of repeated emitters at y = 0.4 and 1.2 m, unique arrays at
    0.8 m).
    """
    nx = check_positive_int("nx", nx)
    ny = check_positive_int("ny", ny)
    check_finite("x", np.asarray(x, np.float64))
    check_finite("y", np.asarray(y, np.float64))
    gx = np.linspace(float(x[0]), float(x[1]), nx)
    gy = np.linspace(float(y[0]), float(y[1]), ny)
    return np.stack(np.meshgrid(gx, gy), axis=-1).reshape(-1, 2)


class SpotTour(NamedTuple):
    """A drive that stops at marked spots (:func:`spot_tour`).

    Attributes:
        poses: ``[T + 1, 3]`` true poses (m, m, rad), ``poses[0]`` the start.
        spot: ``[T + 1]`` int: the index of the spot the robot stands on at
            each sample, −1 while it moves (or waits after the tour).
        spots: ``[S, 2]`` the spots in visiting order (m).
    """

    poses: np.ndarray
    spot: np.ndarray
    spots: np.ndarray


def spot_tour(
    spots: Any,
    speed: float = 0.2,
    dt: float = 0.1,
    dwell: float = 5.0,
    heading: float = 0.0,
    lead_in: Any = None,
    serpentine: int | None = None,
    num_steps: int | None = None,
) -> SpotTour:
    """A drive through ``spots`` at constant ``speed`` that stands ``dwell`` s on each ([W] §5.4.2).

    "The robot stays 5 seconds at the marked spot when passing by to record
    the estimated position and orientation data of the robot. The orientation
    of the robot was maintained at 0 [rad]."

    Args:
        spots: ``[S, 2]`` spots (m), visited in order (see ``serpentine``).
        speed: m/s between spots.
        dt: sample period (s).
        dwell: seconds on each spot (its samples are labelled with the spot).
        heading: the constant heading (rad).
        lead_in: optional ``[K, 2]`` waypoints driven first, without stops
            (the robot starts at ``lead_in[0]``; e.g. a pass under the
            unique emitters so that the filter has started before the first
            spot). Without it the robot starts on the first spot.
        serpentine: with ``nx``, treat ``spots`` as rows of ``nx`` (as
            :func:`spot_grid` makes them) and drive every other row
            backwards (a boustrophedon), so that no leg crosses the area.
        num_steps: pad the drive to ``T`` steps by standing at the last spot
            (label −1), so that tours of different lengths share shapes;
            ``None``: the tour's own length.

    Returns:
        :class:`SpotTour` (host NumPy arrays).
    """
    sp = np.asarray(spots, np.float64)
    check_shape("spots", sp, (None, 2))
    if sp.shape[0] < 1:
        raise ValueError("spots must hold at least one spot")
    check_finite("spots", sp)
    check_positive("speed", speed)
    check_positive("dt", dt)
    check_positive("dwell", dwell)
    check_finite("heading", heading)
    if serpentine is not None:
        nx = check_positive_int("serpentine", serpentine)
        if sp.shape[0] % nx:
            raise ValueError(f"serpentine={nx} does not divide the {sp.shape[0]} spots into rows")
        rows = sp.reshape(-1, nx, 2)
        sp = np.concatenate([r[::-1] if i % 2 else r for i, r in enumerate(rows)], axis=0)
    lead = np.zeros((0, 2)) if lead_in is None else np.asarray(lead_in, np.float64)
    check_shape("lead_in", lead, (None, 2))
    check_finite("lead_in", lead)
    # knots: (position, time) pairs; the robot moves linearly between consecutive knots
    points, times, labels = [], [], []  # labels[i]: the spot held on the segment from knot i to i + 1
    t = 0.0
    for p in lead:
        if points:
            t += float(np.linalg.norm(p - points[-1])) / float(speed)
        points.append(p)
        times.append(t)
        labels.append(-1)
    for i, p in enumerate(sp):
        if points:
            t += float(np.linalg.norm(p - points[-1])) / float(speed)
        points.append(p)
        times.append(t)
        labels.append(i)  # stand
        t += float(dwell)
        points.append(p)
        times.append(t)
        labels.append(-1)  # then move on
    points, times = np.asarray(points), np.asarray(times)
    natural = int(np.floor(times[-1] / float(dt)))
    if num_steps is None:
        num_steps = natural
    num_steps = check_positive_int("num_steps", num_steps)
    if num_steps < natural:
        raise ValueError(f"num_steps={num_steps} is shorter than the tour ({natural} steps)")
    ts = np.arange(num_steps + 1) * float(dt)
    seg = np.clip(np.searchsorted(times, ts, side="right") - 1, 0, len(times) - 1)
    nxt = np.minimum(seg + 1, len(times) - 1)
    span = times[nxt] - times[seg]
    frac = np.where(span > 0, (ts - times[seg]) / np.where(span > 0, span, 1.0), 0.0)
    xy = points[seg] + np.clip(frac, 0.0, 1.0)[:, None] * (points[nxt] - points[seg])
    label = np.where(ts <= times[-1], np.asarray(labels)[seg], -1)
    poses = np.concatenate([xy, np.full((len(ts), 1), float(heading))], axis=1).astype(np.float32)
    return SpotTour(poses, label.astype(np.int32), sp.astype(np.float32))


def body_controls(poses: jax.Array, dt: float | jax.Array) -> jax.Array:
    """``[T, 4]`` exact ``omni_body`` controls ``(v_x, v_y, ω, Δt)`` between consecutive ``poses [T+1, 3]``.

    ``v = R(−θ_{t−1}) (p_t − p_{t−1}) / Δt``, ``ω = wrap(θ_t − θ_{t−1}) / Δt``:
    :func:`jaxnav.models.motion.omni_body_mean` applied to ``poses[t−1]``
    gives ``poses[t]`` back exactly.
    """
    poses = jnp.asarray(poses)
    prev, nxt = poses[:-1], poses[1:]
    d = (nxt[:, :2] - prev[:, :2]) / dt
    c, s = jnp.cos(prev[:, 2]), jnp.sin(prev[:, 2])
    vx = c * d[:, 0] + s * d[:, 1]
    vy = -s * d[:, 0] + c * d[:, 1]
    w = wrap_angle(nxt[:, 2] - prev[:, 2]) / dt
    return jnp.stack([vx, vy, w, jnp.full_like(w, dt)], axis=-1)


@partial(jax.jit, static_argnames=("config",))
def _simulate(key, layout, poses, dt, receiver_params, odometry_error, config):
    true_u = body_controls(poses, dt)
    k_odo, k_det = jax.random.split(key)
    steps = jnp.arange(true_u.shape[0])

    def body(_, inputs):
        t, u, pose = inputs
        eps = rng.normal(jax.random.fold_in(k_odo, t), (3,), u.dtype)
        moving = jnp.any(u[:3] != 0.0)  # a robot standing still reads zero: its encoders do not turn
        v = u[:3] * (1.0 + odometry_error.scale) + jnp.where(moving, odometry_error.sd * eps, 0.0)
        det = ir_receiver.detect(jax.random.fold_in(k_det, t), pose, layout, receiver_params, config)
        return None, (jnp.concatenate([v, u[3:]]), det)

    _, (controls, dets) = jax.lax.scan(body, None, (steps, true_u, poses[1:]))
    return IRRun(poses[0], poses[1:], controls, true_u, dets)


def simulate(
    key: jax.Array,
    layout: ir.EmitterLayout,
    poses: Any,
    dt: float,
    receiver_params: ir_receiver.ReceiverParams | None = None,
    odometry_error: OdometryError = DEFAULT_ODOMETRY_ERROR,
    config: ir_receiver.ReceiverConfig = ir_receiver.DEFAULT_CONFIG,
) -> IRRun:
    """Odometry and receiver detections along the true ``poses [T + 1, 3]`` (e.g. :func:`polyline_path`).

    Args:
        key: PRNG key (module docstring, "Keys").
        layout: the ceiling emitters.
        poses: ``[T + 1, 3]`` true poses (m, m, rad), ``poses[0]`` the start.
        dt: sample period (s) between poses.
        receiver_params: receiver physics (default
            :func:`jaxnav.sim.ir_receiver.default_params`, height 1.2 m);
            its ``offsets [R, 2]`` place the ``R`` receivers on the robot.
        odometry_error: the corruption of the measured velocities.
        config: receiver sampling configuration (one window per step).

    Returns:
        :class:`IRRun`. Jitted; the same shapes never retrace.
    """
    p = jnp.asarray(poses, jnp.float32)
    check_shape("poses", p, (None, 3))
    if p.shape[0] < 2:
        raise ValueError(f"poses must hold at least two poses (T + 1 ≥ 2), got {p.shape[0]}")
    check_key(key)
    check_magnitude("poses", p)
    check_positive("dt", dt)
    if receiver_params is None:
        receiver_params = ir_receiver.default_params()
    if not isinstance(receiver_params, ir_receiver.ReceiverParams):
        raise ValueError(
            f"receiver_params must be a ReceiverParams (ir_receiver.default_params), got {type(receiver_params).__name__}"
        )
    ir_receiver.validate_params(receiver_params)
    if is_concrete(layout):  # inside a trace (a batch of runs over layouts) only the shapes can be checked
        ir.validate_layout(layout)
    else:
        check_shape("layout.positions", layout.positions, (None, 2))
    if not isinstance(odometry_error, OdometryError):
        raise ValueError(f"odometry_error must be an OdometryError, got {type(odometry_error).__name__}")
    check_shape("odometry_error.sd", odometry_error.sd, (3,))
    check_shape("odometry_error.scale", odometry_error.scale, (3,))
    check_nonnegative("odometry_error.sd", odometry_error.sd)
    check_finite("odometry_error.scale", odometry_error.scale)
    oe = OdometryError(jnp.asarray(odometry_error.sd, jnp.float32), jnp.asarray(odometry_error.scale, jnp.float32))
    return _simulate(key, layout, p, jnp.asarray(dt, jnp.float32), receiver_params, oe, config)


@jax.jit
def _dead_reckoning(initial_pose, controls):
    def body(pose, u):
        new = omni_body_mean(pose, u)
        return new, new

    return jax.lax.scan(body, initial_pose, controls)[1]


def dead_reckoning(initial_pose: Any, controls: Any) -> jax.Array:
    """Odometry-only estimate ``[T, 3]``: ``omni_body`` controls integrated from ``initial_pose``.

    The "odometry" row of [W] Table 5.2 (no emitters; the start pose known,
    as [W]'s robot started at a known point).
    """
    x0 = jnp.asarray(initial_pose, jnp.float32)
    u = jnp.asarray(controls, jnp.float32)
    check_shape("initial_pose", x0, (3,))
    check_shape("controls", u, (None, 4))
    check_finite("initial_pose", x0)
    check_finite("controls", u)
    return _dead_reckoning(x0, u)
