"""UTIAS MRCLAM Dataset 7: a loader, and its discretisation into filter steps.

**Overview**

The UTIAS Multi-Robot Cooperative Localization and Mapping dataset (Leung,
Halpern, Barfoot & Liu, IJRR 30(8):969–974, 2011, doi:10.1177/0278364911398404;
cite it in anything that reports results on it) is real indoor data: iRobot
Create robots driving among 15 barcode landmarks for 900 s, with

* odometry ``(t, v [m/s], ω [rad/s])`` at about 100 Hz (irregular, with gaps
  of up to 1 s),
* camera detections ``(t, barcode, range [m], bearing [rad])``,
* Vicon ground truth ``(t, x, y, θ)`` at about 60 Hz, and the surveyed
  landmark map.

This module reads the text files unchanged from a data folder outside the
repository (:func:`data_dir`) and offers two layers:

1. :func:`load_robot` — the raw streams as float64 NumPy arrays, barcodes
   mapped to subjects with ``Barcodes.dat`` (subjects 1–5 are robots, 6–20
   landmarks; a barcode not in that file gets subject ``-1`` and is counted).
   Parsed files are cached in memory per process (read-only arrays), never on
   disk.
2. :func:`to_filter_steps` — a :class:`MRCLAMSequence` that the jaxnav filters
   take as they take a :class:`~jaxnav.sim.landmark_world.SimulatedRun`:
   velocity-model controls ``[T, 3]``, fixed-slot
   :class:`~jaxnav.models.landmarks.RangeBearingObs`, and the ground-truth
   pose at every step.

**Discretisation (the choices, stated once)**

*Clock.* A fixed grid: step ``i = 0 … T−1`` ends at ``times[i] = t₀ + (i+1)·Δt``
with ``t₀`` the start time (default: the robot's first odometry reading) and
``Δt = 0.02 s`` by default (50 Hz: the default of the dataset authors' own
``sampleMRCLAMdataSet.m``, which also rounds measurements to the nearest
time step; it interpolates the odometry where this module integrates it). The filter holds ``initial_pose`` (ground truth at ``t₀``)
before step 0 and the pose at ``times[i]`` after step ``i``. A fixed grid, not
the odometry clock, because the odometry is irregular (periods 0–1 s): on the
grid ``T`` is known in advance and the alignment error below has one bound.

*Controls.* Each odometry reading is held until the next one (zero-order hold,
the convention of the dataset's own dead-reckoning check, which this
reproduces). Step ``i``'s control is the velocity-model control
``u = (s/Δt, Θ/Δt, Δt)`` (:mod:`jaxnav.models.motion` ``velocity``, Thrun et
al. Tab. 5.3) with ``s = ∫v dt`` and ``Θ = ∫ω dt`` over ``(times[i−1],
times[i]]``, integrated exactly. The heading change of every step is exact; the
position change replaces the piecewise arcs inside one step by a single arc,
an error that vanishes unless the reading changes inside the step and is at
most ``v_max·Δt·(ω_max − ω_min)·Δt/4 + (v_max − v_min)·|ω̄|·Δt²`` there
(≈ 30 µm for this data). Against an independent mid-point integration on the
odometry clock, robot 1's dead-reckoned position agrees to 0.12 mm after 60 s
and 0.07 mm after 300 s (float64; tests/io/test_mrclam.py).

*Measurements.* A measurement at time ``t_m`` goes to the step whose end time
is nearest: ``i = ⌊(t_m − t₀)/Δt + ½⌋ − 1`` (ties go to the later step). So it
is scored against the pose the filter holds after that step's motion, and
``|t_m − times[i]| ≤ Δt/2`` (``obs_time_offset`` stores the offset). The pose
it was taken from therefore differs from the held pose by at most
``v_max·Δt/2`` in position and ``|ω|_max·Δt/2`` in heading: with the odometry's
``v ≤ 0.086 m/s`` and ``|ω| ≤ 0.57 rad/s`` and ``Δt = 0.02 s``, 0.9 mm and
5.7 mrad — below the camera's noise (bearing MAD 4–12 mrad). (The Vicon
truth's sample-to-sample slopes, up to 0.31 m/s and 1.0 rad/s, are mostly
its jitter; the tests use them for a looser, data-derived bound.) Measurements
nearest ``t₀`` itself or past the last step are outside the window
(``num_outside_window``).

*Slots.* Each step has ``K = max_obs`` slots ``(ids, z, mask)``; ``ids`` is
the landmark slot ``0 … 14`` (subject ``6 … 20``, the row of ``landmarks``).
Measurements fill slots in time order; those beyond ``K`` are dropped and
counted (``num_dropped_capacity``). Empty slots hold ``id 0``, ``z = 0`` and
``mask False``. Robots and unknown barcodes (natural outliers) are dropped and
counted in ``num_outliers`` by default; with ``keep_outliers=True`` they take
slots with ids outside the map — robot ``n`` gets ``15 + n − 1`` (15–19), an
unknown barcode ``−1`` — so :func:`jaxnav.models.landmarks.lookup` ignores
and counts them in a filter, and a filter that ignores ids (unknown
correspondence) sees them as clutter.

:func:`dead_reckoning` integrates the controls with the velocity model's mean (a
``lax.scan``); the scores (position and heading RMSE) are :mod:`jaxnav.metrics`'.
"""

