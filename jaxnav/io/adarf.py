"""AdaRF real UHF-RFID reads (RSSI and phase of an Impinj reader): a loader and its conversion to filter steps.

**Overview**

The data (dataset 1, test part, of the AdaRF repository ``dapowan/AdaRF``,
commit ``93aa5f3``; most likely Xu et al., "AdaRF", Proc. ACM IMWUT 3(3),
2019 (unverified); **no licence is stated**:
internal validation only, never redistribute) are real reads of a COTS
reader. One antenna moved along the straight line ``y = 0`` and stopped at
50 *aperture points* ``x = 0.02 … 1.00`` m; at each it read three target
tags (EPC ``1000…0001``, ``…0002``, ``…0003``) about 1000 times over 8
channels (920.625–924.125 MHz). The tags lie 20 cm apart on a line parallel
to the track, at ``(X − 0.2, Y)``, ``(X, Y)``, ``(X + 0.2, Y)`` m
(``tag_ground_truth.csv``, derived from the authors' experiment table).

This module reads the ``.csv.gz`` files unchanged from the data folder outside
the repository (:func:`data_dir`) and offers:

1. :func:`load_experiment` — every read of the three target tags as float64
   NumPy arrays (:class:`AdaRFExperiment`), with the ground truth. The
   files' UTF-8 byte-order mark is stripped; the invalid columns (``time``,
   ``velocity``, ``y`` = 1.63, ``angle``, ``dopplerShift``) are not read; reads
   of other EPCs (stray and non-target tags) are dropped and counted
   (``num_stray``). Cached in memory per process.
2. :func:`to_uhf_reads` — one tag's reads as the fixed-slot
   :class:`~jaxnav.models.uhf_reads.UHFReads` that
   :mod:`jaxnav.localization.rfid_tag` takes: one filter step per aperture
   point, ``reads_per_channel`` reads of each channel per step.

**Conversions (the choices, stated once)**

*Geometry (2D).* The antenna track is the line ``y = 0``; the tags lie at
``y = Y > 0``, so the antenna looks along ``+y`` (boresight yaw ``π/2``). The
data have no heights ("any height offset between tag and antenna is folded
into Y"), so reader and tags sit at the same height ``antenna_height``
(default 1 m): localization is 2D with a known tag height. At 1 m the two-ray
breakpoint ``4π h² / λ ≈ 39 m`` is far beyond the 0.5–1.2 m ranges, so the
power model is in its free-space branch and the height value does not matter.

*RSSI.* Reported in dBm (0.5 dB steps); converted to W with
:func:`~jaxnav.models.uhf_channel.dbm_to_watt`.

*Phase convention.* The reader's phase **increases** with distance,
``φ_reader = 4πD/λ + c`` (checked against the ground truth by
:func:`phase_residuals`, which the tests run); jaxnav's model is
``φ = −4πD/λ + θ_off`` ([A] §4.1.2). So ``φ = wrap(−φ_reader)`` in ``[0, 2π)``
(:data:`READER_PHASE_SIGN`).

*Wavelength.* Per read, from its channel: ``λ = c / f`` (0.3244–0.3256 m).

*Channel offsets.* Each channel has its own phase offset (cables, tag and
reader circuits depend on the frequency), while the filter's particle carries
one ``θ_off``. :func:`channel_offsets` estimates, for one tag and from its own
reads only (no ground truth), each channel's offset relative to the lowest
channel: ``δ_c = arg Σ_p z̄_{p,c} · conj(z̄_{p,0})`` with ``z̄_{p,c}`` the mean of
``exp(iφ)`` over the reads of channel ``c`` at point ``p``. Subtracting ``δ_c``
(``align_channels=True``) leaves a residual ``4π(D̄ − D_p)(1/λ_c − 1/λ_0)`` of at
most ``4π · 0.3 m · 3.5 MHz / c ≈ 0.044`` rad over these ranges (``D̄`` the mean
range), small beside the reads' scatter of 0.2–0.6 rad. Without alignment,
use one channel (``channels=(c,)``).

*Slots.* Step ``p`` holds, for each selected channel, ``reads_per_channel``
reads taken at evenly spaced positions of that channel's reads at point ``p``
in file order (deterministic, no key). A channel with fewer reads fills the
rest with masked slots. Treating ~1000 reads at one antenna position as
independent would over-count: their errors are mostly the same multipath, so
a few per channel is the honest amount of information.
"""

from __future__ import annotations

