"""Corrupted data files: every loader refuses them with the file and its 1-based line, never a traceback
from deep inside NumPy or gzip, and never a silent wrong answer.

The files are small synthetic copies of each dataset's layout, written to ``tmp_path``: the real
data are never needed (nor modified).
"""

from __future__ import annotations

import gzip
import re

import numpy as np
import pytest

from jaxnav.io import adarf, mrclam

# ---------------------------------------------------------------------------
# MRCLAM: whitespace-separated tables with "#" comments; line numbers count the comment lines

MRCLAM_FILES = {
    "Barcodes.dat": "# subject barcode\n1 5\n2 14\n6 63\n7 25\n",
    "Landmark_Groundtruth.dat": "# subject x y sdx sdy\n6 1.0 2.0 0.01 0.01\n7 3.0 1.0 0.01 0.01\n",
    "Robot1_Odometry.dat": "# t v w\n0.0 0.1 0.0\n0.1 0.1 0.0\n0.2 0.1 0.0\n0.3 0.1 0.0\n",
    "Robot1_Groundtruth.dat": "# t x y theta\n0.0 0.0 0.0 0.0\n0.1 0.01 0.0 0.0\n0.2 0.02 0.0 0.0\n0.3 0.03 0.0 0.0\n",
    "Robot1_Measurement.dat": "# t barcode range bearing\n0.05 63 1.5 0.1\n0.15 25 2.0 -0.2\n0.25 63 1.4 0.1\n",
}


def _mrclam(folder, **replace):
    """A two-landmark copy of the MRCLAM layout (robot 1); ``replace`` swaps a file's text (``None``: no file)."""
    folder.mkdir(parents=True, exist_ok=True)
    files = dict(MRCLAM_FILES)
    files.update(replace)
    for name, text in files.items():
        if text is None:
            continue
        path = folder / name
        path.write_bytes(text) if isinstance(text, bytes) else path.write_text(text)
    return folder


def _lines(name, *rows):
    """A file of ``name``'s comment line followed by ``rows``."""
    return MRCLAM_FILES[name].splitlines()[0] + "\n" + "".join(r + "\n" for r in rows)


def test_the_synthetic_mrclam_copy_loads(tmp_path):
    robot = mrclam.load_robot(1, _mrclam(tmp_path))
    assert robot.odometry.t.shape == (4,) and robot.num_landmark == 3
    seq = mrclam.to_filter_steps(robot, dt=0.1)
    assert np.all(np.isfinite(np.asarray(seq.controls)))


