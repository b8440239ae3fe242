"""[W] ch. 5 reproduced: the IR emitter positioning experiments of §5.4 as registered experiments.

Five experiments of [W] (:mod:`jaxnav.experiments.registry`), each a table of rows
with the mean over ``R`` seeded runs, its 95 % interval and [W]'s value where
[W] prints one:

* ``table-5.2`` ([W] §5.4.2): errors at 70 marked spots with the proposed
  layout (3 unique + 8 repeated IDs), with 11 unique IDs, and with odometry
  alone; average and maximum over the spots.
* ``table-5.3`` ([W] §5.4.5): the proposed layout at the 70 spots with the
  emitter–receiver height from 1.10 to 1.30 m while the filter keeps eq. 5.3
  calibrated at 1.2 m.
* ``ir-failure`` ([W] §5.4.5, Fig. 5.16): three laps of the predetermined
  trajectory with both emitters of one repeated ID switched off (the filter
  is not told), against all emitters on.
* ``ir-speeds`` ([W] §5.4.4, Fig. 5.15): three laps at 100–300 mm/s.
* ``ir-rotation`` ([W] §5.4.3, Fig. 5.14): the trajectory with five turns
  on the spot, from an unknown start, against odometry.

and one of ours: ``ir-installation``, the 70 spots with the emitters
installed off their map positions (sd 0–30 mm), the error source [W]
§5.4.2 names and our other experiments leave out.

One run
-------
:func:`run_once` simulates a drive (:func:`jaxnav.sim.ir_world.simulate`:
the physical receiver and its FFT decoder at every 0.1 s step, odometry with
:data:`~jaxnav.sim.ir_world.DEFAULT_ODOMETRY_ERROR`), filters it with IR MCL
([W] Alg. 3, :mod:`jaxnav.localization.ir_mcl`, 1,000 particles, uniform
start over the emitters' area) or integrates the odometry from the true start
(the "odometry" row), and scores it (:func:`score`).

Scoring. A drive's steps are grouped into *records*: at the marked spots a
record is a 5 s stay ("the robot stays 5 seconds at the marked spot when
passing by to record the estimated position and orientation", [W] §5.4.2),
scored by the mean estimate over the stay (circular mean for θ) against the
spot; on a trajectory every scored step is a record. A run's errors are the
average and the maximum over its records of ``|x̂ − x|``, ``|ŷ − y|``,
``|θ̂ − θ|`` and ``dr = ‖(x̂, ŷ) − (x, y)‖`` (mm, rad). The result's ``mean``
and ``ci95`` are over the runs' averages; its ``max`` is the mean over runs of
each run's maximum ([W]'s maximum is that of its single run).

What is ours, not [W]'s (it gives no coordinates): the 70 spots
(:func:`jaxnav.sim.ir_world.spot_grid`, a 14 × 5 grid 0.2 m apart, visited
row by row after a lead-in pass under the three unique arrays so that the
filter has started), the trajectories (:data:`~jaxnav.sim.ir_world.EXPERIMENT_WAYPOINTS`,
:data:`~jaxnav.sim.ir_world.ROTATION_WAYPOINTS`), the odometry error, the
failed ID (the first repeated ID, code 1), and which laps count (laps 2–3 of
three: the first includes the start from an unknown pose).

Batching: the runs of a chunk are evaluated one after the other inside one
compiled ``lax.map`` (``Experiment.batching = "map"``): the filter's start is
a ``lax.cond`` whose 16,000-candidate re-draw a ``vmap`` would compute at
every step (measured 2.25 s against 0.38 s per 600-step run). Cells that
differ only in arrays (height, layout, path, speed) share one compilation.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core.validation import check_choice, check_nonnegative, check_positive, check_positive_int
from jaxnav.core.weights import wrap_angle
from jaxnav.experiments import sweep as sw
from jaxnav.experiments.registry import Cell, Experiment, register
from jaxnav.localization import ir_mcl
from jaxnav.models import ir
from jaxnav.sim import ir_receiver, ir_world

__all__ = [
    "IRSetting",
    "DriveInputs",
    "IRErrors",
    "IRRow",
    "LAYOUTS",
    "ALGORITHMS",
    "DRIVES",
    "HEIGHTS",
    "SPEEDS",
    "QUICK",
    "drive_inputs",
    "installed_layout",
    "run_once",
    "Drive",
    "drive_once",
    "format_errors",
    "plot_drive",
    "score",
    "ir_experiment",
]

LAYOUTS = ("proposed", "unique-11")
"""The emitter configurations of [W] §5.4.1: 3 unique + 8 repeated IDs, and 11 unique IDs."""
ALGORITHMS = ("mcl", "odometry")
DRIVES = ("spots", "loop", "rotation")
HEIGHTS = (1.10, 1.12, 1.14, 1.16, 1.18, 1.20, 1.22, 1.24, 1.26, 1.28, 1.30)
"""[W] Table 5.3's emitter–receiver heights (m)."""
SPEEDS = (0.10, 0.15, 0.20, 0.25, 0.30)
"""[W] §5.4.4's speeds (m/s; 0.20 is that of §5.4.1)."""
FAILED_CODE = 1
"""The repeated ID whose two emitters fail in ``ir-failure`` (ours: [W] Fig. 5.16 does not name it)."""
LEAD_IN = ((0.3, 0.8), (2.9, 0.8))
"""The spot tour's lead-in (m): from [W]'s start, (300, 800) mm, east under the three unique arrays."""
ROTATION_SCORED_FROM = 10.0
"""``ir-rotation`` scores the steps from 10 s on, after the robot has passed its second emitter
(the heading is unobservable until then: :mod:`jaxnav.localization.ir_mcl`, "Heading")."""