import csv
import functools
import gzip
import math
import os
import zlib
from pathlib import Path
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxnav.core.validation import check_positive_int
from jaxnav.io._data import ENV_VAR, find_dataset
from jaxnav.io._files import open_regular, require_regular
from jaxnav.models import uhf_rfid as U

__all__ = [
    "DATASET",
    "ENV_VAR",
    "TARGET_EPCS",
    "NUM_POINTS",
    "CHANNELS_HZ",
    "READER_PHASE_SIGN",
    "BORESIGHT_YAW",
    "AdaRFExperiment",
    "data_dir",
    "available_experiments",
    "ground_truth",
    "load_experiment",
    "channel_offsets",
    "to_uhf_reads",
    "phase_residuals",
]

DATASET = "adarf-uhf-rfid-phase"
"""Name of the dataset folder inside the data folder."""

_SUBSET = "dataset1_test"

TARGET_EPCS = ("100000000000000000000001", "100000000000000000000002", "100000000000000000000003")
"""The three target tags, in ground-truth order (x = X − 0.2, X, X + 0.2 m)."""

NUM_POINTS = 50
"""Aperture points per experiment (files ``0.csv.gz`` … ``49.csv.gz``)."""

CHANNELS_HZ = 920.625e6 + 0.5e6 * np.arange(8)
"""The 8 channel frequencies (Hz)."""

READER_PHASE_SIGN = -1.0
"""The sign in ``jaxnav phase = wrap(READER_PHASE_SIGN · reader phase)``, −1 because the reader's phase grows
with distance."""

BORESIGHT_YAW = math.pi / 2
"""The antenna looks along +y, towards the tags (rad)."""

_COLUMNS = {"epc": "epc", "frequency": "frequency", "RSSI": "rssi", "phase": "phase", "x": "x"}
_NUMERIC = ("frequency", "RSSI", "phase", "x")
"""The numeric columns read, in the order of the parsed ``[R, 4]`` table."""
_TRUTH_COLUMNS = ("experiment", "epc", "x_m", "y_m")

_SOURCE = (
    "https://github.com/dapowan/AdaRF (its dataset/1/test/<experiment>/<i>.csv files, each gzipped into "
    "dataset1_test/<experiment>/<i>.csv.gz; tag_ground_truth.csv from its dataset/config.txt, see jaxnav.io.adarf)"
)
_UNREADABLE = (OSError, EOFError, zlib.error, csv.Error, UnicodeDecodeError)
"""What reading a truncated or corrupted ``.csv.gz`` raises."""
_NOT_REGULAR = "replace it by the dataset's own file (the loader reads regular files only)"
"""What to do about a data file that is a folder, a named pipe or a device (never opened)."""


class AdaRFExperiment(NamedTuple):
    """Every read of the three target tags in one experiment (float64, read-only; ``R`` reads).

    Attributes:
        name: the experiment's folder name, e.g. ``"181218-01-50-8"``.
        tag: ``[R]`` int, index 0–2 into :data:`TARGET_EPCS`.
        point: ``[R]`` int, aperture point 0–49 (the file it came from).
        antenna_x: ``[R]`` antenna position along the track (m).
        channel: ``[R]`` int, index 0–7 into :data:`CHANNELS_HZ`.
        rssi_dbm: ``[R]`` RSSI (dBm).
        phase: ``[R]`` phase (rad, in [0, 2π)) **as the reader reports it** (grows with distance;
            the reader's rare 2π is stored as 0).
        tags_xy: ``[3, 2]`` ground-truth tag positions (m), in :data:`TARGET_EPCS` order.
        num_stray: reads of other EPCs, dropped.
    """

    name: str
    tag: np.ndarray
    point: np.ndarray
    antenna_x: np.ndarray
    channel: np.ndarray
    rssi_dbm: np.ndarray
    phase: np.ndarray
    tags_xy: np.ndarray
    num_stray: int

    @property
    def aperture_x(self) -> np.ndarray:
        """``[NUM_POINTS]`` antenna position of each aperture point (m)."""
        x = np.zeros(NUM_POINTS)
        x[self.point] = self.antenna_x
        return x


def _is_dataset(folder: Path) -> bool:
    # exists(), not is_file(): a named pipe or a folder in the file's place is refused by name when read
    return (folder / "tag_ground_truth.csv").exists() and (folder / _SUBSET).is_dir()