MRCLAM_CASES = [
    # (file, its text, the message: file, line (1-based, comments counted), what is wrong)
    (
        "Robot1_Odometry.dat",
        _lines("Robot1_Odometry.dat", "0.0 0.1 0.0", "0.1 abc 0.0", "0.2 0.1 0.0"),
        r"Robot1_Odometry.dat, line 3, column 2: 'abc' is not a number",
    ),
    (
        "Robot1_Odometry.dat",
        _lines("Robot1_Odometry.dat", "0.0 0.1 0.0", "0.1 0.1", "0.2 0.1 0.0"),
        r"Robot1_Odometry.dat, line 3: expected 3 numbers, found 2",
    ),
    (
        "Robot1_Odometry.dat",
        _lines("Robot1_Odometry.dat", "0.0 0.1 0.0", "0.1 0.1 0.0 7", "0.2 0.1 0.0"),
        r"Robot1_Odometry.dat, line 3: expected 3 numbers, found 4",
    ),
    (
        "Robot1_Odometry.dat",
        _lines("Robot1_Odometry.dat", "0.0 0.1 0.0", "0.1 nan 0.0", "0.2 0.1 0.0", "0.3 0.1 0.0"),
        r"Robot1_Odometry.dat, line 3, column 2: nan is not a finite number",
    ),
    (
        "Robot1_Odometry.dat",
        _lines("Robot1_Odometry.dat", "0.0 0.1 0.0", "0.1 0.1 -inf", "0.2 0.1 0.0"),
        r"Robot1_Odometry.dat, line 3, column 3: -inf is not a finite number",
    ),
    (
        "Robot1_Odometry.dat",
        _lines("Robot1_Odometry.dat", "0.0 0.1 0.0", "0.2 0.1 0.0", "0.1 0.1 0.0"),
        r"Robot1_Odometry.dat, line 4: time 0.1 s is earlier than 0.2 s on line 3",
    ),
    (
        "Robot1_Odometry.dat",
        _lines("Robot1_Odometry.dat", "0.0 0.1 0.0"),
        r"Robot1_Odometry.dat: need at least two odometry readings, found 1",
    ),
    (
        "Robot1_Groundtruth.dat",
        _lines("Robot1_Groundtruth.dat", "0.0 0.0 0.0 0.0", "0.1 nan 0.0 0.0", "0.2 0.02 0.0 0.0"),
        r"Robot1_Groundtruth.dat, line 3, column 2: nan is not a finite number",
    ),
    (
        "Robot1_Groundtruth.dat",
        _lines("Robot1_Groundtruth.dat", "0.0 0.0 0.0 0.0", "0.1 0.01 0.0 0.0", "0.1 0.02 0.0 0.0"),
        r"Robot1_Groundtruth.dat, line 4: time 0.1 s is not later than 0.1 s on line 3",
    ),
    (
        "Robot1_Groundtruth.dat",
        "# only a comment\n\n# and another\n",
        r"Robot1_Groundtruth.dat: no data lines",
    ),
    ("Robot1_Groundtruth.dat", "", r"Robot1_Groundtruth.dat: no data lines"),
    (
        "Robot1_Measurement.dat",
        _lines(
            "Robot1_Measurement.dat", "0.05 63 1.5 0.1", "# a comment between\n", "0.25 25 2.0 -0.2", "0.15 63 1.4 0.1"
        ),
        # the backwards jump is on line 6 (header, row, comment, blank, row, row)
        r"Robot1_Measurement.dat, line 6: time 0.15 s is earlier than 0.25 s on line 5",
    ),
    (
        "Robot1_Measurement.dat",
        _lines("Robot1_Measurement.dat", "0.05 63 1.5 0.1", "0.15 25 inf -0.2"),
        r"Robot1_Measurement.dat, line 3, column 3: inf is not a finite number",
    ),
    (
        "Robot1_Measurement.dat",
        _lines("Robot1_Measurement.dat", "0.05 63 1.5 0.1", "0.15,25,2.0,-0.2"),
        r"Robot1_Measurement.dat, line 3: expected 4 numbers, found 1",
    ),
    (
        "Robot1_Measurement.dat",
        b"# t barcode range bearing\n0.05 63 1.5 0.1\n0.15 25 \xff\xfe -0.2\n",
        r"Robot1_Measurement.dat, line 3, column 3: .* is not a number",
    ),
    ("Barcodes.dat", "# subject barcode\n1 5\n2\n", r"Barcodes.dat, line 3: expected 2 numbers, found 1"),
    (
        "Landmark_Groundtruth.dat",
        "# subject x y sdx sdy\n6 1.0 2.0 0.01 0.01\n7 3.0 NaN 0.01 0.01\n",
        r"Landmark_Groundtruth.dat, line 3, column 3: nan is not a finite number",
    ),
]


@pytest.mark.parametrize("name, text, message", MRCLAM_CASES, ids=[f"{c[0]}-{i}" for i, c in enumerate(MRCLAM_CASES)])
def test_mrclam_refuses_a_corrupted_file_naming_file_and_line(tmp_path, name, text, message):
    folder = _mrclam(tmp_path / "data", **{name: text})
    with pytest.raises(ValueError, match=message) as err:
        mrclam.load_robot(1, folder)
    assert str(folder / name) in str(err.value)


def test_mrclam_measurements_out_of_order_are_refused_not_reordered(tmp_path):
    """A clock that jumps back must not silently re-sort (and so misplace) the measurements after it."""
    rows = [f"{0.01 * i:.2f} 63 1.5 0.1" for i in range(1, 20)]
    rows[12:] = [f"{float(r.split()[0]) - 0.1:.2f} 63 1.5 0.1" for r in rows[12:]]
    folder = _mrclam(tmp_path, **{"Robot1_Measurement.dat": _lines("Robot1_Measurement.dat", *rows)})
    with pytest.raises(ValueError, match=r"line 14: time 0\.03 s is earlier than 0\.12 s on line 13 \(1 such line"):
        mrclam.load_robot(1, folder)


def test_mrclam_missing_files_are_named(tmp_path):
    folder = _mrclam(tmp_path, **{"Robot1_Odometry.dat": None})
    with pytest.raises(FileNotFoundError, match=r"Robot1_Odometry.dat not found"):
        mrclam.load_robot(1, folder)
    with pytest.raises(FileNotFoundError, match=r"utias-mrclam-dataset7.*download.*asrl\.utias\.utoronto\.ca"):
        mrclam.data_dir(tmp_path / "nowhere")