@dataclass(frozen=True)
class IRSetting:
    """One simulated IR experiment (hashable).

    Attributes:
        layout: ``"proposed"`` (:func:`jaxnav.models.ir.experiment_layout`) or
            ``"unique-11"`` (:func:`jaxnav.models.ir.unique11_layout`).
        failed_code: a repeated ID (frequency code 1–9) whose emitters are
            switched off in the simulator (the filter keeps the full map), or 0.
        height: emitter–receiver height of the simulated receiver (m); the
            filter's eq. 5.3 stays the 1.2 m calibration.
        speed: m/s.
        drive: ``"spots"`` (the marked-spot tour), ``"loop"`` (``laps`` of the
            predetermined trajectory) or ``"rotation"``.
        laps: laps of the loop; laps 2 … ``laps`` are scored.
        num_particles: N.
        spots: ``(nx, ny)`` of the spot grid.
        dwell: seconds on each spot.
        num_steps: pad the drive to this many steps (so that cells of
            different lengths share a compilation); ``None``: its own length.
        dt: sample period (s).
        installation_sd: sd (m, per axis) of the emitters' installation
            error: each run draws the simulator's emitter positions around
            the map's, which the filter keeps (0: emitters exactly where the
            map says; [W]'s real ceiling had such errors, §5.4.2).
    """

    layout: str = "proposed"
    failed_code: int = 0
    height: float = 1.2
    speed: float = 0.2
    drive: str = "spots"
    laps: int = 3
    num_particles: int = 1000
    spots: tuple[int, int] = (14, 5)
    dwell: float = 5.0
    num_steps: int | None = None
    dt: float = 0.1
    installation_sd: float = 0.0

    def __post_init__(self) -> None:
        check_choice("layout", self.layout, LAYOUTS)
        check_choice("drive", self.drive, DRIVES)
        if self.failed_code and self.failed_code not in range(1, ir.NUM_CODES + 1):
            raise ValueError(f"failed_code must be a frequency code 1–{ir.NUM_CODES} or 0, got {self.failed_code}")
        check_positive("height", self.height)
        check_positive("speed", self.speed)
        check_positive_int("laps", self.laps)
        check_positive_int("num_particles", self.num_particles)
        check_positive("dwell", self.dwell)
        check_positive("dt", self.dt)
        check_nonnegative("installation_sd", self.installation_sd)


QUICK = dict(spots=(7, 3), dwell=2.0, laps=2)
"""What the quick variants change: 21 spots with 2 s stays, two laps (the second scored); [W]'s 1,000 particles."""


class DriveInputs(NamedTuple):
    """The arrays of one setting, given to every run of a cell (so that settings share a compilation).

    Attributes:
        path: ``[T + 1, 3]`` true poses (m, m, rad).
        record: ``[T]`` int32: the record step ``t`` belongs to (its spot, or
            ``t`` itself on a trajectory), −1 when it is not scored.
        dt: sample period (s).
        sim_layout: the emitters the simulator lights (failed ones removed).
        receiver: :class:`~jaxnav.sim.ir_receiver.ReceiverParams` of the simulator.
        filter: :class:`~jaxnav.localization.ir_mcl.IRMCLParams` (the full layout).
        installation_sd: sd (m) of the emitters' installation error.
    """

    path: jax.Array
    record: jax.Array
    dt: jax.Array
    sim_layout: ir.EmitterLayout
    receiver: ir_receiver.ReceiverParams
    filter: ir_mcl.IRMCLParams
    installation_sd: jax.Array