def data_dir(root: str | os.PathLike | None = None) -> Path:
    """The dataset folder ``<data>/adarf-uhf-rfid-phase``.

    ``<data>`` is ``root`` if given, else ``$JAXNAV_DATA`` if set, else ``../shared/data`` relative
    to the repository root when jaxnav runs from a source checkout (never relative to the current
    directory). ``root`` (or ``$JAXNAV_DATA``) may also name the dataset folder itself.

    Raises:
        FileNotFoundError: naming the paths tried and the environment variable.
    """
    return find_dataset(root, DATASET, _is_dataset, "AdaRF UHF-RFID dataset", _SOURCE)


def available_experiments(root: str | os.PathLike | None = None) -> tuple[str, ...]:
    """Experiments present with all 50 aperture files and a ground truth, sorted.

    A file is present when its path exists: one that is a named pipe or a folder lists its experiment,
    which :func:`load_experiment` then refuses naming that file.
    """
    folder = data_dir(root)
    truth = ground_truth(root)
    out = []
    for sub in sorted((folder / _SUBSET).iterdir()):
        if sub.name in truth and all((sub / f"{i}.csv.gz").exists() for i in range(NUM_POINTS)):
            out.append(sub.name)
    return tuple(out)


def ground_truth(root: str | os.PathLike | None = None) -> dict[str, np.ndarray]:
    """``{experiment: [3, 2]}`` tag positions (m) from ``tag_ground_truth.csv``, in :data:`TARGET_EPCS` order."""
    return {k: v.copy() for k, v in _ground_truth(str(data_dir(root))).items()}


@functools.lru_cache(maxsize=2)
def _ground_truth(folder: str) -> dict[str, np.ndarray]:
    path = Path(folder) / "tag_ground_truth.csv"
    table: dict[str, dict[str, tuple[float, float]]] = {}
    try:
        with open_regular(path, _NOT_REGULAR, encoding="utf-8-sig", newline="") as fh:
            reader = csv.reader(fh)
            header = next(reader, None)
            if header is None:
                raise ValueError(f"{path}: empty file")
            missing = [c for c in _TRUTH_COLUMNS if c not in header]
            if missing:
                raise ValueError(f"{path}: missing columns {missing} (header {header})")
            at = [header.index(c) for c in _TRUTH_COLUMNS]
            for row in reader:
                if not row:
                    continue
                name, epc, x, y = _truth_row(path, reader.line_num, header, row, at)
                table.setdefault(name, {})[epc] = (x, y)
    except _UNREADABLE as err:
        raise ValueError(f"{path}: cannot be read as CSV text ({err})") from None
    out = {}
    for name, tags in table.items():
        missing = [e for e in TARGET_EPCS if e not in tags]
        if missing:
            raise ValueError(f"{path}: experiment {name} has no ground truth for EPC {missing}")
        out[name] = np.array([tags[e] for e in TARGET_EPCS], np.float64)
    return out


def _truth_row(
    path: Path, line: int, header: list[str], row: list[str], at: list[int]
) -> tuple[str, str, float, float]:
    """``(experiment, epc, x, y)`` of one ground-truth line; a short line or a bad number is refused with its place."""
    if len(row) <= max(at):
        raise ValueError(
            f"{path}, line {line}: {len(row)} field(s), the header has {len(header)}; the line is cut short"
        )
    name, epc = row[at[0]], row[at[1]]
    xy = tuple(_finite(path, line, col, row[i]) for col, i in zip(_TRUTH_COLUMNS[2:], at[2:]))
    return name, epc, xy[0], xy[1]


def _finite(path: Path, line: int, column: str, text: str) -> float:
    """``text`` as a finite float, or a ValueError naming the file, line and column."""
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{path}, line {line}, column {column!r}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise ValueError(f"{path}, line {line}, column {column!r}: {text!r} is not a finite number")
    return value


def _read_point(path: Path) -> tuple[list[list[str]], list[int], list[str]]:
    """The rows of one aperture file, the 1-based line of each, and the header."""
    rows: list[list[str]] = []
    lines: list[int] = []
    line = 0
    raw = open_regular(path, _NOT_REGULAR, "rb")  # refused before a named pipe is waited on
    try:
        with raw, gzip.open(raw, "rt", encoding="utf-8-sig", newline="") as fh:  # utf-8-sig: files start with a BOM
            reader = csv.reader(fh)
            header = next(reader, None)
            line = reader.line_num
            if header is None:
                raise ValueError(f"{path}: empty file")
            for row in reader:
                line = reader.line_num
                if row:  # a blank line holds no read
                    rows.append(row)
                    lines.append(line)
    except _UNREADABLE as err:
        raise ValueError(
            f"{path}: unreadable after line {line} ({type(err).__name__}: {err}); the file is truncated or "
            "corrupted: copy it again"
        ) from None
    return rows, lines, header


