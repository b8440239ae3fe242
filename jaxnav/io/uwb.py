"""Loader of the TU Chemnitz "Labyrinth" indoor UWB ranging dataset (libRSF ``Indoor_UWB``).

**Overview**

A small differential-drive robot in a 2.4 m × 2.4 m area with four UWB anchors at known positions,
30 s and about 9.3 m of path, at 7.8 Hz: at every time stamp one range to one anchor (the anchors
polled in turn), the two wheel speeds, and the robot's ground-truth position (no heading). The
ranges read long: their residual against the ground truth has a mean of +0.12 m and a standard
deviation of 0.11 m, positive for every anchor — the bias that
:class:`jaxnav.models.range_only.RangeNoise` models. Data: Copyright 2017–2023 Tim Pfeifer
(TU Chemnitz), CC BY-SA 4.0, distributed with libRSF (T. Pfeifer et al.,
https://github.com/TUC-ProAut/libRSF).

**As filter steps.** :func:`load_labyrinth` returns one step per time stamp ``t_i``:

* control ``(v_right, v_left, Δt_i)`` for :func:`jaxnav.models.motion.differential_drive`, with
  ``Δt_i = t_i − t_{i−1}`` (``Δt_0 = 0``: the filter starts at the first time stamp) and the wheel
  speeds read at ``t_i``, held over ``(t_{i−1}, t_i]`` (those read at ``t_{i−1}`` dead-reckon as
  well: a mean position error of 0.20 m either way, from the true start);
* observation: one :class:`~jaxnav.models.range_only.RangeObs` slot, the range read at ``t_i``
  (``ids`` the anchor's index into :attr:`UWBSequence.anchors`).

**The odometry's convention.** The file names its columns ``v_right v_left`` and its wheel base
0.0785 m, but libRSF's own differential-drive model (``PredictMotionDifferential2D``) turns at
``ω = (v_left − v_right) / (2 · 0.0785)``: the stated wheel base is half the distance between the
wheels, and with ``ω = (v_r − v_l)/b`` (turning left positive) the column named ``v_left`` is the
right wheel. The loader follows that model: ``controls = (v_left column, v_right column, Δt)`` and
``wheel_base = 2 · 0.0785 = 0.157`` m. Dead reckoning from the true start then has a mean position
error of 0.20 m over the 30 s; read as named, 1.68 m.

The initial heading, which the ground truth does not give, is the direction of the ground-truth
path's first 0.1 m; the initial position is the ground truth at ``t_0``.

Every file is checked as it is read: a line of the wrong length or with a value that is not a
finite number, time stamps that differ between the three streams, an anchor whose position moves,
or a path that is not a regular file raise ``ValueError`` naming the file and the line.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.io._data import find_dataset
from jaxnav.io._files import open_regular
from jaxnav.models import motion
from jaxnav.models.range_only import RangeObs

__all__ = ["DATASET", "UWBSequence", "data_dir", "load_labyrinth", "segment", "dead_reckoning"]

DATASET = "tuc-labyrinth-uwb"
"""The dataset's folder name under the data folder."""
_SOURCE = "https://github.com/TUC-ProAut/libRSF (datasets/Indoor_UWB)"
_INPUT, _TRUTH = "Indoor_UWB_Input.txt", "Indoor_UWB_GT.txt"
_NOT_REGULAR = "point the loader at the dataset's folder holding the Indoor_UWB text files"
# fields per line after the type: range2 t r var x y id snr; odom2diff t vr vl vy b cr cl cy; point2 t x y c c c c
_FIELDS = {"range2": 7, "odom2diff": 8, "point2": 7}
_HEADING_DISTANCE = 0.1  # m of ground-truth path that give the initial heading


class UWBSequence(NamedTuple):
    """The dataset as filter steps (module docstring), NumPy arrays in float64.

    Attributes:
        times: ``[T]`` time stamps (s).
        controls: ``[T, 3]`` ``(v_right [m/s], v_left [m/s], Δt [s])``.
        observations: :class:`~jaxnav.models.range_only.RangeObs` ``[T, 1]`` slots.
        anchors: ``[4, 2]`` anchor positions (m).
        anchor_ids: the anchors' UWB module IDs, in the order of ``anchors``.
        true_positions: ``[T, 2]`` ground-truth positions (m).
        initial_pose: ``[3]`` the start (m, m, rad): ground truth at ``t_0``, heading of the first 0.1 m.
        wheel_base: distance between the wheels (m): twice the file's value (module docstring).
        range_variance: ``[T]`` the range variance the file states (m²; 0.01 throughout).
    """

    times: np.ndarray
    controls: np.ndarray
    observations: RangeObs
    anchors: np.ndarray
    anchor_ids: tuple[int, ...]
    true_positions: np.ndarray
    initial_pose: np.ndarray
    wheel_base: float
    range_variance: np.ndarray

    @property
    def motion_model(self) -> motion.MotionModel:
        """:func:`jaxnav.models.motion.differential_drive` of the robot's wheel base."""
        return motion.differential_drive(self.wheel_base)