class IRErrors(NamedTuple):
    """One run's errors over its records: averages and maxima (mm, rad), and what the filter did.

    ``restarts`` counts the filter's re-draws after its start (``restart_when_lost``);
    ``start_s`` is the time of its start (s; 0 for odometry).
    """

    x_mm: jax.Array
    y_mm: jax.Array
    theta_rad: jax.Array
    dr_mm: jax.Array
    x_mm_max: jax.Array
    y_mm_max: jax.Array
    theta_rad_max: jax.Array
    dr_mm_max: jax.Array
    restarts: jax.Array
    start_s: jax.Array


COLUMNS = ("x_mm", "y_mm", "theta_rad", "dr_mm")
COLUMN_HEADS = ("x [mm]", "y [mm]", "θ [rad]", "dr [mm]")


def _layout(name: str) -> ir.EmitterLayout:
    return ir.experiment_layout() if name == "proposed" else ir.unique11_layout()


def _path_and_record(s: IRSetting) -> tuple[np.ndarray, np.ndarray]:
    """``(poses [T + 1, 3], record [T])`` of a setting (host-side)."""
    if s.drive == "spots":
        nx, ny = s.spots
        # rows from the east end, so that the first spot follows the lead-in with no long leg
        grid = ir_world.spot_grid(nx, ny, x=(2.9, 0.3))
        tour = ir_world.spot_tour(
            grid, s.speed, s.dt, s.dwell, lead_in=np.asarray(LEAD_IN), serpentine=nx, num_steps=s.num_steps
        )
        return tour.poses, tour.spot[1:]
    if s.drive == "loop":
        lap = _loop_length() / s.speed / s.dt  # steps per lap
        natural = int(math.ceil(s.laps * lap))
        t_steps = natural if s.num_steps is None else s.num_steps
        if t_steps < natural:
            raise ValueError(f"num_steps={t_steps} is shorter than {s.laps} laps ({natural} steps)")
        poses = ir_world.polyline_path(ir_world.EXPERIMENT_WAYPOINTS, s.speed, s.dt, t_steps)
        t = np.arange(1, t_steps + 1)
        scored = (t >= lap) & (t <= s.laps * lap)
        return poses, np.where(scored, t - 1, -1).astype(np.int32)
    # rotation
    natural = _rotation_steps(s)
    t_steps = natural if s.num_steps is None else s.num_steps
    if t_steps < natural:
        raise ValueError(f"num_steps={t_steps} is shorter than the rotation trajectory ({natural} steps)")
    poses = ir_world.polyline_path(ir_world.ROTATION_WAYPOINTS, s.speed, s.dt, t_steps, closed=False)
    t = np.arange(1, t_steps + 1)
    scored = (t * s.dt >= ROTATION_SCORED_FROM) & (t <= natural)
    return poses, np.where(scored, t - 1, -1).astype(np.int32)


def _loop_length() -> float:
    wp = ir_world.EXPERIMENT_WAYPOINTS
    return float(np.sum(np.linalg.norm(np.diff(np.concatenate([wp, wp[:1]]), axis=0), axis=1)))


def _rotation_steps(s: IRSetting) -> int:
    wp = ir_world.ROTATION_WAYPOINTS
    d_xy = np.linalg.norm(np.diff(wp[:, :2], axis=0), axis=1)
    d_th = np.abs(np.asarray(wrap_angle(np.diff(wp[:, 2]))))
    return int(math.ceil((np.sum(d_xy) / s.speed + np.sum(np.where(d_xy > 0, 0.0, d_th)) / 0.5) / s.dt))


def drive_inputs(s: IRSetting) -> DriveInputs:
    """The arrays of setting ``s`` (host-side, validated)."""
    full = _layout(s.layout)
    sim_layout = full
    if s.failed_code:
        off = np.flatnonzero(np.asarray(full.masks) == ir.to_mask(s.failed_code))
        if off.size == 0:
            raise ValueError(f"no emitter of layout {s.layout!r} carries code {s.failed_code}")
        sim_layout = ir.without_emitters(full, off.tolist())
    poses, record = _path_and_record(s)
    config = ir_mcl.IRMCLConfig(num_particles=s.num_particles)
    return DriveInputs(
        path=jnp.asarray(poses, jnp.float32),
        record=jnp.asarray(record, jnp.int32),
        dt=jnp.asarray(s.dt, jnp.float32),
        sim_layout=sim_layout,
        receiver=ir_receiver.default_params(height=s.height),
        filter=ir_mcl.default_params(config, full),
        installation_sd=jnp.asarray(s.installation_sd, jnp.float32),
    )


def installed_layout(key: jax.Array, inputs: DriveInputs) -> ir.EmitterLayout:
    """The simulator's emitters of one run: the map's positions plus ``N(0, installation_sd²)`` per axis.

    Drawn from ``fold_in(key, 1)`` of the run's key, so that with
    ``installation_sd = 0`` a run is exactly the run without the option.
    """
    lay = inputs.sim_layout
    noise = jax.random.normal(jax.random.fold_in(key, 1), lay.positions.shape, lay.positions.dtype)
    return lay._replace(positions=lay.positions + inputs.installation_sd * noise)


