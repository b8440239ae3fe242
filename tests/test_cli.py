"""The ``jaxnav`` command, run as a user would (a subprocess, from outside the repository)."""

import os
import subprocess
import sys

import pytest

import jaxnav


def _jaxnav(*args, cwd):
    return subprocess.run([sys.executable, "-m", "jaxnav.cli", *args], cwd=cwd, capture_output=True, text=True, timeout=600)


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


def test_demo_rejects_bad_arguments(tmp_path):
    out = _jaxnav("demo", "--steps", "0", "--out", "", cwd=tmp_path)
    assert out.returncode == 2
    assert "--steps and --particles must be positive" in out.stderr


def test_mrclam_algorithm_list_matches_the_experiment():
    from jaxnav.cli import _MRCLAM_ALGORITHMS
    from jaxnav.experiments.mrclam import ALGORITHMS

    assert _MRCLAM_ALGORITHMS == ALGORITHMS


def test_hf_slam_choices_match_the_experiment():
    from jaxnav.cli import _HF_METHODS, _HF_TRAJECTORIES
    from jaxnav.experiments.hf_slam import METHODS, TRAJECTORIES

    assert _HF_METHODS == METHODS and _HF_TRAJECTORIES == TRAJECTORIES
