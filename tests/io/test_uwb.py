"""The TU Chemnitz Labyrinth UWB loader (jaxnav.io.uwb): the real log, and corrupted synthetic copies.

The real-data tests read ``$JAXNAV_DATA`` (default ``../shared/data``) and skip, saying so, only when
the folder is absent; the corrupted files are written to ``tmp_path``.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

from jaxnav.io import uwb

try:
    uwb.data_dir()
    _MISSING = None
except FileNotFoundError as err:  # pragma: no cover - depends on the machine
    _MISSING = str(err)

needs_data = pytest.mark.skipif(_MISSING is not None, reason=f"UWB data not found: {_MISSING}")


@needs_data
def test_the_log_as_filter_steps():
    """233 steps of about 0.128 s (0.127–0.176 s), one range per step to the four anchors in turn, the anchors where the
    dataset's notes put them, the wheel base doubled and the wheels swapped (libRSF's convention, module
    docstring), and the range residual against the ground truth that the notes report."""
    seq = uwb.load_labyrinth()
    assert seq.times.shape == (233,) and seq.controls.shape == (233, 3)
    assert seq.observations.z.shape == (233, 1, 1) and seq.observations.mask.all()
    assert seq.anchor_ids == (105, 107, 108, 109)
    np.testing.assert_allclose(seq.anchors, [[-0.02, -0.01], [-0.02, 2.365], [2.385, 2.36], [2.385, -0.005]])
    assert seq.wheel_base == pytest.approx(0.157)
    assert seq.controls[0, 2] == 0.0 and np.all(np.abs(seq.controls[1:, 2] - 0.128) < 0.05)
    np.testing.assert_array_equal(seq.observations.ids[:8, 0], [0, 1, 2, 3, 0, 1, 2, 3])
    distance = np.linalg.norm(seq.true_positions - seq.anchors[seq.observations.ids[:, 0]], axis=1)
    residual = seq.observations.z[:, 0, 0] - distance
    assert 0.11 < residual.mean() < 0.13 and 0.10 < residual.std() < 0.12
    np.testing.assert_allclose(seq.initial_pose[:2], seq.true_positions[0])


@needs_data
def test_dead_reckoning_follows_the_path_with_the_documented_convention():
    """Measured: a mean position error of 0.199 m over the 30 s from the true start; with the columns
    read as named and the wheel base as stated, 1.68 m."""
    seq = uwb.load_labyrinth()
    error = np.linalg.norm(np.asarray(uwb.dead_reckoning(seq))[:, :2] - seq.true_positions, axis=1)
    assert error.mean() < 0.25, error.mean()
    as_named = seq._replace(controls=seq.controls[:, [1, 0, 2]], wheel_base=seq.wheel_base / 2)
    error_as_named = np.linalg.norm(np.asarray(uwb.dead_reckoning(as_named))[:, :2] - seq.true_positions, axis=1)
    assert error_as_named.mean() > 1.0, error_as_named.mean()


# ---------------------------------------------------------------------------
# corrupted copies

RANGES = [
    "range2 0.1 2.9 0.01 -0.02 -0.01 105 0",
    "range2 0.2 1.6 0.01 -0.02 2.365 107 0",
    "range2 0.3 0.9 0.01 2.385 2.36 108 0",
]
ODOMETRY = [
    "odom2diff 0.1 0 0 0 0.0785 0.0001 0.0001 0.0001",
    "odom2diff 0.2 0.1 0.1 0 0.0785 0.0001 0.0001 0.0001",
    "odom2diff 0.3 0.1 0.12 0 0.0785 0.0001 0.0001 0.0001",
]
TRUTH = ["point2 0.1 1.0 2.0 0 0 0 0", "point2 0.2 0.99 2.0 0 0 0 0", "point2 0.3 0.8 2.0 0 0 0 0"]


def _copy(folder, ranges=RANGES, odometry=ODOMETRY, truth=TRUTH):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "Indoor_UWB_Input.txt").write_text("\n".join(ranges + odometry) + "\n")
    (folder / "Indoor_UWB_GT.txt").write_text("\n".join(truth) + "\n")
    return folder


def test_a_well_formed_copy_loads_with_the_heading_of_its_first_tenth_of_a_metre(tmp_path):
    seq = uwb.load_labyrinth(_copy(tmp_path / "d"))
    assert seq.times.shape == (3,) and seq.anchors.shape == (3, 2)
    np.testing.assert_allclose(seq.initial_pose, [1.0, 2.0, np.pi])  # moved −x by 0.2 m at the third stamp
    np.testing.assert_allclose(seq.controls[1], [0.1, 0.1, 0.1])


@pytest.mark.parametrize(
    "change, message",
    [
        (
            {"ranges": RANGES[:1] + ["range2 0.2 1.6 0.01 -0.02 2.365 107"] + RANGES[2:]},
            r"Input\.txt, line 2: a range2 line holds 7",
        ),
        ({"ranges": RANGES[:2] + ["range2 0.3 abc 0.01 2.385 2.36 108 0"]}, r"line 3: .* not a number"),
        ({"ranges": RANGES[:2] + ["range2 0.3 nan 0.01 2.385 2.36 108 0"]}, r"line 3: .* not finite"),
        (
            {"ranges": RANGES[:2] + ["range2 0.3 0.9 0.01 2.0 2.0 105 0"]},
            r"line 3: anchor 105 at \(2, 2\) m, earlier at \(-0\.02, -0\.01\) m",
        ),
        ({"ranges": RANGES[:2] + ["range2 0.15 0.9 0.01 2.385 2.36 108 0"]}, r"line 3: time 0\.15 s does not follow"),
        ({"ranges": RANGES + ["scan2 0.4 1 2 3"]}, r"line 4: unknown measurement type 'scan2'"),
        ({"odometry": ODOMETRY[:2] + [ODOMETRY[2].replace("0.3 ", "0.35 ", 1)]}, r"line 6: odom2diff time 0\.35 s"),
        ({"odometry": ODOMETRY[:2]}, r"2 odom2diff lines for 3 time stamps"),
        ({"odometry": []}, r"holds no odom2diff lines"),
        (
            {"odometry": ODOMETRY[:2] + [ODOMETRY[2].replace("0.0785", "0.08")]},
            r"wheel base must be one positive value",
        ),
        ({"truth": TRUTH[:2] + ["point2 0.31 0.8 2.0 0 0 0 0"]}, r"GT\.txt, line 3: point2 time 0\.31 s"),
    ],
)
def test_a_corrupted_file_is_refused_naming_the_file_and_line(tmp_path, change, message):
    with pytest.raises(ValueError, match=message):
        uwb.load_labyrinth(_copy(tmp_path / "d", **change))


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no named pipes on this system")
def test_a_named_pipe_in_place_of_a_file_is_refused_without_blocking(tmp_path):
    folder = _copy(tmp_path / "d")
    (folder / "Indoor_UWB_GT.txt").unlink()
    os.mkfifo(folder / "Indoor_UWB_GT.txt")
    with pytest.raises(ValueError, match="named pipe"):
        uwb.load_labyrinth(folder)


def test_a_missing_folder_names_the_places_tried_and_the_source(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"tuc-labyrinth-uwb.*libRSF"):
        uwb.load_labyrinth(tmp_path / "nowhere")