def _parse_point(
    path: Path, rows: list[list[str]], lines: list[int], header: list[str]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """One aperture file's target reads: ``(tag [R], values [R, 4] in _NUMERIC order, line [R], stray count)``.

    A row too short for the columns read, a field that is not a number or a NaN / infinite value
    is refused with the file, the line and the column.
    """
    missing = [c for c in _COLUMNS if c not in header]
    if missing:
        raise ValueError(f"{path}: missing columns {missing} (header {header})")
    epc_at = header.index("epc")
    at = [header.index(c) for c in _NUMERIC]
    need = max(at + [epc_at]) + 1
    epc_index = {e: i for i, e in enumerate(TARGET_EPCS)}
    tags: list[int] = []
    values: list[list[str]] = []
    where: list[int] = []
    stray = 0
    for row, line in zip(rows, lines):
        if len(row) < need:
            raise ValueError(
                f"{path}, line {line}: {len(row)} field(s), the header has {len(header)}; the line is cut short"
            )
        tag = epc_index.get(row[epc_at])
        if tag is None:
            stray += 1
            continue
        tags.append(tag)
        values.append([row[i] for i in at])
        where.append(line)
    try:
        table = np.array(values, np.float64).reshape(-1, len(_NUMERIC))
    except ValueError:  # find the field that is not a number
        for fields, line in zip(values, where):
            for column, text in zip(_NUMERIC, fields):
                _finite(path, line, column, text)
        raise
    bad = ~np.isfinite(table)
    if bad.any():
        r, c = (int(i) for i in np.argwhere(bad)[0])
        raise ValueError(
            f"{path}, line {where[r]}, column {_NUMERIC[c]!r}: {values[r][c]!r} is not a finite number "
            f"({int(bad.any(axis=1).sum())} line(s) hold NaN or infinite values)"
        )
    return np.asarray(tags, np.int64), table, np.asarray(where, np.int64), stray


def _channels(path: Path, freq: np.ndarray, line: np.ndarray) -> np.ndarray:
    """The channel index (0–7) of each read's frequency (Hz); another frequency is refused with its line."""
    channel = np.clip(np.rint((freq - CHANNELS_HZ[0]) / 0.5e6), 0, len(CHANNELS_HZ) - 1).astype(np.int64)
    off = np.flatnonzero(np.rint(freq) != np.rint(CHANNELS_HZ[channel]))
    if off.size:
        raise ValueError(
            f"{path}, line {line[off[0]]}: frequency {freq[off[0]]:.0f} Hz is not one of the 8 channels "
            f"{CHANNELS_HZ.tolist()}"
        )
    return channel


def _check_phase(path: Path, phase: np.ndarray, line: np.ndarray) -> None:
    """The reader reports phases in [0, 2π] (its 12-bit phase reaches 2π itself); anything else is refused."""
    off = np.flatnonzero((phase < 0) | (phase > 2 * math.pi + 1e-9))
    if off.size:
        raise ValueError(
            f"{path}, line {line[off[0]]}, column 'phase': {float(phase[off[0]])!r} rad is outside [0, 2π] "
            f"({off.size} read(s)) — not the reader convention this loader expects"
        )


@functools.lru_cache(maxsize=4)
def _load(folder: str, name: str) -> AdaRFExperiment:
    truth = _ground_truth(folder)
    if name not in truth:
        raise ValueError(f"unknown experiment {name!r}: the ground truth has {sorted(truth)}")
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("tag", "point", "x", "channel", "rssi", "phase")}
    stray = 0
    for p in range(NUM_POINTS):
        path = Path(folder) / _SUBSET / name / f"{p}.csv.gz"
        if not require_regular(path, _NOT_REGULAR, missing_ok=True):
            raise FileNotFoundError(f"{path} is missing: experiment {name} needs files 0..{NUM_POINTS - 1}")
        tag, values, line, n_stray = _parse_point(path, *_read_point(path))
        stray += n_stray
        if tag.size == 0:
            raise ValueError(f"{path}: no reads of the target tags")
        freq, rssi, phase, xs = values.T
        if np.ptp(xs) > 1e-6:
            raise ValueError(f"{path}: one file must hold one aperture point, got antenna x {np.unique(xs)}")
        _check_phase(path, phase, line)
        parts["tag"].append(tag)
        parts["channel"].append(_channels(path, freq, line))
        parts["rssi"].append(rssi)
        parts["phase"].append(phase)
        parts["x"].append(xs)
        parts["point"].append(np.full(tag.size, p, np.int64))
    cols = {k: np.concatenate(v) for k, v in parts.items()}
    arrays = dict(
        tag=cols["tag"],
        point=cols["point"],
        antenna_x=cols["x"],
        channel=cols["channel"],
        rssi_dbm=cols["rssi"],
        phase=np.mod(cols["phase"], 2 * math.pi),  # the reader's 2π (155 reads of 181218-01) is the angle 0
    )
    for a in arrays.values():
        a.flags.writeable = False
    tags_xy = truth[name].copy()
    tags_xy.flags.writeable = False
    return AdaRFExperiment(name=name, tags_xy=tags_xy, num_stray=stray, **arrays)


