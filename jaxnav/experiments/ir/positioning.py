"""[W] ch. 5: IR emitter positioning, one simulated drive: simulate, filter, score, draw.

The settings, drives and scoring of [W] §5.4's experiments; the experiments
themselves (Tables 5.2, 5.3 and the drives of §5.4.3–5.4.5) are in
:mod:`jaxnav.experiments.ir.tables`.

**One run**

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
``|θ̂ − θ|`` and ``dr = ‖(x̂, ŷ) − (x, y)‖`` (mm, rad). A run with no scored
record has nothing to score: its errors are NaN, not 0. ``start_s``, the
time the filter started (its first unique ID), is NaN for a filter that
never started.

What is ours, not [W]'s (it gives no coordinates): the 70 spots
(:func:`jaxnav.sim.ir_world.spot_grid`, a 14 × 5 grid 0.2 m apart, visited
row by row after a lead-in pass under the three unique arrays so that the
filter has started), the trajectories (:data:`~jaxnav.sim.ir_world.EXPERIMENT_WAYPOINTS`,
:data:`~jaxnav.sim.ir_world.ROTATION_WAYPOINTS`), the odometry error, the
failed ID (the first repeated ID, code 1), and which laps count (laps 2–3 of
three: the first includes the start from an unknown pose).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import rng
from jaxnav.core.filter import check_key
from jaxnav.core.validation import check_choice, check_nonnegative, check_positive, check_positive_int
from jaxnav.core.weights import wrap_angle
from jaxnav.experiments import report
from jaxnav.localization import ir_mcl
from jaxnav.models import ir
from jaxnav.sim import ir_receiver, ir_world

__all__ = [
    "IRSetting",
    "DriveInputs",
    "IRErrors",
    "COLUMNS",
    "COLUMN_HEADS",
    "LAYOUTS",
    "ALGORITHMS",
    "DRIVES",
    "HEIGHTS",
    "SPEEDS",
    "FAILED_CODE",
    "ROTATION_SCORED_FROM",
    "QUICK",
    "path_and_record",
    "drive_inputs",
    "installed_layout",
    "run_once",
    "Drive",
    "drive_once",
    "format_errors",
    "describe_start",
    "num_steps",
    "memory_estimate",
    "plot_drive",
    "score",
]

LAYOUTS = ("proposed", "unique-11")
"""The emitter configurations of [W] §5.4.1 — 3 unique + 8 repeated IDs, and 11 unique IDs."""
ALGORITHMS = ("mcl", "odometry")
"""The rows of a run — IR MCL, and the odometry integrated from the true start."""
DRIVES = ("spots", "loop", "rotation")
"""The drives of [W] §5.4 — the marked-spot tour, laps of the predetermined trajectory, the rotation drive."""
HEIGHTS = (1.10, 1.12, 1.14, 1.16, 1.18, 1.20, 1.22, 1.24, 1.26, 1.28, 1.30)
"""[W] Table 5.3's emitter–receiver heights (m)."""
SPEEDS = (0.10, 0.15, 0.20, 0.25, 0.30)
"""[W] §5.4.4's speeds (m/s; 0.20 is that of §5.4.1)."""
FAILED_CODE = 1
"""The repeated ID whose two emitters fail in ``ir-failure`` (ours, as [W] Fig. 5.16 does not name it)."""
LEAD_IN = ((0.3, 0.8), (2.9, 0.8))
"""The spot tour's lead-in (m), from [W]'s start, (300, 800) mm, east under the three unique arrays."""
ROTATION_SCORED_FROM = 10.0
"""``ir-rotation`` scores the steps from 10 s on, after the robot has passed its second emitter
(the heading is unobservable until then: :mod:`jaxnav.localization.ir_mcl`, "Heading")."""


@dataclass(frozen=True)
class IRSetting:
    """One simulated IR experiment (hashable).

    Attributes:
        layout: ``"proposed"`` (:func:`jaxnav.sim.ir_world.experiment_layout`) or
            ``"unique-11"`` (:func:`jaxnav.sim.ir_world.unique11_layout`).
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
"""What the quick variants change — 21 spots with 2 s stays, two laps (the second scored); [W]'s 1,000 particles."""


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
    ``start_s`` is the time of its start (s; 0 for odometry, NaN for a filter that never
    started). The errors are NaN when the drive has no scored record.
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
    return ir_world.experiment_layout() if name == "proposed" else ir_world.unique11_layout()