def score(estimate: jax.Array, truth: jax.Array, record: jax.Array) -> tuple[jax.Array, ...]:
    """Average and maximum errors over the records (module docstring, "Scoring").

    Args:
        estimate, truth: ``[T, 3]`` poses (m, m, rad).
        record: ``[T]`` record of each step, −1 for unscored steps.

    Returns:
        ``(mean [4], max [4])`` of ``(|x̂ − x| mm, |ŷ − y| mm, |θ̂ − θ| rad, dr mm)``
        over the records; record ``k``'s pose is the mean of its steps' poses
        (circular for θ).
    """
    t = record.shape[0]
    seg = jnp.where(record >= 0, record, t)  # unscored steps land in an extra segment, dropped

    def mean_pose(p):
        sums = jax.ops.segment_sum(
            jnp.stack([p[:, 0], p[:, 1], jnp.cos(p[:, 2]), jnp.sin(p[:, 2]), jnp.ones_like(p[:, 0])], axis=-1),
            seg,
            num_segments=t + 1,
        )[:t]
        n = jnp.maximum(sums[:, 4], 1.0)
        return sums[:, 0] / n, sums[:, 1] / n, jnp.arctan2(sums[:, 3], sums[:, 2]), sums[:, 4] > 0

    ex, ey, eth, used = mean_pose(estimate)
    tx, ty, tth, _ = mean_pose(truth)
    dx, dy = 1000.0 * jnp.abs(ex - tx), 1000.0 * jnp.abs(ey - ty)
    errs = jnp.stack([dx, dy, jnp.abs(wrap_angle(eth - tth)), jnp.hypot(dx, dy)], axis=-1)  # [t, 4]
    count = jnp.maximum(jnp.sum(used), 1)
    mean = jnp.sum(jnp.where(used[:, None], errs, 0.0), axis=0) / count
    worst = jnp.max(jnp.where(used[:, None], errs, 0.0), axis=0)
    return mean, worst


@functools.cache
def run_once(algorithm: str, num_particles: int):
    """``(key, inputs: DriveInputs) -> IRErrors`` of one seeded run (cached: one function per pair).

    ``algorithm``: ``"mcl"`` ([W] Alg. 3, ``num_particles`` particles, uniform
    start over :func:`jaxnav.sim.ir_world.layout_area` of the experiment
    layout) or ``"odometry"`` (dead reckoning from the true start).
    """
    check_choice("algorithm", algorithm, ALGORITHMS)
    config = ir_mcl.IRMCLConfig(num_particles=int(num_particles))
    area = ir_world.layout_area(ir.experiment_layout())  # unique11_layout has the same positions

    def fn(key: jax.Array, inputs: DriveInputs) -> IRErrors:
        sim, trace = _simulate_and_filter(key, inputs, config if algorithm == "mcl" else None, area)
        if trace is None:
            return _errors(ir_world.dead_reckoning(sim.initial_pose, sim.controls), sim, inputs)
        return _errors(trace.estimate, sim, inputs, trace)

    return fn


def _simulate_and_filter(key, inputs: DriveInputs, config: ir_mcl.IRMCLConfig | None, area):
    """The drive of one run and, with a ``config``, IR MCL's trace on it (keys as :func:`run_once`)."""
    k_sim, k_init, k_run = jax.random.split(key, 3)
    sim = ir_world.simulate(k_sim, installed_layout(key, inputs), inputs.path, inputs.dt, inputs.receiver)
    if config is None:
        return sim, None
    state0 = ir_mcl.init(k_init, config, inputs.filter, area)
    _, trace = ir_mcl.run(k_run, config, inputs.filter, sim.controls, sim.detections, state0)
    return sim, trace


def _errors(estimate, sim, inputs: DriveInputs, trace: ir_mcl.IRMCLInfo | None = None) -> IRErrors:
    mean, worst = score(estimate, sim.true_poses, inputs.record)
    if trace is None:
        restarts, start_s = jnp.asarray(0), jnp.asarray(0.0)
    else:
        restarts = jnp.maximum(jnp.sum(trace.reinitialised) - 1, 0)
        start_s = (jnp.argmax(trace.started) + 1) * inputs.dt
    return IRErrors(*mean, *worst, restarts.astype(jnp.int32), jnp.asarray(start_s, jnp.float32))


