"""Bad input on the ``jaxnav`` command line: every refusal is one line on stderr, exit status 2, naming
the option or the file, never a traceback, and it comes before anything is computed.

Most cases run :func:`jaxnav.cli.main` in this process (fast): the functions that compute are
replaced by ones that fail the test if called, so a case passes only if its refusal precedes the
computation. A few cases run ``python -m jaxnav.cli`` as a user would, to show that no traceback
reaches a real stderr (and that the case that once hung is refused at once). Data files are small
synthetic copies of each dataset's layout in a temporary folder.
"""

from __future__ import annotations

import gzip
import os
import pathlib
import re
import subprocess
import sys
import tempfile

import pytest

from jaxnav import cli
from jaxnav.io import adarf

BIG = str(10**13)  # a size no machine holds

# (argv, a regular expression the one-line message must match); "{file}" is an existing regular
# file, "{dir}" an existing folder, "{nowhere}" a folder that does not exist, "{ro}" one that
# cannot be written (/proc), "{adarf}" a valid synthetic AdaRF copy
REFUSED = [
    # demo
    (["demo", "--steps", "0"], r"argument --steps: must be a positive integer, got 0"),
    (["demo", "--steps", "-3"], r"argument --steps: must be a positive integer"),
    (["demo", "--steps", "ten"], r"argument --steps: must be an integer, got 'ten'"),
    (["demo", "--particles", "0"], r"argument --particles: must be a positive integer"),
    (["demo", "--particles", "1e3"], r"argument --particles: must be an integer"),
    (["demo", "--particles", BIG], r"GiB of memory.*--particles"),
    (["demo", "--seed", "-1"], r"argument --seed: must be an integer in \[0, 2\*\*32\)"),
    (["demo", "--seed", str(2**40)], r"argument --seed: must be an integer in \[0, 2\*\*32\)"),
    (["demo", "--out", "{dir}"], r"--out .*is a folder, not a file"),
    (["demo", "--out", "{file}/x.png"], r"--out .*is a file, not a folder"),
    (["demo", "--out", "{nowhere}/x.png"], r"--out .*does not exist"),
    (["demo", "--out", "{ro}/x.png"], r"--out .*cannot write in"),
    (["demo", "--out", "{dir}/paths.txt"], r"--out .*paths\.txt': \.txt is not a figure format; end the name in one"),
    # mrclam
    (["mrclam", "--robots", "7"], r"--robots must be a comma-separated list of robots 1-5"),
    (["mrclam", "--robots", "one,two"], r"--robots must be a comma-separated list"),
    (["mrclam", "--robots", ""], r"--robots must be a comma-separated list"),
    (
        ["mrclam", "--algorithms", "ekf,kalman"],
        r"--algorithms: unknown algorithm\(s\) kalman; choose a comma-separated subset of dead_reckoning,",
    ),
    (["mrclam", "--algorithms", ","], r"--algorithms: no algorithm in ','; choose a comma-separated subset"),
    (["mrclam", "--duration", "0"], r"argument --duration: must be a finite number > 0, got 0"),
    (["mrclam", "--duration", "-60"], r"argument --duration: must be a finite number > 0"),
    (["mrclam", "--duration", "nan"], r"argument --duration: must be a finite number > 0, got nan"),
    (["mrclam", "--duration", "inf"], r"argument --duration: must be a finite number > 0, got inf"),
    (["mrclam", "--seed", "x"], r"argument --seed: must be an integer"),
    (["mrclam", "--out", "{file}/run"], r"--out .*is a file, not a folder"),
    # --out names a folder: one ending in / or one that exists; any other name is the deprecated prefix
    (["mrclam", "--out", "{file}/"], r"--out '.*a-file/': is a file, not a folder$"),
    (["mrclam", "--out", "{file}/run/"], r"--out .*a-file is a file, not a folder"),
    (["mrclam", "--out", "{out-dir}"], r"--out .*out-dir/robot1\.png is a folder, not a file"),
    (["mrclam", "--robots", "2", "--out", "{out-dir}/"], r"--out .*out-dir/robot2\.png is a folder, not a file"),
    (["mrclam", "--out", "{ro}/new/"], r"--out .*cannot write in"),
    (["mrclam", "--out", "{ro}/prefix"], r"--out .*cannot write in"),
    (
        ["mrclam", "--data", "{nowhere}"],
        r"UTIAS MRCLAM Dataset 7 not found at .*: pass --data <folder holding utias-mrclam-dataset7/> "
        r"or set the environment variable JAXNAV_DATA.*downloaded from http://asrl\.utias\.utoronto\.ca/datasets/mrclam/",
    ),
    # hf-slam
    (["hf-slam", "--density", "3000"], r"--density must be at least .* and below 2500 .*got 3000"),
    (["hf-slam", "--density", "1e-6"], r"--density must be at least 0\.16 tags/m².*got 1e-06"),
    (["hf-slam", "--density", "0"], r"argument --density: must be a finite number > 0"),
    (["hf-slam", "--density", "-16"], r"argument --density: must be a finite number > 0"),
    (["hf-slam", "--density", "nan"], r"argument --density: must be a finite number > 0, got nan"),
    (["hf-slam", "--density", "inf"], r"argument --density: must be a finite number > 0, got inf"),
    (["hf-slam", "--reader-mm", "1e6"], r"--reader-mm must be at most 2500 .*got 1e\+06"),
    (["hf-slam", "--reader-mm", "0"], r"argument --reader-mm: must be a finite number > 0"),
    (["hf-slam", "--reader-mm", "NaN"], r"argument --reader-mm: must be a finite number > 0"),
    (["hf-slam", "--laps", "0"], r"argument --laps: must be a positive integer"),
    (["hf-slam", "--laps", BIG], r"GiB of memory.*--laps \(" + BIG),
    (["hf-slam", "--trajectory", "random", "--steps", "0"], r"argument --steps: must be a positive integer"),
    (["hf-slam", "--trajectory", "random", "--steps", BIG], r"GiB of memory.*--steps \(" + BIG),
    (["hf-slam", "--robot-particles", "0"], r"argument --robot-particles: must be a positive integer"),
    (["hf-slam", "--robot-particles", BIG], r"GiB of memory.*--robot-particles \(" + BIG),
    (["hf-slam", "--tag-particles", "-1"], r"argument --tag-particles: must be a positive integer"),
    (["hf-slam", "--tag-particles", BIG], r"GiB of memory.*--tag-particles \(" + BIG),
    (["hf-slam", "--method", "fastslam", "--robot-particles", BIG], r"GiB of memory.*--robot-particles"),
    (["hf-slam", "--lag", "0"], r"argument --lag: must be a positive integer"),
    (["hf-slam", "--method", "ps_slam", "--lag", BIG], r"GiB of memory.*--lag \(" + BIG),
    (["hf-slam", "--method", "slam"], r"argument --method: invalid choice: 'slam'"),
    (["hf-slam", "--trajectory", "circle"], r"argument --trajectory: invalid choice"),
    (["hf-slam", "--seed", str(2**32)], r"argument --seed: must be an integer in \[0, 2\*\*32\)"),
    (["hf-slam", "--out", "{png-dir}"], r"--out .*plot\.png is a folder, not a file"),
    (["hf-slam", "--out", "{file}/x"], r"--out .*is a file, not a folder"),
    (["hf-slam", "--out", "{ro}/x"], r"--out .*cannot write in"),
    # ir
    (["ir", "--height", "0"], r"argument --height: must be a finite number > 0, got 0"),
    (["ir", "--height", "-1.2"], r"argument --height: must be a finite number > 0"),
    (["ir", "--height", "nan"], r"argument --height: must be a finite number > 0, got nan"),
    (["ir", "--height", "inf"], r"argument --height: must be a finite number > 0, got inf"),
    (["ir", "--speed-mm", "0"], r"argument --speed-mm: must be a finite number > 0"),
    (["ir", "--speed-mm", "-5"], r"argument --speed-mm: must be a finite number > 0"),
    (["ir", "--speed-mm", "1e-9"], r"GiB of memory.*--speed-mm \(1e-09\)"),
    (["ir", "--laps", "0"], r"argument --laps: must be a positive integer"),
    (["ir", "--drive", "loop", "--laps", BIG], r"GiB of memory.*--laps \(" + BIG),
    (["ir", "--particles", "0"], r"argument --particles: must be a positive integer"),
    (["ir", "--particles", BIG], r"GiB of memory.*--particles \(" + BIG),
    (["ir", "--failed-code", "12"], r"--failed-code must be a repeated ID 1-9, or 0 for none, got 12"),
    (["ir", "--failed-code", "-1"], r"--failed-code must be a repeated ID 1-9"),
    (["ir", "--failed-code", "one"], r"argument --failed-code: must be an integer"),
    (["ir", "--layout", "grid"], r"argument --layout: invalid choice"),
    (["ir", "--drive", "fly"], r"argument --drive: invalid choice"),
    (["ir", "--out", "{file}/x"], r"--out .*is a file, not a folder"),
    (["ir", "--out", "{png-dir}"], r"--out .*plot\.png is a folder, not a file"),  # the old form: one line
    (["ir", "--out", "{png-dir}.png"], r"--out .*plot\.png is a folder, not a file"),
    # uhf-real
    (["uhf-real", "--particles", "0"], r"argument --particles: must be a positive integer"),
    (["uhf-real", "--particles", BIG], r"GiB of memory.*--particles \(" + BIG),
    (["uhf-real", "--reads-per-channel", "0"], r"argument --reads-per-channel: must be a positive integer"),
    (["uhf-real", "--reads-per-channel", BIG], r"GiB of memory.*--reads-per-channel \(" + BIG),
    (["uhf-real", "--phase-sigma", "0"], r"argument --phase-sigma: must be a finite number > 0"),
    (["uhf-real", "--phase-sigma", "-0.1"], r"argument --phase-sigma: must be a finite number > 0"),
    (["uhf-real", "--phase-sigma", "nan"], r"argument --phase-sigma: must be a finite number > 0"),
    (["uhf-real", "--seeds", "0"], r"argument --seeds: must be a positive integer"),
    (["uhf-real", "--seeds", BIG], r"GiB of memory.*--seeds \(" + BIG),
    (
        ["uhf-real", "--weightings", "loud"],
        r"--weightings: unknown weighting\(s\) loud; choose a comma-separated subset of combined,rssi,phase",
    ),
    (["uhf-real", "--weightings", ""], r"--weightings: no weighting in ''; choose"),
    (
        ["uhf-real", "--data", "{nowhere}"],
        r"AdaRF UHF-RFID dataset not found at .*: pass --data <folder holding adarf-uhf-rfid-phase/>.*"
        r"downloaded from https://github\.com/dapowan/AdaRF",
    ),
    (
        ["uhf-real", "--data", "{adarf}", "--experiment", "nope"],
        r"--experiment: unknown experiment 'nope'; .* holds x ",
    ),
    (["uhf-real", "--data", "{adarf}", "--experiment", "x", "--out", "{file}/u"], r"--out .*is a file, not a folder"),
    (["uhf-real", "--data", "{adarf}", "--experiment", "x", "--out", "{file}/u/"], r"--out .*is a file, not a folder"),
    (["uhf-real", "--data", "{adarf}", "--experiment", "x", "--out", "{out-dir}"], r"out-dir/x\.png is a folder, not"),
    # uwb
    (["uwb", "--out", "{dir}"], r"--out .*a-dir is a folder, not a file"),
    (["uwb", "--out", "{nowhere}/uwb.png"], r"--out .*does not exist"),
    (["uwb", "--out", "{dir}/uwb.docx"], r"--out .*\.docx is not a figure format"),
    # experiments
    (["experiments", "run"], r"name an experiment \(see 'jaxnav experiments list'\)"),
    (["experiments", "run", "table-9.9"], r"unknown experiment 'table-9\.9'; choose from"),
    (["experiments", "fly"], r"argument action: invalid choice: 'fly'"),
    (["experiments", "run", "table-3.1", "--runs", "0"], r"argument --runs: must be a positive integer"),
    (["experiments", "run", "table-3.1", "--runs", BIG, "--out", "{dir}"], r"GiB of memory.*--runs \(" + BIG),
    (["experiments", "run", "table-3.1", "--chunk", "0"], r"argument --chunk: must be a positive integer"),
    (["experiments", "run", "table-3.1", "--workers", "0"], r"argument --workers: must be a positive integer"),
    (["experiments", "run", "table-3.1", "--workers", "-2"], r"argument --workers: must be a positive integer"),
    (["experiments", "run", "table-3.1", "--seed", "-1"], r"argument --seed: must be an integer in"),
    (["experiments", "run", "table-3.1", "--out", "{file}"], r"--out .*: is a file, not a folder"),
    (["experiments", "run", "table-3.1", "--out", "{file}/sub"], r"--out .*is a file, not a folder"),
    (["experiments", "run", "table-3.1", "--out", "{ro}/sub"], r"--out .*cannot write in"),
    # the top level
    (["fly"], r"argument COMMAND: invalid choice: 'fly'"),
    (["--verbose"], r"unrecognized arguments: --verbose"),
]