from __future__ import annotations

import functools
import math
import os
import warnings
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core.validation import check_finite, check_positive_int, check_shape
from jaxnav.io._data import ENV_VAR, find_dataset
from jaxnav.io._files import open_regular, require_regular
from jaxnav.models import landmarks as lm
from jaxnav.models.motion import get_motion_model

__all__ = [
    "DATASET",
    "ENV_VAR",
    "Odometry",
    "Measurements",
    "GroundTruth",
    "LandmarkMap",
    "MRCLAMRobot",
    "MRCLAMSequence",
    "data_dir",
    "available_robots",
    "load_robot",
    "interpolate_ground_truth",
    "to_filter_steps",
    "dead_reckoning",
]

DATASET = "utias-mrclam-dataset7"
"""Name of the dataset folder inside the data folder."""

_SOURCE = "http://asrl.utias.utoronto.ca/datasets/mrclam/ (the MRCLAM_Dataset7 files, unchanged)"

_NOT_REGULAR = "replace it by the dataset's own file (the loader reads regular files only)"
"""What to do about a data file that is a folder, a named pipe or a device (never opened)."""


NUM_ROBOTS = 5  # MRCLAM robots are subjects 1..5


# ---------------------------------------------------------------------------
# containers


class Odometry(NamedTuple):
    """Wheel odometry, ``[N]`` float64 each.

    Attributes:
        t: time stamps (s, Unix epoch, one clock for all files).
        v: forward velocity (m/s).
        omega: angular velocity (rad/s, counter-clockwise positive).
    """

    t: np.ndarray
    v: np.ndarray
    omega: np.ndarray


class Measurements(NamedTuple):
    """Camera detections, ``[N]`` each, sorted by time.

    Attributes:
        t: time stamps (s), float64.
        barcode: barcode read by the camera (the files' second column), int64.
        subject: subject from ``Barcodes.dat`` (1–5 robots, 6–20 landmarks,
            ``-1`` for a barcode not in that file), int64.
        range: range (m), float64.
        bearing: bearing in the robot frame (rad, counter-clockwise positive), float64.
    """

    t: np.ndarray
    barcode: np.ndarray
    subject: np.ndarray
    range: np.ndarray
    bearing: np.ndarray


class GroundTruth(NamedTuple):
    """Vicon robot pose, ``[N]`` float64 each (heading wrapped as in the file).

    Attributes:
        t: time stamps (s). x, y: position (m). theta: heading (rad).
    """

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    theta: np.ndarray


class LandmarkMap(NamedTuple):
    """The surveyed landmarks; row ``j`` is landmark slot ``j``.

    Attributes:
        subjects: ``[15]`` int64 subject numbers 6…20 (slot ``j`` ↔ ``subjects[j]``).
        positions: ``[15, 2]`` float64 ``(x, y)`` (m).
        sd: ``[15, 2]`` float64 survey standard deviations (m).
    """

    subjects: np.ndarray
    positions: np.ndarray
    sd: np.ndarray