class Drive(NamedTuple):
    """One drive with its traces (:func:`drive_once`): what a figure of [W] §5.4 draws.

    Attributes:
        setting: the :class:`IRSetting`.
        inputs: its :class:`DriveInputs`.
        sim: the :class:`~jaxnav.sim.ir_world.IRRun` (truth, odometry, detections).
        trace: the :class:`~jaxnav.localization.ir_mcl.IRMCLInfo` trace of IR MCL.
        odometry: ``[T, 3]`` dead reckoning from the true start.
        mcl: :class:`IRErrors` of the filter; ``dead``: of the odometry.
    """

    setting: IRSetting
    inputs: DriveInputs
    sim: ir_world.IRRun
    trace: ir_mcl.IRMCLInfo
    odometry: jax.Array
    mcl: IRErrors
    dead: IRErrors


def drive_once(key: jax.Array, setting: IRSetting) -> Drive:
    """Simulate one drive of ``setting``, filter it, and score the filter and the odometry.

    The same keys as :func:`run_once` (so its errors are those of that run).
    """
    inputs = drive_inputs(setting)
    config = ir_mcl.IRMCLConfig(num_particles=setting.num_particles)
    sim, trace = _simulate_and_filter(key, inputs, config, ir_world.layout_area(ir.experiment_layout()))
    odometry = ir_world.dead_reckoning(sim.initial_pose, sim.controls)
    return Drive(
        setting,
        inputs,
        sim,
        trace,
        odometry,
        _errors(trace.estimate, sim, inputs, trace),
        _errors(odometry, sim, inputs),
    )


def format_errors(rows: Sequence[tuple[str, IRErrors]]) -> str:
    """A small table of average and maximum errors per row (mm, rad)."""
    head = f"{'':<10}" + "".join(f"{h:>10}" for h in COLUMN_HEADS) + "".join(f"{'max ' + h:>14}" for h in COLUMN_HEADS)
    lines = [head]
    for name, e in rows:
        vals = [float(v) for v in e[:8]]
        lines.append(
            f"{name:<10}"
            + "".join(f"{_fmt(c, v):>10}" for c, v in zip(COLUMNS, vals[:4]))
            + "".join(f"{_fmt(c, v):>14}" for c, v in zip(COLUMNS, vals[4:]))
        )
    return "\n".join(lines)


def plot_drive(drive: Drive, path: str | None = None, ax=None):
    """The emitters, the true path, IR MCL's estimate and the odometry (as [W] Figs. 5.11–5.16).

    Writes a PNG to ``path`` when given; returns the axes.
    """
    import matplotlib.pyplot as plt

    own = ax is None
    if own:
        fig, ax = plt.subplots(figsize=(9, 3.8))
    lay = drive.inputs.filter.layout
    pos = np.asarray(lay.positions)
    unique = np.asarray(ir.popcount(lay.masks)) >= 2
    lit = {tuple(np.round(p, 6)) for p in np.asarray(drive.inputs.sim_layout.positions)}
    dark = np.array([tuple(np.round(p, 6)) not in lit for p in pos])
    ax.scatter(*pos[unique & ~dark].T, marker="s", s=80, c="tab:orange", label="unique-ID array", zorder=3)
    ax.scatter(*pos[~unique & ~dark].T, marker="o", s=60, c="tab:green", label="repeated-ID LED", zorder=3)
    if dark.any():
        ax.scatter(*pos[dark].T, marker="x", s=80, c="k", label="failed emitter", zorder=3)
    for p, name in zip(pos, ir.layout_names(lay)):
        ax.annotate(name, p, textcoords="offset points", xytext=(6, 6), fontsize=7)
    truth = np.asarray(drive.sim.true_poses)
    est = np.asarray(drive.trace.estimate)
    started = np.asarray(drive.trace.started)
    ax.plot(truth[:, 0], truth[:, 1], "k-", lw=1.0, label="true path")
    ax.plot(
        np.where(started, est[:, 0], np.nan),
        np.where(started, est[:, 1], np.nan),
        "-",
        c="tab:blue",
        lw=0.8,
        label=f"IR MCL (dr {float(drive.mcl.dr_mm):.0f} mm)",
    )
    odo = np.asarray(drive.odometry)
    ax.plot(odo[:, 0], odo[:, 1], "--", c="tab:red", lw=0.8, label=f"odometry (dr {float(drive.dead.dr_mm):.0f} mm)")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    s = drive.setting
    ax.set_title(f"{s.drive}, {s.layout} layout, height {s.height:g} m, {1000 * s.speed:.0f} mm/s", fontsize=9)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    if own:
        fig.tight_layout()
        if path is not None:
            fig.savefig(path, dpi=110)
            plt.close(fig)
    return ax


# ---------------------------------------------------------------------------
# experiments