# ---------------------------------------------------------------------------
# synthetic data and the places the cases name


def _adarf_rows(p, reads=2):
    x = 0.02 * (p + 1)
    return [
        f"{epc},1,{int(f)},0,-50.5,{(0.1 * (t + c + r)) % 6.28:.4f},0,0,{x:.3f},1.63,0,0"
        for t, epc in enumerate(adarf.TARGET_EPCS)
        for c, f in enumerate(adarf.CHANNELS_HZ)
        for r in range(reads)
    ]


def _adarf_file(rows):
    header = "epc,antennaIndex,frequency,time,RSSI,phase,dopplerShift,velocity,x,y,z,angle"
    return gzip.compress(("\n".join([header, *rows]) + "\n").encode("utf-8-sig"), mtime=0)


def _adarf(root, point3=None, truth_y="0.8"):
    """A synthetic AdaRF copy with experiment ``x``; ``point3`` replaces the bytes of its file 3."""
    folder = root / adarf.DATASET
    exp = folder / "dataset1_test" / "x"
    exp.mkdir(parents=True)
    (folder / "tag_ground_truth.csv").write_text(
        "experiment,epc,x_m,y_m\n"
        + "".join(f"x,{e},{0.3 + 0.2 * i},{truth_y}\n" for i, e in enumerate(adarf.TARGET_EPCS))
    )
    for p in range(adarf.NUM_POINTS):
        data = _adarf_file(_adarf_rows(p))
        (exp / f"{p}.csv.gz").write_bytes(point3 if p == 3 and point3 is not None else data)
    return root