def path_and_record(s: IRSetting) -> tuple[np.ndarray, np.ndarray]:
    """``(poses [T + 1, 3], record [T])`` of a setting (host-side): the true path and the record of each
    step (:class:`DriveInputs`)."""
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


def num_steps(s: IRSetting) -> int:
    """About how many steps the drive of ``s`` has, from its sizes alone (no path is built).

    Exact for the loop and the rotation; for the spot tour, the stays plus the legs driven
    through the spots in grid order (an estimate). With ``s.num_steps`` the drive is padded to it.
    """
    if s.drive == "loop":
        natural = int(math.ceil(s.laps * (_loop_length() / s.speed / s.dt)))  # as path_and_record
    elif s.drive == "rotation":
        natural = _rotation_steps(s)
    else:
        nx, ny = s.spots
        points = np.concatenate([np.asarray(LEAD_IN), ir_world.spot_grid(nx, ny, x=(2.9, 0.3))])
        length = float(np.sum(np.linalg.norm(np.diff(points, axis=0), axis=1)))
        natural = int(math.ceil(length / s.speed / s.dt + nx * ny * (s.dwell / s.dt + 1) + len(points)))
    return natural if s.num_steps is None else max(natural, s.num_steps)


def memory_estimate(s: IRSetting) -> int:
    """Bytes one drive of ``s`` holds at once, estimated from its sizes: about 200 bytes a step for the
    simulated drive and the filter's trace, and 64 numbers a particle for one step's arrays, doubled
    for XLA's temporaries. A rough figure (within a few times), to refuse sizes that cannot fit."""
    return 2 * (256 * num_steps(s) + 4 * 64 * s.num_particles)


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
    poses, record = path_and_record(s)
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
    noise = rng.normal(jax.random.fold_in(key, 1), lay.positions.shape, lay.positions.dtype)
    return lay._replace(positions=lay.positions + inputs.installation_sd * noise)


def score(estimate: jax.Array, truth: jax.Array, record: jax.Array) -> tuple[jax.Array, ...]:
    """Average and maximum errors over the records (module docstring, "Scoring").

    Args:
        estimate, truth: ``[T, 3]`` poses (m, m, rad).
        record: ``[T]`` record of each step, −1 for unscored steps.

    Returns:
        ``(mean [4], max [4])`` of ``(|x̂ − x| mm, |ŷ − y| mm, |θ̂ − θ| rad, dr mm)``
        over the records; record ``k``'s pose is the mean of its steps' poses
        (circular for θ). Both are NaN when no step is scored.
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
    scored = jnp.sum(used)
    count = jnp.maximum(scored, 1)
    mean = jnp.sum(jnp.where(used[:, None], errs, 0.0), axis=0) / count
    worst = jnp.max(jnp.where(used[:, None], errs, 0.0), axis=0)
    nothing = scored == 0  # no record: nothing to score, NaN rather than 0
    return jnp.where(nothing, jnp.nan, mean), jnp.where(nothing, jnp.nan, worst)


@functools.cache
def run_once(algorithm: str, num_particles: int) -> Callable[..., IRErrors]:
    """``(key, inputs: DriveInputs) -> IRErrors`` of one seeded run (cached: one function per pair).

    ``algorithm``: ``"mcl"`` ([W] Alg. 3, ``num_particles`` particles, uniform
    start over :func:`jaxnav.sim.ir_world.layout_area` of the experiment
    layout) or ``"odometry"`` (dead reckoning from the true start).
    """
    check_choice("algorithm", algorithm, ALGORITHMS)
    config = ir_mcl.IRMCLConfig(num_particles=int(num_particles))
    area = ir_world.layout_area(ir_world.experiment_layout())  # unique11_layout has the same positions

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
    _, trace = ir_mcl.run(k_run, state0, config, inputs.filter, sim.controls, sim.detections)
    return sim, trace


def _errors(estimate, sim, inputs: DriveInputs, trace: ir_mcl.IRMCLInfo | None = None) -> IRErrors:
    mean, worst = score(estimate, sim.true_poses, inputs.record)
    if trace is None:
        restarts, start_s = jnp.asarray(0), jnp.asarray(0.0)
    else:
        restarts = jnp.maximum(jnp.sum(trace.reinitialised) - 1, 0)
        # the step the filter started at; NaN when it never started (no unique ID seen)
        start_s = jnp.where(jnp.any(trace.started), (jnp.argmax(trace.started) + 1) * inputs.dt, jnp.nan)
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

    The same keys as :func:`run_once` (so its errors are those of that run). The simulation, the
    filter and the scores are one compiled program per particle count, which a drive of another
    setting reuses when its inputs have the same shapes (as many steps and emitters).
    """
    check_key(key)
    inputs = drive_inputs(setting)
    sim, trace, odometry, mcl, dead = _drive_program(setting.num_particles)(key, inputs)
    return Drive(setting, inputs, sim, trace, odometry, mcl, dead)