def load_experiment(name: str, root: str | os.PathLike | None = None) -> AdaRFExperiment:
    """All reads of the three target tags in experiment ``name`` (e.g. ``"181218-01-50-8"``).

    Reads the 50 files of ``dataset1_test/<name>/`` (about 1 s). Cached per process.

    Raises:
        FileNotFoundError: the data folder or a file is missing.
        ValueError: an unknown experiment; or a file that does not look like the documented format:
            truncated or corrupted, a line cut short, a field that is not a number, a NaN or
            infinite value, a phase outside [0, 2π] or an unknown frequency (the message names
            the file, its 1-based line and the column); or a file that is a folder, a named pipe
            (FIFO) or a device instead of a regular file, refused before it is opened.
    """
    return _load(str(data_dir(root)), str(name))


def _tag_reads(exp: AdaRFExperiment, tag: int) -> np.ndarray:
    if tag not in (0, 1, 2):
        raise ValueError(f"tag must be 0, 1 or 2 (index into TARGET_EPCS), got {tag!r}")
    return np.flatnonzero(exp.tag == tag)


def _jaxnav_phase(reader_phase: np.ndarray) -> np.ndarray:
    return np.mod(READER_PHASE_SIGN * reader_phase, 2 * math.pi)


def _point_channel_means(exp: AdaRFExperiment, idx: np.ndarray) -> np.ndarray:
    """``[NUM_POINTS, 8]`` complex mean of ``exp(iφ)`` (jaxnav convention); 0 where a cell has no read."""
    z = np.zeros((NUM_POINTS, len(CHANNELS_HZ)), np.complex128)
    n = np.zeros(z.shape)
    np.add.at(z, (exp.point[idx], exp.channel[idx]), np.exp(1j * _jaxnav_phase(exp.phase[idx])))
    np.add.at(n, (exp.point[idx], exp.channel[idx]), 1.0)
    return np.where(n > 0, z / np.maximum(n, 1.0), 0.0)


def channel_offsets(exp: AdaRFExperiment, tag: int) -> np.ndarray:
    """``[8]`` phase offset of each channel relative to channel 0 (rad, jaxnav convention), from ``tag``'s own reads.

    ``δ_c = arg Σ_p z̄_{p,c} conj(z̄_{p,0})`` over the aperture points (module docstring); ``δ_0 = 0``.
    Uses no ground truth.
    """
    z = _point_channel_means(exp, _tag_reads(exp, tag))
    cross = np.sum(z * np.conj(z[:, :1]), axis=0)
    if np.any(np.abs(cross) == 0):
        raise ValueError(f"tag {tag}: a channel shares no aperture point with channel 0; use channels=(c,)")
    return np.angle(cross)