def test_mrclam_hand_made_non_finite_streams_never_become_nan_controls(tmp_path):
    """One NaN odometry sample would turn every later control into NaN (the integral is cumulative):
    :func:`to_filter_steps` refuses it, and refuses readings whose integral overflows."""
    robot = mrclam.load_robot(1, _mrclam(tmp_path))
    v = np.array(robot.odometry.v)
    v[1] = np.nan
    bad = robot._replace(odometry=robot.odometry._replace(v=v))
    with pytest.raises(ValueError, match=r"robot_data\.odometry\.v contains NaN or infinite values"):
        mrclam.to_filter_steps(bad, dt=0.1)
    x = np.array(robot.ground_truth.x)
    x[2] = np.inf
    with pytest.raises(ValueError, match=r"robot_data\.groundtruth\.x"):
        mrclam.to_filter_steps(robot._replace(ground_truth=robot.ground_truth._replace(x=x)), dt=0.1)
    # finite readings whose integral overflows float64 (1e308 m/s over 10 s)
    t = 0.1 * np.arange(101)
    folder = _mrclam(
        tmp_path / "huge",
        **{
            "Robot1_Odometry.dat": _lines("Robot1_Odometry.dat", *(f"{x:.1f} 1e308 0.0" for x in t)),
            "Robot1_Groundtruth.dat": _lines("Robot1_Groundtruth.dat", *(f"{x:.1f} 0.0 0.0 0.0" for x in t)),
        },
    )
    with pytest.raises(ValueError, match=r"non-finite controls from step \d+ .*velocities are too large"):
        mrclam.to_filter_steps(mrclam.load_robot(1, folder), dt=0.1)


# ---------------------------------------------------------------------------
# AdaRF: gzipped CSV with a BOM, one file per aperture point, and a ground-truth CSV

HEADER = "epc,antennaIndex,frequency,time,RSSI,phase,dopplerShift,velocity,x,y,z,angle"
STRAY = "000000000000000000000005"


def _point_rows(p, reads=3):
    """Rows of aperture point ``p``: ``reads`` reads of each target tag on each channel, and one stray read."""
    x = 0.02 * (p + 1)
    rows = [
        f"{epc},1,{int(f)},0,-50.5,{(0.1 * (t + c + r)) % 6.28:.4f},0,0,{x:.3f},1.63,0,0"
        for t, epc in enumerate(adarf.TARGET_EPCS)
        for c, f in enumerate(adarf.CHANNELS_HZ)
        for r in range(reads)
    ]
    return rows + [f"{STRAY},1,{int(adarf.CHANNELS_HZ[0])},0,-60,1.0,0,0,{x:.3f},1.63,0,0"]


def _gz(rows, header=HEADER):
    return gzip.compress(("\n".join([header, *rows]) + "\n").encode("utf-8-sig"), mtime=0)


def _adarf(root, name="x", points=None, truth=None):
    """A synthetic AdaRF layout with experiment ``name``; ``points`` maps a point to its file's bytes (None: absent)."""
    folder = root / adarf.DATASET
    exp = folder / "dataset1_test" / name
    exp.mkdir(parents=True, exist_ok=True)
    default_truth = "experiment,epc,x_m,y_m\n" + "".join(
        f"{name},{e},{0.3 + 0.2 * i},0.8\n" for i, e in enumerate(adarf.TARGET_EPCS)
    )
    (folder / "tag_ground_truth.csv").write_text(default_truth if truth is None else truth, encoding="utf-8-sig")
    points = points or {}
    for p in range(adarf.NUM_POINTS):
        data = points.get(p, _gz(_point_rows(p)))
        if data is not None:
            (exp / f"{p}.csv.gz").write_bytes(data)
    return root


def _load(root, name="x"):
    return adarf.load_experiment(name, root)


def test_the_synthetic_adarf_copy_loads(tmp_path):
    exp = _load(_adarf(tmp_path))
    assert exp.tag.shape == (adarf.NUM_POINTS * 3 * 8 * 3,) and exp.num_stray == adarf.NUM_POINTS
    assert np.all(np.isfinite(exp.phase)) and set(np.unique(exp.channel)) == set(range(8))


def _with_row(p, index, row):
    rows = _point_rows(p)
    rows[index] = row
    return _gz(rows)


_GOOD = _point_rows(3)[4].split(",")  # a target read of point 3, on line 6 of its file (header first)


def _field(name, value):
    row = list(_GOOD)
    row[HEADER.split(",").index(name)] = value
    return ",".join(row)


