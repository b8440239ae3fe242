"""The ``jaxnav`` command, run as a user would (a subprocess, from outside the repository).

The refusals and the listing run :func:`jaxnav.cli.main` in this process instead: a subprocess spends
most of its time importing jax, and the exit status and output are the same. So do the forms of
``--out`` (a file, a folder, the deprecated forms, the defaults), with every computation replaced by a
fake that returns at once.
"""

import dataclasses
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
    out = _jaxnav("ir", "--drive", "rotation", "--out", str(tmp_path / "ir.png"), cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    rows = {
        line.split()[0]: line.split() for line in out.stdout.splitlines() if line.startswith(("IR MCL", "odometry"))
    }
    mcl_dr, odo_dr = float(rows["IR"][5]), float(rows["odometry"][4])
    assert mcl_dr < 0.5 * odo_dr, out.stdout
    assert (tmp_path / "ir.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and "deprecated" not in out.stderr


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
    """``jaxnav uhf-real``: a row per tag, errors under the prior's spread, a PNG in the folder --out."""
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
        str(tmp_path / "u") + os.sep,
        cwd=tmp_path,
    )
    assert out.returncode == 0, out.stderr
    rows = [line.split() for line in out.stdout.splitlines() if line.startswith("181218-01-50-8")]
    assert [r[1] for r in rows] == ["0", "1", "2"]
    for r in rows:
        assert float(r[3]) < float(r[8]), out.stdout  # final error below the uniform guess's RMS error
    assert (tmp_path / "u" / "181218-01-50-8.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "deprecated" not in out.stderr


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


# ---------------------------------------------------------------------------
# --out: a FILE for a command that draws one figure, a FOLDER for one that writes several; the forms of
# earlier releases still work, with a deprecation warning. The computations are replaced by fakes that
# return at once (the command's own handling of --out is what is tested), the plots by a writer of
# FIGURE.

FIGURE = b"a figure"


@pytest.fixture
def fake_runs(monkeypatch, tmp_path):
    """Every command computes nothing and draws FIGURE; the data folders are found in ``tmp_path``."""
    from types import SimpleNamespace as NS

    import numpy as np

    from jaxnav import demo
    from jaxnav.experiments import hf_slam, registry
    from jaxnav.experiments import mrclam as mrclam_xp
    from jaxnav.experiments import sweep as sw
    from jaxnav.experiments import uwb as uwb_xp
    from jaxnav.experiments.hf_slam import ERROR_COLUMNS
    from jaxnav.experiments.ir import positioning
    from jaxnav.experiments.uhf import real
    from jaxnav.io import adarf
    from jaxnav.io import mrclam as mrclam_io
    from jaxnav.io import uwb as uwb_io

    def draw(*args):
        with open(args[-1], "wb") as fh:  # the path is the last argument of every plot function
            fh.write(FIGURE)

    def text(*args, **kwargs):
        return "(table)"

    steps = np.zeros((5, 3))
    hf_run = NS(
        odometry=steps,
        detections=NS(mask=np.zeros((5, 2), bool)),
        true_poses=steps,
        kidnapped=np.zeros(5, bool),
    )
    hf_world = NS(run=hf_run, carpet=NS(layout=NS(num_tags=4)))
    hf_result = NS(seen=np.zeros(4, bool), lost=np.zeros(5, bool))
    drive = NS(
        sim=NS(controls=steps, detections=NS(valid=np.zeros(5, bool))),
        inputs=NS(record=np.zeros(5, int)),
        mcl=None,
        dead=None,
    )
    mrclam_seq = NS(controls=steps, dt=0.1, num_placed=0, num_outliers=0)
    uwb_seq = NS(times=np.arange(3.0), anchors=np.zeros((4, 2)))

    def sweep(cells, runs, key, path, chunk_size, progress, **kwargs):
        rng = np.random.default_rng(0)
        return {c[0]: {col: rng.uniform(10, 50, runs) for col in ERROR_COLUMNS} for c in cells}

    for module, name, fake in [
        (demo, "run_demo", lambda seed, num_steps, num_particles: NS(dt=0.25, position_error=np.ones(num_steps))),
        (demo, "plot_demo", draw),
        (mrclam_io, "data_dir", lambda root=None: tmp_path),
        (mrclam_xp, "run_robot", lambda robot, algorithms, **kwargs: (mrclam_seq, [])),
        (mrclam_xp, "plot_robot", draw),
        (mrclam_xp, "format_table", text),
        (uwb_io, "data_dir", lambda root=None: tmp_path),
        (uwb_xp, "run_study", lambda algorithms, **kwargs: (uwb_seq, [])),
        (uwb_xp, "plot_study", draw),
        (uwb_xp, "format_table", text),
        (hf_slam, "run_once_compiled", lambda key, method, setting: (None, hf_world, hf_result)),
        (hf_slam, "dead_reckoning", lambda run: steps),
        (hf_slam, "format_errors", text),
        (hf_slam, "plot_run", draw),
        (positioning, "drive_once", lambda key, setting: drive),
        (positioning, "describe_start", text),
        (positioning, "format_errors", text),
        (positioning, "plot_drive", draw),
        (adarf, "data_dir", lambda root=None: tmp_path),
        (adarf, "available_experiments", lambda root=None: ("e1", "e2")),
        (real, "localize", lambda name, weightings, setting, **kwargs: name),
        (real, "format_results", text),
        (real, "plot_results", draw),
        (sw, "sweep", sweep),
    ]:
        monkeypatch.setattr(module, name, fake)
    get = registry.get  # the experiments' figures too
    monkeypatch.setattr(registry, "get", lambda name: dataclasses.replace(get(name), plot=draw))
    return tmp_path


def _written(folder) -> dict[str, bytes]:
    """The files under ``folder`` (paths relative to it) and their contents."""
    return {
        os.path.relpath(os.path.join(parent, name), folder): open(os.path.join(parent, name), "rb").read()
        for parent, _, names in os.walk(folder)
        for name in names
    }


MRCLAM = ["mrclam", "--robots", "1,2", "--algorithms", "ekf"]
UHF = ["uhf-real", "--experiment", "all", "--particles", "10"]
HF = ["hf-slam", "--laps", "1", "--robot-particles", "10", "--tag-particles", "5"]
IR = ["ir", "--drive", "rotation", "--particles", "10"]
XP = ["experiments", "run", "table-3.1", "--runs", "2", "--no-progress"]

# (argv without --out, --out, the files written under the current folder and their contents)
OUT_FORMS = [
    # one figure: the FILE as given, its extension the format
    (["demo", "--steps", "3"], "d/plot.png", {"d/plot.png": FIGURE}),
    (["demo", "--steps", "3"], "d/plot.svg", {"d/plot.svg": FIGURE}),
    (["demo", "--steps", "3"], "d/plot", {"d/plot": FIGURE}),  # as given, as it always was for demo
    (["uwb", "--runs", "1"], "d/uwb.pdf", {"d/uwb.pdf": FIGURE}),
    (HF, "d/run.png", {"d/run.png": FIGURE}),  # not run.png.png
    (HF, "d/run.pdf", {"d/run.pdf": FIGURE}),
    (IR, "d/drive.png", {"d/drive.png": FIGURE}),
    (IR, "d/drive.SVG", {"d/drive.SVG": FIGURE}),
    # several files: the FOLDER, created if missing (a name ending in /, or an existing folder)
    (MRCLAM, "d/mr/", {"d/mr/robot1.png": FIGURE, "d/mr/robot2.png": FIGURE}),
    (MRCLAM, "d", {"d/robot1.png": FIGURE, "d/robot2.png": FIGURE}),
    (UHF, "d/new/uhf/", {"d/new/uhf/e1.png": FIGURE, "d/new/uhf/e2.png": FIGURE}),
    (UHF, "d", {"d/e1.png": FIGURE, "d/e2.png": FIGURE}),
]


@pytest.mark.parametrize("argv, out, files", OUT_FORMS, ids=[f"{a[0]} --out {o}" for a, o, _ in OUT_FORMS])
def test_out_is_a_file_or_a_folder(argv, out, files, fake_runs, monkeypatch, capsys):
    """The new form of ``--out``: each file written where it says, without a warning, and named in the output."""
    monkeypatch.chdir(fake_runs)
    os.mkdir("d")
    status, stdout, err = _jaxnav_in_process(capsys, *argv, "--out", out)
    assert (status, err) == (0, ""), err
    assert _written("d") == {os.path.relpath(path, "d"): data for path, data in files.items()}
    for path in files:
        assert f"wrote {path}\n" in stdout, stdout


# (argv without --out, the old --out, the files written, what the warning says)
OLD_FORMS = [
    (HF, "d/run", {"d/run.png": FIGURE}, "--out 'd/run' has no figure extension: d/run.png is written, as before"),
    (HF, "d/run.v2", {"d/run.v2.png": FIGURE}, "give the extension (--out d/run.v2.png)"),
    (IR, "d/ir", {"d/ir.png": FIGURE}, "--out 'd/ir' has no figure extension: d/ir.png is written, as before"),
    (
        MRCLAM,
        "d/mr",
        {"d/mr-robot1.png": FIGURE, "d/mr-robot2.png": FIGURE},
        "--out 'd/mr' is read as a prefix (d/mr-robot1.png, …), as before; --out now names a folder: "
        "give --out d/mr/ to write d/mr/robot1.png, …",
    ),
    (
        UHF,
        "d/u",
        {"d/u-e1.png": FIGURE, "d/u-e2.png": FIGURE},
        "--out 'd/u' is read as a prefix (d/u-e1.png, …), as before; --out now names a folder: "
        "give --out d/u/ to write d/u/e1.png, …",
    ),
]


@pytest.mark.parametrize("argv, out, files, says", OLD_FORMS, ids=[f"{a[0]} --out {o}" for a, o, _, _ in OLD_FORMS])
def test_the_old_forms_of_out_still_work_with_a_warning(argv, out, files, says, fake_runs, monkeypatch, capsys):
    """The forms of earlier releases write what they wrote (never ``NAME.png.png``), and say, in one line on
    stderr, that they are deprecated and what to give instead."""
    monkeypatch.chdir(fake_runs)
    os.mkdir("d")
    status, stdout, err = _jaxnav_in_process(capsys, *argv, "--out", out)
    assert status == 0, err
    assert _written("d") == {os.path.relpath(path, "d"): data for path, data in files.items()}
    assert err.count("\n") == 1 and err.startswith(f"jaxnav {argv[0]}: warning: deprecated: "), err
    assert says in err, err
    assert "next release" in err
    for path in files:
        assert f"wrote {path}\n" in stdout, stdout


DEFAULTS = [
    (["demo", "--steps", "3"], ["jaxnav-demo.png"]),
    (["uwb", "--runs", "1"], ["jaxnav-uwb.png"]),
    (HF, ["jaxnav-hf-slam.png"]),
    (IR, ["jaxnav-ir.png"]),
    (MRCLAM, ["jaxnav-mrclam/robot1.png", "jaxnav-mrclam/robot2.png"]),
    (UHF, ["jaxnav-uhf-real/e1.png", "jaxnav-uhf-real/e2.png"]),
]


@pytest.mark.parametrize("argv, files", DEFAULTS, ids=[a[0] for a, _ in DEFAULTS])
def test_out_defaults_are_those_the_help_shows(argv, files, fake_runs, monkeypatch, capsys):
    """Without ``--out``, the default its ``--help`` names is written (a folder ends in /), with no warning;
    with ``--out ''`` nothing is."""
    from jaxnav import cli

    monkeypatch.chdir(fake_runs)
    status, _, err = _jaxnav_in_process(capsys, *argv)
    assert (status, err) == (0, ""), err
    assert sorted(_written(".")) == [os.path.normpath(f) for f in files]
    default = cli.build_parser().parse_args(argv).out
    assert default in {files[0], os.path.dirname(files[0]) + "/"}
    for path in files:
        os.remove(path)
    status, _, err = _jaxnav_in_process(capsys, *argv, "--out", "")
    assert (status, err) == (0, ""), err
    assert _written(".") == {}


@pytest.mark.parametrize("command", ["demo", "mrclam", "uwb", "hf-slam", "ir", "uhf-real", "experiments"])
def test_every_help_says_what_out_is_and_its_default(command, capsys):
    from jaxnav import cli

    with pytest.raises(SystemExit):
        cli.main([command, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    default = cli.build_parser().parse_args([command]).out
    kind = "--out DIR folder for" if default.endswith("/") else "--out FILE figure file; its extension"
    assert kind in text, text
    assert f"default {default})" in text, text


def test_experiments_writes_into_its_folder_created_if_missing(fake_runs, monkeypatch, capsys):
    """``experiments run --out DIR``: DIR and its parents are created; a name without / is a folder too."""
    monkeypatch.chdir(fake_runs)
    for out in ("new/xp", "other/"):
        status, stdout, err = _jaxnav_in_process(capsys, *XP, "--out", out)
        assert (status, err) == (0, ""), err
        names = sorted(os.listdir(out))
        assert names == ["table-3.1.json", "table-3.1.md", "table-3.1.png"], names  # the fake sweep keeps no runs
        assert open(os.path.join(out, "table-3.1.png"), "rb").read() == FIGURE
        assert f"wrote {os.path.join(out, 'table-3.1.png')}" in stdout


def test_experiments_out_empty_is_the_current_folder_with_a_deprecation(fake_runs, monkeypatch, capsys):
    """``experiments run --out ''`` wrote into the current folder; it still does, and says to give ``.``."""
    monkeypatch.chdir(fake_runs)
    status, stdout, err = _jaxnav_in_process(capsys, *XP, "--out", "")
    assert status == 0, err
    assert sorted(n for n in os.listdir(".") if n.startswith("table-3.1")) == [
        "table-3.1.json",
        "table-3.1.md",
        "table-3.1.png",
    ]
    assert err == (
        "jaxnav experiments: warning: deprecated: --out '' is read as the current folder, as before; give "
        "--out . for it (the next release refuses '': a run's results are its files)\n"
    )


def test_a_figure_format_matplotlib_does_not_write_is_refused_before_computing(fake_runs, monkeypatch, capsys):
    from jaxnav import demo

    monkeypatch.setattr(demo, "run_demo", lambda **kwargs: pytest.fail("computed before refusing --out"))
    monkeypatch.chdir(fake_runs)
    status, _, err = _jaxnav_in_process(capsys, "demo", "--out", "paths.txt")
    assert status == 2
    assert err.startswith("jaxnav demo: error: --out 'paths.txt': .txt is not a figure format; end the name in ")
    assert ".png, .pdf, .svg" in err and err.count("\n") == 1
    assert _written(".") == {}