def _mrclam(root, **files):
    """A synthetic MRCLAM copy (robot 1, two landmarks); ``files`` replaces the text of some files."""
    folder = root / "utias-mrclam-dataset7"
    folder.mkdir(parents=True)
    text = {
        "Barcodes.dat": "# subject barcode\n1 5\n6 63\n7 25\n",
        "Landmark_Groundtruth.dat": "# subject x y sdx sdy\n6 1.0 2.0 0.01 0.01\n7 3.0 1.0 0.01 0.01\n",
        "Robot1_Odometry.dat": "# t v w\n" + "".join(f"{0.1 * i:.1f} 0.1 0.0\n" for i in range(30)),
        "Robot1_Groundtruth.dat": "# t x y theta\n" + "".join(f"{0.1 * i:.1f} {0.01 * i:.2f} 0 0\n" for i in range(30)),
        "Robot1_Measurement.dat": "# t barcode range bearing\n0.05 63 1.5 0.1\n0.15 25 2.0 -0.2\n",
    }
    text.update(files)
    for name, content in text.items():
        (folder / name).write_text(content)
    return root


def _unwritable(base):
    """A folder no file can be created in: a read-only one, or /proc for root (who writes anywhere else)."""
    (base / "read-only").mkdir(mode=0o500)
    for folder in (str(base / "read-only"), "/proc"):
        try:
            with tempfile.TemporaryFile(dir=folder):
                pass
        except OSError:
            return folder
    return None