ADARF_CASES = [
    # (point 3's file content, the message after "<path>")
    (_gz(_point_rows(3))[:150], r"3\.csv\.gz: unreadable after line \d+ \(EOFError.*truncated or corrupted"),
    (("\n".join([HEADER, *_point_rows(3)])).encode(), r"3\.csv\.gz: unreadable after line 0 \(BadGzipFile"),
    (b"", r"3\.csv\.gz: empty file"),
    (_gz([], header=""), r"3\.csv\.gz: empty file|3\.csv\.gz: missing columns"),
    (
        _with_row(3, 4, ",".join(_GOOD[:3])),
        r"3\.csv\.gz, line 6: 3 field\(s\), the header has 12; the line is cut short",
    ),
    (_with_row(3, 4, _field("phase", "abc")), r"3\.csv\.gz, line 6, column 'phase': 'abc' is not a number"),
    (_with_row(3, 4, _field("phase", "nan")), r"3\.csv\.gz, line 6, column 'phase': 'nan' is not a finite number"),
    (_with_row(3, 4, _field("x", "inf")), r"3\.csv\.gz, line 6, column 'x': 'inf' is not a finite number"),
    (_with_row(3, 4, _field("RSSI", "-inf")), r"3\.csv\.gz, line 6, column 'RSSI': '-inf' is not a finite number"),
    (_with_row(3, 4, _field("frequency", "NaN")), r"3\.csv\.gz, line 6, column 'frequency': 'NaN' is not a finite"),
    (_with_row(3, 4, _field("frequency", "915000000")), r"3\.csv\.gz, line 6: frequency 915000000 Hz is not one of"),
    (_with_row(3, 4, _field("phase", "7.5")), r"3\.csv\.gz, line 6, column 'phase': 7\.5 rad is outside \[0, 2π\]"),
    (_with_row(3, 4, _field("x", "0.5")), r"3\.csv\.gz: one file must hold one aperture point"),
    (
        gzip.compress(("\ufeff" + HEADER + "\n" + "\n".join(_point_rows(3))).encode()[:-40] + b"\xff\xfe\n"),
        r"3\.csv\.gz: unreadable after line \d+ \(UnicodeDecodeError",
    ),
    (_gz([r for r in _point_rows(3) if r.startswith(STRAY)]), r"3\.csv\.gz: no reads of the target tags"),
]


@pytest.mark.parametrize("content, message", ADARF_CASES, ids=[f"case{i}" for i in range(len(ADARF_CASES))])
def test_adarf_refuses_a_corrupted_point_file_naming_file_and_line(tmp_path, content, message):
    root = _adarf(tmp_path, points={3: content})
    with pytest.raises(ValueError, match=message) as err:
        _load(root)
    assert str(tmp_path / adarf.DATASET / "dataset1_test" / "x" / "3.csv.gz") in str(err.value)


def test_adarf_missing_point_file_is_named(tmp_path):
    root = _adarf(tmp_path, points={7: None})
    with pytest.raises(FileNotFoundError, match=r"7\.csv\.gz is missing: experiment x needs files 0\.\.49"):
        _load(root)
    assert "x" not in adarf.available_experiments(root)


TRUTH_CASES = [
    (
        "experiment,epc,x_m,y_m\nx,{0},0.3,0.8\nx,{1},nan,0.8\nx,{2},0.7,0.8\n",
        r"line 3, column 'x_m': 'nan' is not a finite",
    ),
    (
        "experiment,epc,x_m,y_m\nx,{0},0.3,0.8\nx,{1},0.5,inf\nx,{2},0.7,0.8\n",
        r"line 3, column 'y_m': 'inf' is not a finite",
    ),
    (
        "experiment,epc,x_m,y_m\nx,{0},0.3,0.8\nx,{1},0.5,far\nx,{2},0.7,0.8\n",
        r"line 3, column 'y_m': 'far' is not a number",
    ),
    ("experiment,epc,x_m,y_m\nx,{0},0.3,0.8\nx,{1},0.5\nx,{2},0.7,0.8\n", r"line 3: 3 field\(s\), the header has 4"),
    ("experiment,epc,x,y\nx,{0},0.3,0.8\n", r"missing columns \['x_m', 'y_m'\]"),
    ("experiment,epc,x_m,y_m\nx,{0},0.3,0.8\nx,{1},0.5,0.8\n", r"experiment x has no ground truth for EPC"),
    ("", r"tag_ground_truth\.csv: empty file"),
]


@pytest.mark.parametrize("truth, message", TRUTH_CASES, ids=[f"truth{i}" for i in range(len(TRUTH_CASES))])
def test_adarf_refuses_a_corrupted_ground_truth_naming_file_and_line(tmp_path, truth, message):
    root = _adarf(tmp_path, truth=truth.format(*adarf.TARGET_EPCS))
    with pytest.raises(ValueError, match=message) as err:
        _load(root)
    assert str(tmp_path / adarf.DATASET / "tag_ground_truth.csv") in str(err.value)


def test_adarf_missing_data_says_where_to_get_it(tmp_path):
    with pytest.raises(FileNotFoundError, match=re.escape("https://github.com/dapowan/AdaRF")) as err:
        adarf.data_dir(tmp_path)
    assert "root=" in str(err.value) and adarf.ENV_VAR in str(err.value)
