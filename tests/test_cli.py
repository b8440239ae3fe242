"""The ``jaxnav`` command, run as a user would (a subprocess, from outside the repository).

The refusals and the listing run :func:`jaxnav.cli.main` in this process instead: a subprocess spends
most of its time importing jax, and the exit status and output are the same.
"""

import os
import subprocess
import sys

import pytest

import jaxnav


def _jaxnav(*args, cwd):
    return subprocess.run(
        [sys.executable, "-m", "jaxnav.cli", *args], cwd=cwd, capture_output=True, text=True, timeout=600
    )


def _jaxnav_in_process(capsys, *args):
    """``jaxnav ARGS`` by :func:`jaxnav.cli.main`: ``(exit status, stdout, stderr)``."""
    from jaxnav.cli import main

    capsys.readouterr()
    try:
        status = main(list(args))
    except SystemExit as exit:  # argparse's refusals
        status = exit.code
    out = capsys.readouterr()
    return status, out.out, out.err


def test_version(tmp_path):
    out = _jaxnav("--version", cwd=tmp_path)
    assert out.returncode == 0
    assert out.stdout.strip() == f"jaxnav {jaxnav.__version__}"


def test_demo_prints_errors_and_writes_png(tmp_path):
    pytest.importorskip("matplotlib")
    png = tmp_path / "paths.png"
    out = _jaxnav("demo", "--steps", "60", "--out", str(png), cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert "position error [m]" in out.stdout
    rows = [line.split() for line in out.stdout.splitlines() if line.strip()[:1].isdigit()]
    errors = {int(r[0]): float(r[2]) for r in rows}
    assert max(errors) == 60
    assert errors[60] < 0.2
    assert png.exists() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert os.path.getsize(png) > 10_000


def test_demo_rejects_bad_arguments(capsys):
    status, _, err = _jaxnav_in_process(capsys, "demo", "--steps", "0", "--out", "")
    assert status == 2
    assert err == "jaxnav demo: error: argument --steps: must be a positive integer, got 0 (see 'jaxnav demo --help')\n"


def test_mrclam_algorithm_list_matches_the_experiment():
    from jaxnav.cli import MRCLAM_ALGORITHMS
    from jaxnav.experiments.mrclam import ALGORITHMS

    assert MRCLAM_ALGORITHMS == ALGORITHMS


def test_uwb_algorithm_list_matches_the_experiment():
    from jaxnav.cli import UWB_ALGORITHMS
    from jaxnav.experiments.uwb import ALGORITHMS

    assert UWB_ALGORITHMS == ALGORITHMS


def test_hf_slam_choices_match_the_experiment():
    from jaxnav.cli import HF_METHODS, HF_TRAJECTORIES
    from jaxnav.experiments.hf_slam import METHODS, TRAJECTORIES

    assert HF_METHODS == METHODS and HF_TRAJECTORIES == TRAJECTORIES


def test_ir_choices_match_the_experiment():
    from jaxnav.cli import IR_DRIVES, IR_LAYOUTS
    from jaxnav.experiments.ir.positioning import DRIVES, LAYOUTS

    assert IR_LAYOUTS == LAYOUTS and IR_DRIVES == DRIVES


def test_ir_runs_a_drive_and_writes_png(tmp_path):
    """``jaxnav ir --drive rotation``: the filter localises (error well under the odometry's) and draws it."""
    pytest.importorskip("matplotlib")
    out = _jaxnav("ir", "--drive", "rotation", "--out", str(tmp_path / "ir"), cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    rows = {
        line.split()[0]: line.split() for line in out.stdout.splitlines() if line.startswith(("IR MCL", "odometry"))
    }
    mcl_dr, odo_dr = float(rows["IR"][5]), float(rows["odometry"][4])
    assert mcl_dr < 0.5 * odo_dr, out.stdout
    assert (tmp_path / "ir.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize(
    "args, message",
    [
        (("--height", "0"), "height"),
        (("--failed-code", "12"), "--failed-code"),
        (("--speed-mm", "-5"), "speed"),
    ],
)
def test_ir_rejects_bad_arguments(capsys, args, message):
    status, _, err = _jaxnav_in_process(capsys, "ir", *args, "--out", "")
    assert status == 2
    assert message in err


def test_ir_says_when_the_filter_never_started(capsys):
    """Receivers 100 m below the emitters decode nothing: the filter never starts, and the command says
    so instead of a start time, and prints no errors for the meaningless estimate of its uniform cloud."""
    from jaxnav.cli import main

    argv = ["ir", "--height", "100", "--drive", "rotation", "--particles", "50", "--out", ""]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "0 receiver detections; localization never started (no unique ID was decoded)" in out
    assert "started at" not in out
    mcl = next(line.split() for line in out.splitlines() if line.startswith("IR MCL"))
    assert mcl[2:] == ["n/a"] * 8
    odometry = next(line.split() for line in out.splitlines() if line.startswith("odometry"))
    assert all(float(v) > 0 for v in odometry[1:])


def test_experiments_list_names_the_ir_experiments(capsys):
    status, out, _ = _jaxnav_in_process(capsys, "experiments", "list")
    assert status == 0
    for name in ("table-5.2", "table-5.3", "ir-failure", "ir-speeds", "ir-rotation"):
        assert name in out


def test_uhf_real_weightings_match_the_filter():
    from jaxnav.cli import UHF_WEIGHTINGS
    from jaxnav.localization.rfid_tag import WEIGHTINGS

    assert UHF_WEIGHTINGS == WEIGHTINGS


@pytest.fixture
def adarf_dir():
    from jaxnav.io import adarf

    try:
        return str(adarf.data_dir())
    except FileNotFoundError as err:
        pytest.skip(f"the AdaRF data are not available: {err}")


def test_uhf_real_localizes_the_real_tags(tmp_path, adarf_dir):
    """``jaxnav uhf-real``: a row per tag, errors under the prior's spread, a PNG."""
    pytest.importorskip("matplotlib")
    out = _jaxnav(
        "uhf-real",
        "--weightings",
        "phase",
        "--particles",
        "2000",
        "--data",
        adarf_dir,
        "--out",
        str(tmp_path / "u"),
        cwd=tmp_path,
    )
    assert out.returncode == 0, out.stderr
    rows = [line.split() for line in out.stdout.splitlines() if line.startswith("181218-01-50-8")]
    assert [r[1] for r in rows] == ["0", "1", "2"]
    for r in rows:
        assert float(r[3]) < float(r[8]), out.stdout  # final error below the uniform guess's RMS error
    assert (tmp_path / "u-181218-01-50-8.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize(
    "args, message",
    [
        (("--weightings", "loud"), "weighting"),
        (("--particles", "0"), "--particles"),
        (("--experiment", "no-such"), "unknown experiment"),
    ],
)
def test_uhf_real_rejects_bad_arguments(capsys, adarf_dir, args, message):
    status, _, err = _jaxnav_in_process(capsys, "uhf-real", *args, "--data", adarf_dir, "--out", "")
    assert status == 2
    assert message in err