@pytest.fixture(scope="module")
def places(tmp_path_factory):
    base = tmp_path_factory.mktemp("cli")
    (base / "a-file").write_text("not a folder\n")
    (base / "a-dir").mkdir()
    (base / "plot.png").mkdir()
    for name in ("robot1.png", "robot2.png", "x.png"):  # folders where --out DIR would write files
        (base / "out-dir" / name).mkdir(parents=True)
    good = _adarf_rows(3)  # row 5 is on line 7 (the header is line 1)
    short, nan = list(good), list(good)
    short[5] = ",".join(good[5].split(",")[:4])
    fields = good[5].split(",")
    fields[5] = "nan"  # the phase
    nan[5] = ",".join(fields)
    return {
        "file": str(base / "a-file"),
        "dir": str(base / "a-dir"),
        "nowhere": str(base / "no-such-folder"),
        "ro": _unwritable(base),
        "png-dir": str(base / "plot"),
        "out-dir": str(base / "out-dir"),
        "adarf": str(_adarf(base / "adarf-ok")),
        "adarf-truncated": str(_adarf(base / "adarf-truncated", point3=_adarf_file(good)[:120])),
        "adarf-not-gzip": str(_adarf(base / "adarf-not-gzip", point3=b"epc,frequency\n1,2\n")),
        "adarf-short": str(_adarf(base / "adarf-short", point3=_adarf_file(short))),
        "adarf-nan-phase": str(_adarf(base / "adarf-nan-phase", point3=_adarf_file(nan))),
        "adarf-nan-truth": str(_adarf(base / "adarf-nan-truth", truth_y="nan")),
        "mrclam-nan-truth": str(
            _mrclam(base / "mrclam-nan-truth", **{"Robot1_Groundtruth.dat": "# t x y theta\n0 0 0 0\n0.1 nan 0 0\n"})
        ),
        "mrclam-backwards": str(
            _mrclam(
                base / "mrclam-backwards",
                **{"Robot1_Measurement.dat": "# t barcode range bearing\n0.05 63 1.5 0.1\n1.5 25 2 0\n0.9 63 1 0\n"},
            )
        ),
        "mrclam-text": str(
            _mrclam(base / "mrclam-text", **{"Robot1_Odometry.dat": "# t v w\n0.0 0.1 0.0\n0.1 fast 0.0\n"})
        ),
        "mrclam-ok": str(_mrclam(base / "mrclam-ok")),
        "checkpoint": str(base / "checkpoint"),
    }