@functools.lru_cache(maxsize=16)
def _drive_program(num_particles: int) -> Callable[[jax.Array, DriveInputs], tuple]:
    """``jit((key, inputs) -> (sim, trace, odometry, mcl errors, odometry errors))`` of :func:`drive_once`.

    Run op by op instead, the simulation's many small operations each cost a dispatch (and, the
    first time, a compilation of their own): the whole ``jaxnav ir`` command with its default drive
    takes 11.3 s compiled against 13.7 s op by op (medians of four, 2 CPU cores)."""
    config = ir_mcl.IRMCLConfig(num_particles=num_particles)
    area = ir_world.layout_area(ir_world.experiment_layout())

    @jax.jit
    def drive(key: jax.Array, inputs: DriveInputs) -> tuple:
        sim, trace = _simulate_and_filter(key, inputs, config, area)
        odometry = ir_world.dead_reckoning(sim.initial_pose, sim.controls)
        return sim, trace, odometry, _errors(trace.estimate, sim, inputs, trace), _errors(odometry, sim, inputs)

    return drive


def format_errors(rows: Sequence[tuple[str, IRErrors]]) -> str:
    """A small table of average and maximum errors per row (mm, rad).

    A filter that never started (``start_s`` NaN) has only the meaningless mean of its
    uniform cloud: its cells read ``n/a`` (:func:`describe_start` says why).
    """
    columns = [report.Column("", 10, "<")] + [report.Column(h, 10) for h in COLUMN_HEADS]
    columns += [report.Column("max " + h, 14) for h in COLUMN_HEADS]
    cells = []
    for name, e in rows:
        never = not math.isfinite(float(e.start_s))
        cells.append(
            [name]
            + [report.NA if never else report.number(float(v), _digits(c)) for c, v in zip(COLUMNS + COLUMNS, e[:8])]
        )
    return report.text(columns, cells, rule=False)


def describe_start(e: IRErrors) -> str:
    """When the filter started and how often it re-drew its particles after that, in words."""
    if not math.isfinite(float(e.start_s)):
        return "localization never started (no unique ID was decoded)"
    return f"localization started at {float(e.start_s):.1f} s, {int(e.restarts)} re-draws after it"


def _digits(col: str) -> int:
    return 3 if col.startswith("theta") else 0


def plot_drive(drive: Drive, path: str | None = None, ax: Any = None) -> Any:
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
        ax.annotate(name, p, textcoords="offset points", xytext=(6, 6), fontsize=8)
    truth = np.asarray(drive.sim.true_poses)
    est = np.asarray(drive.trace.estimate)
    started = np.asarray(drive.trace.started)
    # the true path on top, thinner than the estimate, so that both stay visible where they overlap
    ax.plot(
        np.where(started, est[:, 0], np.nan),
        np.where(started, est[:, 1], np.nan),
        "-",
        c="tab:blue",
        lw=1.6,
        alpha=0.8,
        label=f"IR MCL estimate (mean error {float(drive.mcl.dr_mm):.0f} mm)",
    )
    odo = np.asarray(drive.odometry)
    ax.plot(
        odo[:, 0], odo[:, 1], "--", c="tab:red", lw=0.8, label=f"odometry (mean error {float(drive.dead.dr_mm):.0f} mm)"
    )
    ax.plot(truth[:, 0], truth[:, 1], "k-", lw=0.8, zorder=4, label="true path")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    s = drive.setting
    ax.set_title(f"{s.drive}, {s.layout} layout, height {s.height:g} m, {1000 * s.speed:.0f} mm/s", fontsize=9)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0), title="numbers: emitter IDs", title_fontsize=7)
    if own:
        fig.tight_layout()
        if path is not None:
            fig.savefig(path, dpi=110, bbox_inches="tight")  # the legend sits outside the axes, to the right
            plt.close(fig)
    return ax