@dataclass(frozen=True)
class IRRow:
    """One result row: ``name`` (the JSON ``method``), the algorithm, the setting and [W]'s values.

    ``paper`` and ``paper_max``: [W]'s average and maximum of x, y, θ, dr
    (mm, rad), or ``None`` where [W] prints none.
    """

    name: str
    algorithm: str
    setting: IRSetting
    paper: tuple | None = None
    paper_max: tuple | None = None
    label: str | None = None

    @property
    def row(self) -> str:
        return self.label or self.name


def _setting_json(s: IRSetting) -> dict:
    return {
        "layout": s.layout,
        "failed_code": s.failed_code,
        "height_m": s.height,
        "speed_mm_s": round(1000 * s.speed, 3),
        "drive": s.drive,
        "num_particles": s.num_particles,
        "installation_mm": round(1000 * s.installation_sd, 3),
    }


def _quick(s: IRSetting, num_steps: int | None) -> IRSetting:
    return replace(s, **QUICK, num_steps=num_steps)


def _padded(rows: Sequence[IRRow], quick: bool) -> list[IRSetting]:
    """The rows' settings (quick or not) padded to the longest drive of each kind: one compilation per kind."""
    settings = [_quick(r.setting, None) if quick else r.setting for r in rows]
    longest: dict[str, int] = {}
    for s in settings:
        longest[s.drive] = max(longest.get(s.drive, 0), len(_path_and_record(s)[1]))
    return [replace(s, num_steps=longest[s.drive]) for s in settings]


def summarize_errors(values: dict, paper: tuple | None, paper_max: tuple | None) -> dict:
    """Per column: ``{"mean", "ci95": [lo, hi], "median", "max", "max_ci95", "paper", "paper_max"}``.

    ``mean``, ``ci95`` and ``median`` are over the runs' averages (the median shows a run
    that lost the robot for what it is: one run, not a shift of all); ``max`` is the
    mean over runs of each run's maximum.
    """
    out = {}
    for i, col in enumerate(COLUMNS):
        m, lo, hi = sw.mean_ci(values[col])
        mm, mlo, mhi = sw.mean_ci(values[col + "_max"])
        out[col] = {
            "mean": m,
            "ci95": [lo, hi],
            "median": float(np.median(values[col])),
            "max": mm,
            "max_ci95": [mlo, mhi],
            "paper": None if paper is None else paper[i],
            "paper_max": None if paper_max is None else paper_max[i],
        }
    return out


def ir_experiment(
    name: str,
    title: str,
    rows: Sequence[IRRow],
    notes: str = "",
    row_key: str | None = None,
    quick_rows: Sequence[int] | None = None,
) -> Experiment:
    """Build and register an IR experiment from its rows.

    ``row_key``: an extra JSON field per row (``"height_m"``, ``"speed_mm_s"``);
    ``quick_rows``: the indices of the rows the quick variant runs (default all).
    """
    rows = tuple(rows)
    by_label = {r.row: r for r in rows}
    if len(by_label) != len(rows):
        raise ValueError(f"row labels must be unique in {name}")
    quick_subset = rows if quick_rows is None else tuple(rows[i] for i in quick_rows)

    def cells(quick: bool) -> list[Cell]:
        out = []
        chosen = quick_subset if quick else rows
        for row, s in zip(chosen, _padded(chosen, quick)):
            fn = run_once(row.algorithm, s.num_particles)
            out.append(Cell(f"{row.row}|{row.algorithm}", row.row, row.algorithm, s, fn, (drive_inputs(s),)))
        return out

    def summarize(raw: dict, cell_list: list[Cell], quick: bool) -> dict:
        out_rows = []
        for cell in cell_list:
            row, vals = by_label[cell.row], raw[cell.id]
            entry = {
                "row": row.row,
                "method": row.name,
                "algorithm": row.algorithm,
                "setting": _setting_json(cell.setting),
            }
            if row_key == "height_m":
                entry["height_m"] = row.setting.height
            if row_key == "speed_mm_s":
                entry["speed_mm_s"] = round(1000 * row.setting.speed, 3)
            if row_key == "installation_mm":
                entry["installation_mm"] = round(1000 * row.setting.installation_sd, 3)
            entry.update(summarize_errors(vals, row.paper, row.paper_max))
            entry["restarts"] = float(np.mean(vals["restarts"]))
            entry["start_s"] = float(np.mean(vals["start_s"]))
            out_rows.append(entry)
        return {"rows": out_rows, "notes": notes}

    return register(
        Experiment(name, title, cells, summarize, render_table, markdown_table, plot_table, notes, batching="map")
    )


def _fmt(col: str, v: float | None) -> str:
    if v is None or not np.isfinite(v):
        return "–"
    return f"{v:.3f}" if col.startswith("theta") else f"{v:.0f}"