def _argv(argv, places):
    return [a.format(**places) for a in argv]


def _main(argv, capsys):
    """``jaxnav ARGV`` in this process: (exit status, stdout, stderr)."""
    try:
        code = cli.main(argv)
    except SystemExit as stop:  # argparse's refusals
        code = stop.code
    out, err = capsys.readouterr()
    return code, out, err


def _assert_refused(code, err, pattern, command):
    import re

    assert code == 2, err
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"jaxnav {command}: error: ") if command else lines[0].startswith("jaxnav: error: ")
    assert re.search(pattern, lines[0]), lines[0]


@pytest.fixture
def nothing_computed(monkeypatch):
    """The functions that compute fail the test if called: a refusal must come first."""

    def computed(*args, **kwargs):
        raise AssertionError("the command computed before refusing its input")

    from jaxnav import demo
    from jaxnav.experiments import hf_slam, registry
    from jaxnav.experiments import mrclam as mrclam_xp
    from jaxnav.experiments.ir import positioning
    from jaxnav.experiments.uhf import real

    for module, name in [
        (demo, "run_demo"),
        (hf_slam, "run_once_compiled"),
        (positioning, "drive_once"),
        (real, "localize"),
        (registry, "run"),
        (mrclam_xp, "run_robot"),
    ]:
        monkeypatch.setattr(module, name, computed)