class MRCLAMRobot(NamedTuple):
    """One robot's raw streams (:func:`load_robot`). Arrays are read-only (shared cache).

    Attributes:
        robot: robot number (1–5).
        odometry, measurements, ground_truth, landmarks: see their classes.
        num_landmark, num_robot, num_unknown: measurement counts by kind of
            subject (landmarks 6–20, robots 1–5, barcodes not in ``Barcodes.dat``).
    """

    robot: int
    odometry: Odometry
    measurements: Measurements
    ground_truth: GroundTruth
    landmarks: LandmarkMap
    num_landmark: int
    num_robot: int
    num_unknown: int


class MRCLAMSequence(NamedTuple):
    """A robot's data as ``T`` filter steps (:func:`to_filter_steps`; conventions in the module docstring).

    The first three fields have the names and meaning of
    :class:`~jaxnav.sim.landmark_world.SimulatedRun`. "float32" below is the
    default ``dtype`` of :func:`to_filter_steps`.

    Attributes:
        true_poses: ``[T, 3]`` float32 ground-truth pose at ``times`` (m, m, rad;
            θ unwrapped, interpolated, re-wrapped to ``[-π, π)``).
        controls: ``[T, 3]`` float32 velocity-model controls ``(v [m/s], ω [rad/s], Δt [s])``.
        observations: :class:`~jaxnav.models.landmarks.RangeBearingObs`,
            ``ids [T, K]`` int32, ``z [T, K, 2]`` float32, ``mask [T, K]`` bool.
        initial_pose: ``[3]`` float32 ground-truth pose at ``t0``.
        landmarks: ``[15, 2]`` float32 landmark map; row = observation id.
        times: ``[T]`` float64 NumPy, end time of each step (s, Unix epoch).
        obs_time_offset: ``[T, K]`` float32, measurement time minus ``times``
            (s; 0 in empty slots); ``|·| ≤ Δt/2``.
        t0: start time (s, Unix epoch).
        dt: step length Δt (s).
        robot: robot number.
        num_placed: measurements placed in slots.
        num_outliers: robot / unknown-barcode measurements in the window
            (placed with out-of-map ids if ``keep_outliers``, else dropped).
        num_dropped_capacity: measurements dropped because their step had more than ``K``.
        num_outside_window: measurements nearest ``t0`` or after the last step.
    """

    true_poses: jax.Array
    controls: jax.Array
    observations: lm.RangeBearingObs
    initial_pose: jax.Array
    landmarks: jax.Array
    times: np.ndarray
    obs_time_offset: jax.Array
    t0: float
    dt: float
    robot: int
    num_placed: int
    num_outliers: int
    num_dropped_capacity: int
    num_outside_window: int


def data_dir(root: str | os.PathLike | None = None) -> Path:
    """The dataset folder ``<data>/utias-mrclam-dataset7``.

    ``<data>`` is ``root`` if given, else ``$JAXNAV_DATA`` if set, else
    ``../shared/data`` relative to the repository root when jaxnav runs from
    a source checkout (never relative to the current directory). ``root``
    (or ``$JAXNAV_DATA``) may also name the dataset folder itself.

    Raises:
        FileNotFoundError: naming the paths tried and the environment variable.
    """
    return find_dataset(
        root,
        DATASET,
        # exists(), not is_file(): a named pipe or a folder in a file's place is refused by name when read
        lambda folder: (folder / "Barcodes.dat").exists() and (folder / "Landmark_Groundtruth.dat").exists(),
        "UTIAS MRCLAM Dataset 7",
        _SOURCE,
    )


def available_robots(root: str | os.PathLike | None = None) -> tuple[int, ...]:
    """Robot numbers whose three files are present in the dataset folder."""
    folder = data_dir(root)
    return tuple(n for n in range(1, NUM_ROBOTS + 1) if all(p.is_file() for p in _robot_files(folder, n)))


def _robot_files(folder: Path, robot: int) -> tuple[Path, Path, Path]:
    return tuple(folder / f"Robot{robot}_{kind}.dat" for kind in ("Odometry", "Measurement", "Groundtruth"))