def render_table(result: dict) -> str:
    """Terminal table: per row, ours (mean ± half-interval, mean maximum) and [W]'s average / maximum."""
    lines = [
        f"{result['experiment']}: {result['title']}  ({result['runs']} runs per row"
        f"{', quick variant' if result.get('quick') else ''}; average over records: mean ± 95 % half-interval "
        "over runs; max: mean over runs of the run's maximum)"
    ]
    head = (
        f"{'row':<16}{'':<5}"
        + "".join(f"{h:>18}" for h in COLUMN_HEADS)
        + "".join(f"{'max ' + h:>14}" for h in COLUMN_HEADS)
        + f"{'median dr':>12}"
    )
    lines += [head, "-" * len(head)]
    for r in result["rows"]:
        ours = "".join(
            f"{_fmt(c, r[c]['mean']) + ' ± ' + _fmt(c, (r[c]['ci95'][1] - r[c]['ci95'][0]) / 2):>18}" for c in COLUMNS
        )
        ours += "".join(f"{_fmt(c, r[c]['max']):>14}" for c in COLUMNS)
        ours += f"{_fmt('dr_mm', r['dr_mm'].get('median')):>12}"
        lines.append(f"{r['row']:<16}{'ours':<5}{ours}")
        if any(r[c]["paper"] is not None for c in COLUMNS):
            paper = "".join(f"{_fmt(c, r[c]['paper']):>18}" for c in COLUMNS)
            paper += "".join(f"{_fmt(c, r[c]['paper_max']):>14}" for c in COLUMNS)
            lines.append(f"{'':<16}{'[W]':<5}{paper}")
    if result.get("notes"):
        lines.append(result["notes"])
    return "\n".join(lines)


def markdown_table(result: dict) -> str:
    """Markdown: per column ``mean [lo, hi] ([W])`` for the average and ``max ([W])`` for the maximum."""
    head = (
        "| row | "
        + " | ".join(COLUMN_HEADS)
        + " | "
        + " | ".join("max " + h for h in COLUMN_HEADS)
        + " | median dr [mm] |"
    )
    lines = [
        f"**{result['experiment']}** — {result['title']} ({result['runs']} runs per row; average: mean "
        "[95 % interval] (thesis); max: mean over runs of each run's maximum (thesis); median over runs of "
        "the average dr)",
        "",
        head,
        "|" + " --- |" * (2 + 2 * len(COLUMNS)),
    ]
    for r in result["rows"]:
        avg = [
            f"{_fmt(c, r[c]['mean'])} [{_fmt(c, r[c]['ci95'][0])}, {_fmt(c, r[c]['ci95'][1])}] "
            f"({_fmt(c, r[c]['paper'])})"
            for c in COLUMNS
        ]
        mx = [f"{_fmt(c, r[c]['max'])} ({_fmt(c, r[c]['paper_max'])})" for c in COLUMNS]
        lines.append(
            f"| {r['row']} | "
            + " | ".join(avg)
            + " | "
            + " | ".join(mx)
            + f" | {_fmt('dr_mm', r['dr_mm'].get('median'))} |"
        )
    if result.get("notes"):
        lines += ["", result["notes"]]
    return "\n".join(lines)