def _command(argv):
    return argv[0] if argv and argv[0] in {"demo", "mrclam", "uwb", "hf-slam", "ir", "uhf-real", "experiments"} else ""


@pytest.mark.parametrize("argv, pattern", REFUSED, ids=[" ".join(a)[:60] for a, _ in REFUSED])
def test_bad_options_are_refused_in_one_line_before_computing(argv, pattern, places, capsys, nothing_computed):
    if "{ro}" in " ".join(argv) and places["ro"] is None:
        pytest.skip("no folder here refuses new files")
    code, _, err = _main(_argv(argv, places), capsys)
    _assert_refused(code, err, pattern, _command(argv))


# ---------------------------------------------------------------------------
# corrupted data and checkpoints: refused at load, naming the file and its line

CORRUPTED = [
    (
        ["mrclam", "--robots", "1", "--duration", "100", "--data", "{mrclam-ok}"],
        r"robot 1: --duration must be in \(0, 2\.\d+\] s from this t_start, got 100",
    ),
    (
        ["uhf-real", "--experiment", "x", "--data", "{adarf-truncated}"],
        r"3\.csv\.gz: unreadable after line \d+ \(EOFError.*truncated",
    ),
    (
        ["uhf-real", "--experiment", "x", "--data", "{adarf-not-gzip}"],
        r"3\.csv\.gz: unreadable after line 0 \(BadGzipFile",
    ),
    (
        ["uhf-real", "--experiment", "x", "--data", "{adarf-short}"],
        r"3\.csv\.gz, line 7: 4 field\(s\), the header has 12; the line is cut short",
    ),
    (
        ["uhf-real", "--experiment", "x", "--data", "{adarf-nan-phase}"],
        r"3\.csv\.gz, line 7, column 'phase': 'nan' is not a finite number",
    ),
    (
        ["uhf-real", "--experiment", "x", "--data", "{adarf-nan-truth}"],
        r"tag_ground_truth\.csv, line 2, column 'y_m': 'nan' is not a finite",
    ),
    (
        ["mrclam", "--data", "{mrclam-nan-truth}", "--robots", "1"],
        r"robot 1: .*Robot1_Groundtruth\.dat, line 3, column 2: nan is not a finite number",
    ),
    (
        ["mrclam", "--data", "{mrclam-backwards}", "--robots", "1"],
        r"Robot1_Measurement\.dat, line 4: time 0\.9 s is earlier than 1\.5 s on line 3",
    ),
    (["mrclam", "--data", "{mrclam-text}", "--robots", "1"], r"Robot1_Odometry\.dat, line 3, column 2: 'fast' is not"),
]


@pytest.mark.parametrize("argv, pattern", CORRUPTED, ids=[" ".join(a)[:60] for a, _ in CORRUPTED])
def test_corrupted_data_files_are_refused_in_one_line(argv, pattern, places, capsys):
    code, _, err = _main(_argv(argv, places) + ["--out", ""], capsys)
    _assert_refused(code, err, pattern, argv[0])