def _data_lines(path: Path):
    """``(line number, fields)`` of each line holding data: ``#`` starts a comment, blank lines are skipped."""
    with open_regular(path, _NOT_REGULAR, encoding="utf-8", errors="replace") as fh:
        for number, line in enumerate(fh, start=1):
            fields = line.split("#", 1)[0].split()
            if fields:
                yield number, fields


def _data_line_numbers(path: Path) -> np.ndarray:
    """The 1-based file line of each data row (to name the line of a bad row)."""
    return np.array([number for number, _ in _data_lines(path)], np.int64)


def _first_bad_line(path: Path, columns: int) -> str | None:
    """Where a table of ``columns`` numbers per line breaks, as a message; None if every line parses."""
    for number, fields in _data_lines(path):
        if len(fields) != columns:
            return f"{path}, line {number}: expected {columns} numbers, found {len(fields)} ({' '.join(fields)!r})"
        for col, text in enumerate(fields, start=1):
            try:
                float(text)
            except ValueError:
                return f"{path}, line {number}, column {col}: {text!r} is not a number"
    return None


def _read(path: Path, columns: int) -> np.ndarray:
    """The ``[rows, columns]`` float64 table of a data file; every value finite.

    Raises:
        ValueError: naming the file and the 1-based line (and column) of the first bad value; or a
            folder, a named pipe or a device in the file's place (refused before it is opened).
    """
    require_regular(path, _NOT_REGULAR)  # np.loadtxt would wait forever on a named pipe
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # an empty file is refused below, with its name
            table = np.loadtxt(path, comments="#", ndmin=2, dtype=np.float64)
    except ValueError as err:  # also a byte that is not UTF-8 (UnicodeDecodeError)
        raise ValueError(
            _first_bad_line(path, columns) or f"{path}: not a table of {columns} numbers ({err})"
        ) from None
    if table.shape[0] == 0:
        raise ValueError(f"{path}: no data lines (the file is empty or holds only comments)")
    if table.shape[1] != columns:
        raise ValueError(
            _first_bad_line(path, columns) or f"{path}: expected {columns} columns, found {table.shape[1]}"
        )
    bad = ~np.isfinite(table)
    if bad.any():  # a filter would carry one NaN or infinity into every later estimate
        row, col = (int(i) for i in np.argwhere(bad)[0])
        raise ValueError(
            f"{path}, line {_data_line_numbers(path)[row]}, column {col + 1}: {table[row, col]} is not a finite "
            f"number ({int(bad.any(axis=1).sum())} line(s) hold NaN or infinite values); remove or correct such lines"
        )
    return table