def plot_table(result: dict, path: str) -> None:
    """dr per row: average (bar, 95 % interval) and mean maximum (dot), [W]'s as red marks."""
    import matplotlib.pyplot as plt

    rows = result["rows"]
    x = np.arange(len(rows))
    fig, ax = plt.subplots(figsize=(max(6.0, 0.9 * len(rows) + 3), 4.2))
    means = np.array([r["dr_mm"]["mean"] for r in rows])
    lo = np.array([r["dr_mm"]["ci95"][0] for r in rows])
    hi = np.array([r["dr_mm"]["ci95"][1] for r in rows])
    ax.bar(x, means, color="tab:blue", alpha=0.7, label=f"ours: average ({result['runs']} runs, 95 % CI)")
    ax.errorbar(x, means, yerr=[means - lo, hi - means], fmt="none", color="k", capsize=3)
    ax.plot(x, [r["dr_mm"]["max"] for r in rows], "o", color="tab:blue", label="ours: maximum (mean over runs)")
    for key, style, label in (("paper", "r_", "[W] average"), ("paper_max", "rx", "[W] maximum")):
        px = [i for i, r in enumerate(rows) if r["dr_mm"][key] is not None]
        if px:
            ax.plot(px, [rows[i]["dr_mm"][key] for i in px], style, ms=18 if style == "r_" else 8, mew=3, label=label)
    ax.set_xticks(x)
    ax.set_xticklabels([r["row"] for r in rows], fontsize=8, rotation=30 if len(rows) > 6 else 0)
    ax.set_ylabel("robot position error dr (mm)")
    ax.legend(fontsize=8)
    ax.set_title(f"{result['experiment']}: {result['title']}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ---------------------------------------------------------------------------
# the five experiments of [W] §5.4

_SPOTS = IRSetting()
_LOOP = IRSetting(drive="loop")

ir_experiment(
    "table-5.2",
    "IR positioning at 70 marked spots: proposed layout, 11 unique IDs, odometry ([W] Table 5.2)",
    [
        IRRow("proposed", "mcl", _SPOTS, (22, 29, 0.06, 36), (69, 79, 0.23, 105)),
        IRRow("unique-11", "mcl", replace(_SPOTS, layout="unique-11"), (30, 25, 0.04, 39), (87, 91, 0.10, 126)),
        IRRow("odometry", "odometry", _SPOTS, (94, 55, 0.03, 108), (161, 99, 0.08, 189)),
    ],
)

_T53 = {  # [W] Table 5.3: height -> (average x, y, θ, dr), (maximum x, y, θ, dr)
    1.10: ((54, 60, 0.20, 80), (129, 216, 0.22, 251)),
    1.12: ((74, 42, 0.12, 85), (141, 96, 0.16, 171)),
    1.14: ((38, 30, 0.10, 49), (103, 76, 0.16, 128)),
    1.16: ((29, 38, 0.11, 47), (56, 88, 0.15, 105)),
    1.18: ((25, 26, 0.04, 36), (45, 38, 0.08, 59)),
    1.20: ((22, 29, 0.07, 36), (69, 79, 0.23, 105)),
    1.22: ((26, 28, 0.05, 39), (53, 47, 0.07, 70)),
    1.24: ((36, 30, 0.01, 47), (63, 74, 0.02, 97)),
    1.26: ((22, 36, 0.06, 42), (50, 72, 0.08, 88)),
    1.28: ((87, 21, 0.04, 90), (122, 39, 0.05, 128)),
    1.30: ((56, 51, 0.07, 76), (98, 77, 0.11, 124)),
}

ir_experiment(
    "table-5.3",
    "IR positioning at the 70 spots against the emitter-receiver height, eq. 5.3 calibrated at 1.2 m ([W] Table 5.3)",
    [IRRow("proposed", "mcl", replace(_SPOTS, height=h), *_T53[h], label=f"{h:.2f} m") for h in HEIGHTS],
    row_key="height_m",
    quick_rows=(0, 5, 10),
)

ir_experiment(
    "ir-failure",
    "IR positioning with both emitters of one repeated ID failed, three laps ([W] §5.4.5, Fig. 5.16)",
    [
        IRRow("proposed", "mcl", _LOOP, label="all emitters"),
        IRRow("failed-2", "mcl", replace(_LOOP, failed_code=FAILED_CODE), label="2 failed"),
    ],
    notes=f"The two emitters of repeated ID {FAILED_CODE} are dark in the simulator; the filter's map still has "
    "them. Laps 2-3 of three are scored. [W] shows the path only.",
)

ir_experiment(
    "ir-speeds",
    "IR positioning at 100-300 mm/s, three laps ([W] §5.4.4, Fig. 5.15)",
    [IRRow("proposed", "mcl", replace(_LOOP, speed=v), label=f"{1000 * v:.0f} mm/s") for v in SPEEDS],
    notes="Laps 2-3 of three are scored. [W] shows the paths only and says speed does not change the accuracy.",
    row_key="speed_mm_s",
    quick_rows=(2, 4),
)

ir_experiment(
    "ir-rotation",
    "IR positioning on the trajectory with five turns, unknown start ([W] §5.4.3, Fig. 5.14)",
    [
        IRRow("proposed", "mcl", IRSetting(drive="rotation")),
        IRRow("odometry", "odometry", IRSetting(drive="rotation")),
    ],
    notes=f"Steps from {ROTATION_SCORED_FROM:g} s on are scored (after the second emitter). [W] shows the path only.",
)

INSTALLATION_SDS = (0.0, 0.01, 0.02, 0.03)
"""``ir-installation``: sd of the emitters' installation error (m)."""

ir_experiment(
    "ir-installation",
    "IR positioning at the 70 spots with emitters installed off their map positions (ours, not in [W])",
    [
        IRRow("proposed", "mcl", replace(_SPOTS, installation_sd=sd), label=f"{1000 * sd:.0f} mm")
        for sd in INSTALLATION_SDS
    ],
    notes="Each run draws every emitter's true position around its map position with the given sd per axis; the filter "
    "keeps the map. [W] §5.4.2 names installation errors as a source of its 36 mm; our other experiments have none.",
    row_key="installation_mm",
    quick_rows=(0, 3),
)