def test_a_corrupted_checkpoint_is_refused_in_one_line(places, capsys):
    """A damaged ``NAME.runs.json`` (the sweep refuses it with a ValueError naming it): one line, --fresh advised."""
    folder = places["checkpoint"]
    os.makedirs(folder, exist_ok=True)
    path = os.path.join(folder, "table-3.1.quick.runs.json")
    with open(path, "w") as fh:
        fh.write('{"meta": {"experiment": "table-3.1"')  # cut short
    argv = ["experiments", "run", "table-3.1", "--quick", "--runs", "1", "--out", folder, "--no-progress"]
    code, _, err = _main(argv, capsys)
    _assert_refused(code, err, r"table-3\.1\.quick\.runs\.json.*--fresh", "experiments")


def test_unexpected_errors_are_one_line_with_their_type(monkeypatch, capsys):
    """An error of another kind (an IndexError from deep inside, say) is still one line, with its type."""
    from jaxnav import demo

    def broken(*args, **kwargs):
        raise IndexError("list index out of range\nsecond line")

    monkeypatch.setattr(demo, "run_demo", broken)
    code, _, err = _main(["demo", "--out", ""], capsys)
    _assert_refused(code, err, r"IndexError: list index out of range second line$", "demo")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs named pipes")
@pytest.mark.parametrize(
    "argv, out, pipe",
    [
        (["mrclam", "--robots", "1,2"], "{tmp}/", "robot2.png"),  # the folder
        (["mrclam", "--robots", "1,2"], "{tmp}", "robot2.png"),  # an existing folder, without /
        (["mrclam", "--robots", "1"], "{tmp}/old", "old-robot1.png"),  # the deprecated prefix
        (["uhf-real", "--experiment", "x"], "{tmp}/", "x.png"),
        (["uhf-real", "--experiment", "x"], "{tmp}/old", "old-x.png"),
        (["hf-slam"], "{tmp}/run", "run.png"),  # the deprecated name without .png
        (["hf-slam"], "{tmp}/run.png", "run.png"),
        (["ir"], "{tmp}/ir.svg", "ir.svg"),
    ],
    ids=["mrclam-dir/", "mrclam-dir", "mrclam-prefix", "uhf-dir/", "uhf-prefix", "hf-old", "hf", "ir"],
)
def test_a_named_pipe_where_out_would_write_is_refused_at_once(
    argv, out, pipe, places, tmp_path, capsys, nothing_computed
):
    """Whatever the form of ``--out``, a named pipe at a file it would write is refused by name, in one line
    and with the same message (a write would block on it), before anything is computed or warned."""
    path = tmp_path / pipe
    os.mkfifo(path)
    value = out.format(tmp=tmp_path)
    code, _, err = _main(
        [*argv, "--data", places["adarf"], "--out", value] if argv[0] == "uhf-real" else [*argv, "--out", value], capsys
    )
    _assert_refused(
        code,
        err,
        re.escape(
            f"--out {value!r}: {path} is a named pipe (FIFO), not a regular file; remove it or choose another --out"
        )
        + "$",
        argv[0],
    )
    assert sorted(os.listdir(tmp_path)) == [pipe]


# ---------------------------------------------------------------------------
# the data folder: --data (root=), else $JAXNAV_DATA, else ../shared/data relative to the repository
# (the user's data folder for an installed copy), never relative to the current folder