def _evenly_spaced(order: np.ndarray, group: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """From reads sorted by ``group`` (``order``), up to ``k`` evenly spaced per group: (read, group, slot)."""
    g_sorted = group[order]
    starts = np.flatnonzero(np.r_[True, g_sorted[1:] != g_sorted[:-1]])
    counts = np.diff(np.r_[starts, g_sorted.size])
    slot = np.arange(k)
    take = slot[None, :] < counts[:, None]
    pos = starts[:, None] + np.floor((slot[None, :] + 0.5) * counts[:, None] / k).astype(np.int64)
    rows, cols = np.nonzero(take)
    return order[pos[rows, cols]], g_sorted[starts[rows]], cols


def to_uhf_reads(
    exp: AdaRFExperiment,
    tag: int,
    reads_per_channel: int = 1,
    channels: tuple[int, ...] | None = None,
    align_channels: bool = True,
    antenna_height: float = 1.0,
) -> U.UHFReads:
    """Tag ``tag``'s reads as :class:`~jaxnav.models.uhf_reads.UHFReads` ``[NUM_POINTS, J]``, one step per aperture point.

    Args:
        exp: from :func:`load_experiment`.
        tag: 0, 1 or 2 (index into :data:`TARGET_EPCS`).
        reads_per_channel: reads of each channel per step (evenly spaced in file order).
        channels: channel indices to use (default all 8).
        align_channels: subtract :func:`channel_offsets` so one ``θ_off`` fits every channel
            (module docstring); needed when several channels are used.
        antenna_height: reader (and tag) height ``z`` (m); the data are 2D.

    Returns:
        ``J = len(channels) · reads_per_channel`` slots per step; reader poses
        ``(x_antenna, 0, antenna_height, π/2)``, RSSI in W, phase in jaxnav's
        convention, per-read wavelength ``c/f``; unfilled slots masked.
    """
    check_positive_int("reads_per_channel", reads_per_channel)
    chans = tuple(range(len(CHANNELS_HZ))) if channels is None else tuple(int(c) for c in channels)
    if not chans or any(c < 0 or c >= len(CHANNELS_HZ) for c in chans) or len(set(chans)) != len(chans):
        raise ValueError(f"channels must be distinct indices in 0..{len(CHANNELS_HZ) - 1}, got {channels!r}")
    if not antenna_height > 0:
        raise ValueError(f"antenna_height must be > 0 (m), got {antenna_height!r}")
    idx = _tag_reads(exp, tag)
    idx = idx[np.isin(exp.channel[idx], chans)]
    phase = _jaxnav_phase(exp.phase)
    if align_channels:
        phase = np.mod(phase - channel_offsets(exp, tag)[exp.channel], 2 * math.pi)
    slot_of_channel = np.full(len(CHANNELS_HZ), -1)
    slot_of_channel[list(chans)] = np.arange(len(chans))
    group = exp.point * len(CHANNELS_HZ) + exp.channel
    order = idx[np.argsort(group[idx], kind="stable")]  # file order kept inside each (point, channel)
    read, g, s = _evenly_spaced(order, group, reads_per_channel)
    point, chan = g // len(CHANNELS_HZ), g % len(CHANNELS_HZ)
    col = slot_of_channel[chan] * reads_per_channel + s
    j = len(chans) * reads_per_channel

    reader = np.zeros((NUM_POINTS, j, 4))
    reader[:, :, 0] = exp.aperture_x[:, None]
    reader[:, :, 2] = antenna_height
    reader[:, :, 3] = BORESIGHT_YAW
    rssi = np.ones((NUM_POINTS, j))  # masked slots hold finite dummies (never read)
    phi = np.zeros((NUM_POINTS, j))
    lam = np.broadcast_to((U.SPEED_OF_LIGHT / CHANNELS_HZ[list(chans)]).repeat(reads_per_channel), (NUM_POINTS, j))
    mask = np.zeros((NUM_POINTS, j), bool)
    rssi[point, col] = np.asarray(U.dbm_to_watt(exp.rssi_dbm[read]))
    phi[point, col] = phase[read]
    mask[point, col] = True
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    out = U.UHFReads(f32(reader), f32(rssi), f32(np.where(phi >= 2 * math.pi, 0.0, phi)), f32(lam), jnp.asarray(mask))
    U.validate_reads(out)
    return out


def phase_residuals(exp: AdaRFExperiment, tag: int, tag_xy: np.ndarray, channel: int = 0) -> tuple[np.ndarray, float]:
    """Residuals (rad) of channel ``channel``'s per-point circular mean phase against jaxnav's model at ``tag_xy``.

    The model ``φ = −4πD/λ + θ_off`` with ``D`` the antenna–tag distance (2D) and
    ``θ_off`` fitted (circular mean of the residual). Returns ``([NUM_POINTS], rms)``;
    a correct position and convention give an RMS well below the ``≈ 1.8`` rad of
    uniform phases. A check of the sign convention, used by the tests.
    """
    z = _point_channel_means(exp, _tag_reads(exp, tag))[:, channel]
    lam = U.SPEED_OF_LIGHT / CHANNELS_HZ[channel]
    d = np.hypot(exp.aperture_x - tag_xy[0], tag_xy[1])
    r = np.angle(z * np.exp(1j * 4 * math.pi * d / lam))
    r = np.angle(np.exp(1j * (r - np.angle(np.sum(np.exp(1j * r))))))
    return r, float(np.sqrt(np.mean(r * r)))