def _frozen(*arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    out = []
    for a in arrays:
        a = np.ascontiguousarray(a)
        a.flags.writeable = False
        out.append(a)
    return tuple(out)


def _check_times(path: Path, t: np.ndarray, strict: bool) -> None:
    """Refuse time stamps that go backwards (or, ``strict``, repeat), naming the file line."""
    step = np.diff(t)
    bad = np.flatnonzero(step <= 0 if strict else step < 0)
    if bad.size:
        i = int(bad[0]) + 1
        lines = _data_line_numbers(path)
        order = "is not later than" if strict else "is earlier than"
        raise ValueError(
            f"{path}, line {lines[i]}: time {float(t[i])!r} s {order} {float(t[i - 1])!r} s on line {lines[i - 1]} "
            f"({bad.size} such line(s)); the time stamps must {'increase' if strict else 'not decrease'} "
            "(a clock that jumps back cannot be aligned with the other files)"
        )


@functools.lru_cache(maxsize=4)
def _load_map(folder: str) -> tuple[dict[int, int], LandmarkMap]:
    folder_path = Path(folder)
    codes = _read(folder_path / "Barcodes.dat", 2).astype(np.int64)
    barcode_to_subject = {int(b): int(s) for s, b in codes}
    table = _read(folder_path / "Landmark_Groundtruth.dat", 5)
    order = np.argsort(table[:, 0], kind="stable")
    table = table[order]
    subjects, positions, sd = _frozen(table[:, 0].astype(np.int64), table[:, 1:3], table[:, 3:5])
    return barcode_to_subject, LandmarkMap(subjects, positions, sd)


@functools.lru_cache(maxsize=8)
def _load_robot(folder: str, robot: int) -> MRCLAMRobot:
    barcode_to_subject, landmark_map = _load_map(folder)
    odo_path, meas_path, gt_path = _robot_files(Path(folder), robot)
    odo = _read(odo_path, 3)
    if odo.shape[0] < 2:
        raise ValueError(f"{odo_path}: need at least two odometry readings, found {odo.shape[0]}")
    _check_times(odo_path, odo[:, 0], strict=False)
    gt = _read(gt_path, 4)
    _check_times(gt_path, gt[:, 0], strict=True)
    meas = _read(meas_path, 4)
    _check_times(meas_path, meas[:, 0], strict=False)

    barcode = np.rint(meas[:, 1]).astype(np.int64)
    subject = np.array([barcode_to_subject.get(int(b), -1) for b in barcode], dtype=np.int64)
    is_landmark = np.isin(subject, landmark_map.subjects)
    is_robot = (subject >= 1) & (subject <= NUM_ROBOTS)
    return MRCLAMRobot(
        robot=robot,
        odometry=Odometry(*_frozen(odo[:, 0], odo[:, 1], odo[:, 2])),
        measurements=Measurements(*_frozen(meas[:, 0], barcode, subject, meas[:, 2], meas[:, 3])),
        ground_truth=GroundTruth(*_frozen(gt[:, 0], gt[:, 1], gt[:, 2], gt[:, 3])),
        landmarks=landmark_map,
        num_landmark=int(is_landmark.sum()),
        num_robot=int(is_robot.sum()),
        num_unknown=int((subject == -1).sum()),
    )


def load_robot(robot: int, root: str | os.PathLike | None = None) -> MRCLAMRobot:
    """Load robot ``robot``'s odometry, measurements and ground truth, and the landmark map.

    Args:
        robot: 1–5 (the robots of Dataset 7; the copy the tests use holds robots 1–3).
        root: data folder (see :func:`data_dir`).

    Raises:
        ValueError: ``robot`` is not an integer in 1–5; or a file holds a line that is not the
            right count of numbers, a NaN or infinite value, or a time stamp that goes backwards
            (the message names the file and its 1-based line); or a file is a folder, a named pipe
            (FIFO) or a device (``/dev/null``, ``/dev/zero``) instead of a regular file, refused
            before it is opened (the message names it).
        FileNotFoundError: the dataset folder, or this robot's files, are absent.
    """
    if isinstance(robot, bool) or not isinstance(robot, (int, np.integer)) or not 1 <= robot <= NUM_ROBOTS:
        raise ValueError(f"robot must be an integer in 1..{NUM_ROBOTS} (MRCLAM has five robots), got {robot!r}")
    folder = data_dir(root)
    missing = [
        str(p) for p in _robot_files(folder, int(robot)) if not require_regular(p, _NOT_REGULAR, missing_ok=True)
    ]
    if missing:
        raise FileNotFoundError(
            f"robot {robot}: {', '.join(missing)} not found; this copy holds robots {list(available_robots(folder))}"
        )
    return _load_robot(str(folder), int(robot))


# ---------------------------------------------------------------------------
# ground truth


def interpolate_ground_truth(ground_truth: GroundTruth, t: np.ndarray) -> np.ndarray:
    """Ground-truth poses ``[len(t), 3]`` (float64) at times ``t`` (s).

    Linear interpolation of ``x``, ``y`` and the *unwrapped* heading, which is
    then wrapped to ``[-π, π)``. Times outside the record take the end values.
    """
    t = np.asarray(t, dtype=np.float64)
    gt = ground_truth
    theta = np.unwrap(gt.theta)
    x = np.interp(t, gt.t, gt.x)
    y = np.interp(t, gt.t, gt.y)
    th = np.interp(t, gt.t, theta)
    return np.stack([x, y, _wrap_np(th)], axis=-1)


def _wrap_np(angle: np.ndarray) -> np.ndarray:
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


# ---------------------------------------------------------------------------
# discretisation


def _zoh_integral(t: np.ndarray, y: np.ndarray, query: np.ndarray) -> np.ndarray:
    """``∫_{t[0]}^{q} y`` with each ``y[j]`` held on ``[t[j], t[j+1])``, at ``query ⊂ [t[0], t[-1]]``."""
    cumulative = np.concatenate([[0.0], np.cumsum(y[:-1] * np.diff(t))])
    j = np.clip(np.searchsorted(t, query, side="right") - 1, 0, t.shape[0] - 2)
    return cumulative[j] + y[j] * (query - t[j])


def to_filter_steps(
    robot_data: MRCLAMRobot,
    dt: float = 0.02,
    t_start: float | None = None,
    duration: float | None = None,
    max_obs: int = 10,
    keep_outliers: bool = False,
    dtype: Any = jnp.float32,
) -> MRCLAMSequence:
    """Discretise a robot's streams into ``T`` filter steps (conventions in the module docstring).

    Args:
        robot_data: from :func:`load_robot`.
        dt: step length Δt (s); measurement times are within ``Δt/2`` of their step's time.
        t_start: start, in seconds after the robot's first odometry reading
            (default 0: the first reading; odometry does not exist before it).
        duration: length of the sequence (s); default: up to the end of the
            odometry or ground truth, whichever ends first. ``T = ⌊duration/Δt⌋``.
        max_obs: ``K``, observation slots per step.
        keep_outliers: place robot and unknown-barcode measurements in slots
            with out-of-map ids instead of dropping them.
        dtype: float dtype of the JAX arrays (``float64`` needs
            ``jax.enable_x64``; ``times`` is always float64).

    Raises:
        ValueError: an argument is out of range or the window leaves the data.
    """
    if not isinstance(robot_data, MRCLAMRobot):
        raise ValueError(f"robot_data must be an MRCLAMRobot (from load_robot), got {type(robot_data).__name__}")
    dt = float(dt)
    if not (math.isfinite(dt) and dt > 0.0):
        raise ValueError(f"dt must be a positive number of seconds, got {dt}")
    k_slots = check_positive_int("max_obs", max_obs)
    dtype = np.dtype(dtype)
    if dtype.kind != "f" or jax.dtypes.canonicalize_dtype(dtype) != dtype:
        raise ValueError(f"dtype must be a float dtype JAX can hold now (float64 needs jax.enable_x64), got {dtype}")
    odo, gt, meas = robot_data.odometry, robot_data.ground_truth, robot_data.measurements
    for stream in (odo, gt, meas):  # load_robot refuses these; a hand-made MRCLAMRobot may hold them
        for field, values in stream._asdict().items():
            check_finite(f"robot_data.{type(stream).__name__.lower()}.{field}", values)

    offset = 0.0 if t_start is None else float(t_start)
    t0 = float(odo.t[0]) + offset
    t_end = float(min(odo.t[-1], gt.t[-1]))
    if not (math.isfinite(offset) and offset >= 0.0 and t0 >= gt.t[0] and t0 < t_end):
        raise ValueError(
            f"t_start must be in [0, {t_end - odo.t[0]:.3f}) s after the first odometry reading, got {t_start}"
        )
    available = t_end - t0
    if duration is None:
        duration = available
    duration = float(duration)
    if not (math.isfinite(duration) and duration > 0.0) or duration > available + 1e-9:
        raise ValueError(f"duration must be in (0, {available:.3f}] s from this t_start, got {duration}")
    num_steps = int(math.floor(duration / dt + 1e-9))
    if num_steps < 1:
        raise ValueError(f"duration {duration} s is shorter than one step of dt = {dt} s")

    # step end times, relative to t0 (float64; absolute epoch times only at the end)
    rel = dt * np.arange(num_steps + 1, dtype=np.float64)  # rel[0] = t0
    times = t0 + rel[1:]

    # controls: exact zero-order-hold integrals of v and ω over each step
    t_odo = odo.t - t0
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is refused below
        dist = np.diff(_zoh_integral(t_odo, odo.v, rel))
        turn = np.diff(_zoh_integral(t_odo, odo.omega, rel))
    controls = np.stack([dist / dt, turn / dt, np.full(num_steps, dt)], axis=-1)
    overflow = np.flatnonzero(~np.all(np.isfinite(controls), axis=1))
    if overflow.size:  # finite readings whose integral overflows float64
        raise ValueError(
            f"the odometry integrates to non-finite controls from step {int(overflow[0])} "
            f"(time {times[overflow[0]]!r} s): its velocities are too large"
        )

    # measurements: nearest step end time, in time order, K slots per step
    landmark_map = robot_data.landmarks
    num_map = landmark_map.subjects.shape[0]
    slot_of = {int(s): j for j, s in enumerate(landmark_map.subjects)}
    ids_all = np.array([slot_of.get(int(s), -1) for s in meas.subject], dtype=np.int64)
    is_landmark = ids_all >= 0
    robot_ids = num_map + meas.subject - 1
    is_robot = (meas.subject >= 1) & (meas.subject <= NUM_ROBOTS)
    ids_all = np.where(is_robot, robot_ids, ids_all)  # robots 15..19, unknown barcodes -1

    k = np.floor((meas.t - t0) / dt + 0.5).astype(np.int64)  # nearest step end: k·dt after t0
    in_window = (k >= 1) & (k <= num_steps)
    num_outliers = int(np.sum(in_window & ~is_landmark))
    use = in_window & (is_landmark | keep_outliers)
    sel = np.flatnonzero(use)  # measurements are sorted by time, so steps are non-decreasing
    step = k[sel] - 1
    rank = np.arange(sel.shape[0]) - np.searchsorted(step, step, side="left")
    fits = rank < k_slots
    sel, step, rank = sel[fits], step[fits], rank[fits]

    ids = np.zeros((num_steps, k_slots), np.int32)
    z = np.zeros((num_steps, k_slots, 2), np.float64)
    mask = np.zeros((num_steps, k_slots), bool)
    offset_t = np.zeros((num_steps, k_slots), np.float64)
    ids[step, rank] = ids_all[sel]
    z[step, rank, 0] = meas.range[sel]
    z[step, rank, 1] = meas.bearing[sel]
    mask[step, rank] = True
    offset_t[step, rank] = meas.t[sel] - times[step]

    true_poses = interpolate_ground_truth(gt, times)
    initial_pose = interpolate_ground_truth(gt, np.array([t0]))[0]
    return MRCLAMSequence(
        true_poses=jnp.asarray(true_poses, dtype),
        controls=jnp.asarray(controls, dtype),
        observations=lm.RangeBearingObs(jnp.asarray(ids), jnp.asarray(z, dtype), jnp.asarray(mask)),
        initial_pose=jnp.asarray(initial_pose, dtype),
        landmarks=jnp.asarray(landmark_map.positions, dtype),
        times=times,
        obs_time_offset=jnp.asarray(offset_t, dtype),
        t0=t0,
        dt=dt,
        robot=robot_data.robot,
        num_placed=int(sel.shape[0]),
        num_outliers=num_outliers,
        num_dropped_capacity=int(np.sum(~fits)),
        num_outside_window=int(np.sum(~in_window)),
    )


# ---------------------------------------------------------------------------
# scoring


@jax.jit
def _dead_reckon(initial_pose: jax.Array, controls: jax.Array) -> jax.Array:
    mean = get_motion_model("velocity").mean

    def body(pose, u):
        pose = mean(pose, u)
        return pose, pose

    _, poses = jax.lax.scan(body, initial_pose, controls)
    return poses


def dead_reckoning(sequence: MRCLAMSequence, initial_pose: jax.Array | None = None) -> jax.Array:
    """Odometry-only poses ``[T, 3]`` after each step (velocity-model mean, Thrun et al. eq. 5.9).

    Starts from ``initial_pose`` (default: the sequence's ground-truth start)
    and follows the dtype of the controls.
    """
    controls = jnp.asarray(sequence.controls)
    check_shape("sequence.controls", controls, (None, 3))
    check_finite("sequence.controls", controls)
    pose = sequence.initial_pose if initial_pose is None else initial_pose
    pose = jnp.asarray(pose, controls.dtype)
    check_shape("initial_pose", pose, (3,))
    return _dead_reckon(pose, controls)