def test_the_data_folder_is_not_found_from_the_current_folder(tmp_path, monkeypatch, capsys, nothing_computed):
    """A ``../shared/data`` beside the current folder is not looked at: the default is an absolute folder
    fixed by the repository (the user's data folder for an installed copy); ``root=`` and ``$JAXNAV_DATA``
    still name one."""
    from jaxnav.io import _data
    from jaxnav.io import mrclam as mrclam_io

    _mrclam(tmp_path / "shared" / "data")  # what ../shared/data from tmp_path/work would hold
    (tmp_path / "work").mkdir()
    monkeypatch.chdir(tmp_path / "work")
    monkeypatch.delenv(_data.ENV_VAR, raising=False)
    repo = pathlib.Path(__file__).resolve().parents[1]
    default = (repo / ".." / "shared" / "data").resolve()
    assert _data.default_data_dir() == default and default.is_absolute()
    assert _data.data_candidates(None) == [default]
    try:
        found = mrclam_io.data_dir()
    except FileNotFoundError as err:
        assert str(tmp_path) not in str(err)
    else:
        assert tmp_path not in found.parents

    # an installed copy: the user's data folder, from $XDG_DATA_HOME when it is absolute, never the cwd
    monkeypatch.setattr(_data, "_source_checkout", lambda: None)
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    assert _data.data_candidates(None) == [tmp_path / "xdg" / "jaxnav"]
    monkeypatch.setenv("XDG_DATA_HOME", "relative/data")  # a relative value is ignored, as XDG asks
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert _data.data_candidates(None) == [tmp_path / "home" / ".local" / "share" / "jaxnav"]
    code, _, err = _main(["mrclam", "--robots", "1", "--out", ""], capsys)
    _assert_refused(
        code,
        err,
        r"UTIAS MRCLAM Dataset 7 not found at \S+/home/\.local/share/jaxnav/utias-mrclam-dataset7: "
        r"pass --data <folder holding utias-mrclam-dataset7/> or set the environment variable JAXNAV_DATA",
        "mrclam",
    )
    with pytest.raises(FileNotFoundError, match=r"\.local/share/jaxnav.*pass root="):
        mrclam_io.data_dir()

    # root= and $JAXNAV_DATA, relative to the current folder as any path a user gives
    expected = (tmp_path / "shared" / "data" / mrclam_io.DATASET).resolve()
    assert mrclam_io.data_dir("../shared/data") == expected
    monkeypatch.setenv(_data.ENV_VAR, str(tmp_path / "shared" / "data"))
    assert mrclam_io.data_dir() == expected


def test_the_ir_code_range_matches_the_model():
    from jaxnav.models import ir

    assert cli.IR_CODES == range(0, ir.NUM_CODES + 1)


def test_detection_capacity_is_capped_by_the_carpet():
    """A footprint far larger than the carpet cannot detect more tags than the carpet holds
    (the 143-tag carpet once got 128 million detection slots per step from 1 km readers)."""
    from jaxnav.experiments import hf_slam
    from jaxnav.models import hf_rfid
    from jaxnav.sim import tag_carpet

    layout = hf_slam.HFSetting().layout
    offsets = hf_rfid.default_reader_offsets()
    assert layout.num_tags == 143
    assert tag_carpet.detection_capacity(layout, 1000.0, offsets) == 8 * 143
    assert tag_carpet.detection_capacity(layout, 0.06, offsets) < 8 * 143  # the usual bound is untouched


# ---------------------------------------------------------------------------
# as a user runs it: a subprocess, so stderr is the real one


def _jaxnav(*args, cwd):
    return subprocess.run(
        [sys.executable, "-m", "jaxnav.cli", *args], cwd=cwd, capture_output=True, text=True, timeout=300
    )


@pytest.mark.parametrize(
    "argv, pattern",
    [
        (["hf-slam", "--reader-mm", "1e6", "--out", ""], r"--reader-mm must be at most 2500"),  # once hung
        (["hf-slam", "--out", "{file}/x"], r"--out .*is a file, not a folder"),
        (
            ["uhf-real", "--experiment", "x", "--data", "{adarf-truncated}", "--out", ""],
            r"3\.csv\.gz: unreadable after line",
        ),
        (["mrclam", "--data", "{mrclam-nan-truth}", "--robots", "1", "--out", ""], r"line 3, column 2: nan"),
    ],
    ids=["reader-mm-1e6", "out-under-a-file", "truncated-gz", "nan-ground-truth"],
)
def test_no_traceback_reaches_a_real_stderr(argv, pattern, places, tmp_path):
    out = _jaxnav(*_argv(argv, places), cwd=tmp_path)
    _assert_refused(out.returncode, out.stderr, pattern, argv[0])