def data_dir(root: str | os.PathLike | None = None) -> Path:
    """The dataset folder ``<data>/tuc-labyrinth-uwb`` (``root``, else ``$JAXNAV_DATA``, else
    ``../shared/data`` relative to the repository root of a source checkout, never to the current
    directory; :mod:`jaxnav.io`). Raises :class:`~jaxnav.io.DataNotFoundError` naming the paths tried."""
    return find_dataset(
        root,
        DATASET,
        lambda folder: (folder / _INPUT).exists() and (folder / _TRUTH).exists(),
        "TU Chemnitz Labyrinth UWB dataset",
        _SOURCE,
    )


def _read_lines(path: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``{type: (values [n, fields], line numbers [n])}`` of a libRSF text file, every value checked."""
    rows: dict[str, list[list[float]]] = {}
    lines: dict[str, list[int]] = {}
    with open_regular(path, _NOT_REGULAR, encoding="utf-8", errors="replace") as fh:
        for number, line in enumerate(fh, start=1):
            fields = line.split()
            if not fields:
                continue
            kind = fields[0]
            if kind not in _FIELDS:
                raise ValueError(
                    f"{path}, line {number}: unknown measurement type {kind!r} (expected one of {sorted(_FIELDS)})"
                )
            if len(fields) - 1 != _FIELDS[kind]:
                raise ValueError(
                    f"{path}, line {number}: a {kind} line holds {_FIELDS[kind]} numbers, found {len(fields) - 1}"
                )
            try:
                values = [float(v) for v in fields[1:]]
            except ValueError:
                raise ValueError(
                    f"{path}, line {number}: {line.strip()!r} holds a value that is not a number"
                ) from None
            if not np.all(np.isfinite(values)):
                raise ValueError(f"{path}, line {number}: {line.strip()!r} holds a value that is not finite")
            rows.setdefault(kind, []).append(values)
            lines.setdefault(kind, []).append(number)
    return {kind: (np.asarray(rows[kind], np.float64), np.asarray(lines[kind])) for kind in rows}


def _require(tables: dict, kind: str, path: Path) -> tuple[np.ndarray, np.ndarray]:
    if kind not in tables:
        raise ValueError(f"{path}: holds no {kind} lines")
    return tables[kind]


def _check_same_times(path: Path, kind: str, t: np.ndarray, lines: np.ndarray, reference: np.ndarray) -> None:
    if t.shape != reference.shape:
        raise ValueError(
            f"{path}: {t.shape[0]} {kind} lines for {reference.shape[0]} time stamps; every stream needs one per stamp"
        )
    off = np.flatnonzero(np.abs(t - reference) > 1e-6)
    if off.size:
        i = int(off[0])
        raise ValueError(f"{path}, line {lines[i]}: {kind} time {t[i]} s where the ranges have {reference[i]} s")


def _anchors(path: Path, ranges: np.ndarray, lines: np.ndarray) -> tuple[np.ndarray, tuple[int, ...], np.ndarray]:
    """``(positions [M, 2], ids, index per range line)``, refusing an anchor whose position changes."""
    ids = ranges[:, 5]
    if np.any(ids != np.round(ids)):
        i = int(np.flatnonzero(ids != np.round(ids))[0])
        raise ValueError(f"{path}, line {lines[i]}: anchor id {ids[i]} is not an integer")
    unique, index = np.unique(ids.astype(np.int64), return_inverse=True)
    positions = np.zeros((unique.size, 2))
    for a in range(unique.size):
        xy = ranges[index == a, 3:5]
        moved = np.flatnonzero(np.any(np.abs(xy - xy[0]) > 1e-9, axis=1))
        if moved.size:
            i = int(np.flatnonzero(index == a)[moved[0]])
            (x, y), (x0, y0) = xy[moved[0]], xy[0]
            raise ValueError(
                f"{path}, line {lines[i]}: anchor {unique[a]} at ({x:g}, {y:g}) m, earlier at ({x0:g}, {y0:g}) m"
            )
        positions[a] = xy[0]
    return positions, tuple(int(u) for u in unique), index


def _initial_heading(positions: np.ndarray) -> float:
    """The direction of the path's first ``_HEADING_DISTANCE`` metres (0 if it never gets that far)."""
    far = np.flatnonzero(np.linalg.norm(positions - positions[0], axis=1) >= _HEADING_DISTANCE)
    if not far.size:
        return 0.0
    d = positions[far[0]] - positions[0]
    return float(np.arctan2(d[1], d[0]))


def load_labyrinth(root: str | os.PathLike | None = None) -> UWBSequence:
    """The Labyrinth dataset as filter steps (module docstring); ``root`` as :func:`data_dir`."""
    folder = data_dir(root)
    inputs, truth_path = folder / _INPUT, folder / _TRUTH
    tables = _read_lines(inputs)
    ranges, range_lines = _require(tables, "range2", inputs)
    odometry, odometry_lines = _require(tables, "odom2diff", inputs)
    truth, truth_lines = _require(_read_lines(truth_path), "point2", truth_path)
    times = ranges[:, 0]
    if np.any(np.diff(times) <= 0):
        i = int(np.flatnonzero(np.diff(times) <= 0)[0]) + 1
        raise ValueError(f"{inputs}, line {range_lines[i]}: time {times[i]} s does not follow {times[i - 1]} s")
    _check_same_times(inputs, "odom2diff", odometry[:, 0], odometry_lines, times)
    _check_same_times(truth_path, "point2", truth[:, 0], truth_lines, times)
    bases = odometry[:, 4]
    if np.any(bases <= 0) or np.ptp(bases) > 1e-9:
        raise ValueError(f"{inputs}: the wheel base must be one positive value, got {np.unique(bases)} m")
    anchors, anchor_ids, index = _anchors(inputs, ranges, range_lines)
    dt = np.diff(times, prepend=times[0])
    # the file's convention (module docstring): its "v_left" column is our right wheel, its wheel base half ours
    controls = np.stack([odometry[:, 2], odometry[:, 1], dt], axis=1)
    obs = RangeObs(index[:, None].astype(np.int32), ranges[:, 1].reshape(-1, 1, 1), np.ones((times.size, 1), bool))
    positions = truth[:, 1:3]
    start = np.array([positions[0, 0], positions[0, 1], _initial_heading(positions)])
    return UWBSequence(times, controls, obs, anchors, anchor_ids, positions, start, 2.0 * float(bases[0]), ranges[:, 2])


def segment(sequence: UWBSequence, start: int, stop: int | None = None) -> UWBSequence:
    """Steps ``start`` to ``stop`` (exclusive; default the end) of ``sequence`` as a sequence of their own:
    the initial pose is the ground truth at step ``start`` with the heading of the next 0.1 m of path,
    and the first step's ``Δt`` is 0 (the robot starts there, as at the log's first step)."""
    num_steps = sequence.times.size
    stop = num_steps if stop is None else stop
    for name, value in (("start", start), ("stop", stop)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise ValueError(f"{name} must be an int, got {value!r}")
    if not 0 <= start < stop <= num_steps:
        raise ValueError(f"need 0 <= start < stop <= {num_steps} (the steps), got start={start}, stop={stop}")
    cut = slice(start, stop)
    controls = sequence.controls[cut].copy()
    controls[0, 2] = 0.0
    positions = sequence.true_positions[cut]
    pose = np.array([positions[0, 0], positions[0, 1], _initial_heading(positions)])
    return sequence._replace(
        times=sequence.times[cut],
        controls=controls,
        observations=RangeObs(*(np.asarray(a)[cut] for a in sequence.observations)),
        true_positions=positions,
        initial_pose=pose,
        range_variance=sequence.range_variance[cut],
    )


def dead_reckoning(sequence: UWBSequence, initial_pose: np.ndarray | None = None) -> jax.Array:
    """``[T, 3]`` poses from the wheel speeds alone (the differential-drive model's mean), from
    ``initial_pose`` (default the sequence's), in JAX's default float dtype."""
    model = sequence.motion_model
    dtype = jnp.result_type(float)
    start = jnp.asarray(sequence.initial_pose if initial_pose is None else initial_pose, dtype)
    step = lambda pose, control: (model.mean(pose, control),) * 2  # noqa: E731
    return jax.lax.scan(step, start, jnp.asarray(sequence.controls, dtype))[1]
