"""The ``jaxnav`` command line: ``--version``, ``demo``, ``mrclam``, ``uwb``, ``hf-slam``, ``ir``, ``uhf-real``,
``experiments``.

Bad input never ends in a traceback: every refusal is one line on stderr,
``jaxnav COMMAND: error: MESSAGE``, naming the option or the file, with exit
status 2. Options are checked before anything is computed: numbers must be
finite and in range, ``--out`` must be writable and name regular files (not a
folder, a named pipe or a device), and the sizes of a run must fit in this
machine's memory. Outputs are written to a temporary file renamed into place:
a full disk (or a quota, a read-only file system) is one line naming the file,
and leaves no truncated file behind.

``--out`` has one meaning per kind of output. A command that draws one figure
(``demo``, ``uwb``, ``hf-slam``, ``ir``) writes it to the FILE ``--out`` names,
exactly as given, its extension choosing the format (``.png``, ``.pdf``, ``.svg``,
…). A command that writes several files (``mrclam``: one PNG per robot,
``uhf-real``: one per experiment, ``experiments``: JSON, Markdown and PNG) writes
them into the FOLDER ``--out`` names, created if missing. ``--out ''`` writes
no figure. The forms of earlier releases still work, with a deprecation warning
on stderr: ``hf-slam`` and ``ir`` append ``.png`` to a name without a figure
extension, ``mrclam`` and ``uhf-real`` read a name that is no folder and does
not end in ``/`` as a prefix of the file names (``PREFIX-robot1.png``), and
``experiments`` reads ``--out ''`` as the current folder (give ``.``).
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import stat
import sys
import tempfile
import textwrap
import warnings
import zlib

from jaxnav._version import __version__

# the help text lists these without importing the experiment; tests/test_cli.py checks they match
MRCLAM_ALGORITHMS = ("dead_reckoning", "ekf", "ukf", "mcl", "ekf_slam", "fastslam1", "fastslam2", "pf_slam", "ps_slam")
UWB_ALGORITHMS = ("dead_reckoning", "ekf", "ukf", "mcl", "mcl_t", "fastslam", "fastslam_ring", "pf_slam", "ps_slam")
HF_METHODS = ("pf_slam", "ps_slam", "fastslam")
HF_TRAJECTORIES = ("rectangle", "random", "kidnapping")
IR_LAYOUTS = ("proposed", "unique-11")
IR_DRIVES = ("spots", "loop", "rotation")
UHF_WEIGHTINGS = ("combined", "rssi", "phase")
MRCLAM_ROBOTS = range(1, 6)
IR_CODES = range(0, 10)  # 0: no failed emitter; 1-9: the repeated IDs (jaxnav.models.ir.NUM_CODES)

_REFUSED = (
    ValueError,  # bad values, unreadable data files (UnicodeDecodeError is one)
    TypeError,
    OSError,  # missing or unwritable files (FileNotFoundError, PermissionError, gzip.BadGzipFile)
    EOFError,  # a truncated compressed file
    LookupError,  # IndexError, KeyError
    ArithmeticError,  # OverflowError
    MemoryError,
    RuntimeError,  # XLA's out-of-memory
    zlib.error,
    csv.Error,
)
"""What a command turns into one line on stderr and exit status 2."""


# ---------------------------------------------------------------------------
# option types (argparse names the option in its one-line error)


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line on stderr (exit status 2), without the usage block."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def _integer(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None


def _positive_int(text: str) -> int:
    value = _integer(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return value


def _non_negative_int(text: str) -> int:
    value = _integer(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a non-negative integer, got {text}")
    return value


def _seed(text: str) -> int:
    value = _integer(text)
    if not 0 <= value < 2**32:
        raise argparse.ArgumentTypeError(f"must be an integer in [0, 2**32), got {text}")
    return value


def _positive_number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return value


# ---------------------------------------------------------------------------
# checks run before anything is computed


def _one_line(err: BaseException) -> str:
    """The error as one line; errors other than bad values and files carry their type."""
    from jaxnav.io._data import DataNotFoundError

    if isinstance(err, DataNotFoundError):
        text = err.explain(f"pass --data <folder holding {err.dataset}/>")
    else:
        text = str(err) or type(err).__name__
        if isinstance(err, KeyError) and err.args:
            text = repr(err.args[0])
        if not isinstance(err, (ValueError, OSError, EOFError)):
            text = f"{type(err).__name__}: {text}"
    return " ".join(line.strip() for line in text.splitlines() if line.strip())


def _check_folder_takes_files(option: str, value: str, folder: str) -> None:
    """``folder`` exists, is a folder, and a file can be created in it."""
    if not os.path.isdir(folder):
        what = "is a file, not a folder" if os.path.exists(folder) else "does not exist"
        raise ValueError(f"{option} {value!r}: {folder} {what}")
    try:
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as err:
        raise ValueError(f"{option} {value!r}: cannot write in {folder} ({err.strerror or err})") from None


def _check_out_kinds(option: str, value: str, paths: list[str]) -> None:
    """None of ``paths`` (derived from ``--out``) is a folder, a named pipe, a device or a socket: each is
    absent or a regular file (a write would otherwise block on a pipe, or replace a device)."""
    from jaxnav.io._files import describe

    for path in paths:
        try:
            mode = os.stat(path).st_mode
        except OSError:  # absent: created; a folder on the way that cannot be searched: refused below
            continue
        if stat.S_ISDIR(mode):
            raise ValueError(f"{option} {value!r}: {path} is a folder, not a file")
        if not stat.S_ISREG(mode):
            raise ValueError(
                f"{option} {value!r}: {path} is {describe(mode)}, not a regular file; remove it or choose another "
                f"{option}"
            )


def _check_out_files(option: str, value: str, paths: list[str]) -> None:
    """The files ``paths`` (derived from ``--out``) can be written: their folder takes files, each is absent
    or a regular file (not a folder, a named pipe or a device)."""
    _check_out_kinds(option, value, paths)
    for path in paths:
        _check_folder_takes_files(option, value, os.path.dirname(os.path.abspath(path)))


def _check_out_dir(option: str, value: str) -> None:
    """``--out`` names a folder that exists and takes files, or one that can be created."""
    path = os.path.abspath(value)
    if os.path.exists(path) and not os.path.isdir(path):
        raise ValueError(f"{option} {value!r}: is a file, not a folder")
    existing = path
    while not os.path.exists(existing):
        existing = os.path.dirname(existing)
    _check_folder_takes_files(option, value, existing)


FIGURE_FORMATS = (
    "png", "pdf", "svg", "svgz", "eps", "ps", "jpg", "jpeg", "tif", "tiff", "webp", "avif", "gif", "pgf", "raw", "rgba"
)  # fmt: skip
"""The extensions of a figure's ``--out`` taken as its format (those matplotlib writes)."""


def _deprecated(args: argparse.Namespace, message: str) -> None:
    """Say on stderr, in one line, that an option was given in a form that the next release drops."""
    print(f"jaxnav {args.command}: warning: deprecated: {message}", file=sys.stderr, flush=True)


def _out_file(args: argparse.Namespace, *, old_adds_png: bool = False) -> str | None:
    """The figure file ``--out`` names (a command that draws one figure), checked; None for ``--out ''``.

    The name is used as given, its extension choosing the format; one that is not a figure format is
    refused. With ``old_adds_png`` (``hf-slam``, ``ir``, whose ``--out`` was a path without ``.png``), a
    name without a figure extension still gets ``.png`` appended, with a deprecation warning."""
    value = args.out
    if not value:
        return None
    ext = os.path.splitext(value)[1]
    known = ext[1:].lower() in FIGURE_FORMATS
    if old_adds_png and not known:
        path = value + ".png"
        _check_out_files("--out", value, [path])
        _deprecated(
            args,
            f"--out {value!r} has no figure extension: {path} is written, as before; give the extension "
            f"(--out {path}): the next release writes the name as given",
        )
        return path
    if ext and not known:
        raise ValueError(
            f"--out {value!r}: {ext} is not a figure format; end the name in one that matplotlib writes: "
            f"{', '.join('.' + f for f in FIGURE_FORMATS)}"
        )
    _check_out_files("--out", value, [value])
    return value


def _is_folder_form(value: str) -> bool:
    """Whether ``--out VALUE`` of a command writing several files names a folder: it ends in ``/``
    or is one. Any other name is the prefix of the file names of earlier releases (deprecated)."""
    ends = tuple(sep for sep in (os.sep, os.altsep) if sep)
    return value.endswith(ends) or os.path.isdir(value)


def _out_folder(args: argparse.Namespace, names: list[str]) -> list[str]:
    """The files ``names`` in the folder ``--out`` names (a command writing several files), checked;
    none for ``--out ''``. A name that is no folder and does not end in ``/`` is the prefix of earlier
    releases: ``PREFIX-NAME`` is written, with a deprecation warning."""
    value = args.out
    if not value:
        return []
    if _is_folder_form(value):
        _check_out_dir("--out", value)
        paths = [os.path.join(value, name) for name in names]
        _check_out_kinds("--out", value, paths)
        return paths
    paths = [f"{value}-{name}" for name in names]
    _check_out_files("--out", value, paths)
    folder = value + "/"
    _deprecated(
        args,
        f"--out {value!r} is read as a prefix ({paths[0]}{', …' if len(paths) > 1 else ''}), as before; "
        f"--out now names a folder: give --out {folder} to write {os.path.join(folder, names[0])}"
        f"{', …' if len(names) > 1 else ''} (the next release reads every --out as a folder)",
    )
    return paths


def _memory_bytes() -> int:
    """The memory this process may use (bytes; :func:`jaxnav.core.memory.host_memory_bytes`); 0 when unknown."""
    from jaxnav.core import memory

    host = memory.host_memory_bytes()
    return host[0] if host else 0


def _check_memory(need: int, options: str) -> None:
    """Refuse a run whose estimated memory exceeds what this process may use, naming the options that
    size it; ``JAXNAV_ALLOW_LARGE_ALLOCATIONS=1`` lets it through (:mod:`jaxnav.core.memory`)."""
    from jaxnav.core import memory

    have = _memory_bytes()
    if memory.guard_enabled() and have and need > have:
        raise ValueError(
            f"this run would need about {need / 2**30:.3g} GiB of memory, more than the "
            f"{have / 2**30:.3g} GiB this process may use: reduce {options} (or set {memory.ENV_VAR}=1 to try anyway)"
        )


def _names(option: str, text: str, choices: tuple[str, ...], what: str) -> list[str]:
    """A comma-separated list of ``choices`` (each a ``what``): at least one, all known."""
    names = [n for n in text.split(",") if n]
    unknown = [n for n in names if n not in choices]
    if unknown or not names:
        found = f"unknown {what}(s) {', '.join(unknown)}" if unknown else f"no {what} in {text!r}"
        raise ValueError(f"{option}: {found}; choose a comma-separated subset of {','.join(choices)}")
    return names


def _warn_line(command: str):
    """A ``warnings.showwarning`` that prints ``COMMAND: warning: MESSAGE`` as one line on stderr."""

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        text = " ".join(part.strip() for part in str(message).splitlines() if part.strip())
        print(f"{command}: warning: {text}", file=sys.stderr, flush=True)

    return show


def _compiling(text: str) -> None:
    """Say on stderr, when it is a terminal, that XLA compiles (most of a first run's wait) before output."""
    try:
        terminal = sys.stderr.isatty()
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        terminal = False
    if terminal:
        print(text, file=sys.stderr, flush=True)


def _write_plot(draw, path: str) -> None:
    """Call ``draw`` on a temporary file renamed to ``path`` once written (a full disk leaves no truncated
    PNG, and the error names ``path``), and say where the PNG went, or that matplotlib is missing."""
    from jaxnav.io._files import write_atomic_path

    folder = os.path.dirname(path)
    if folder:  # a folder --out of mrclam and uhf-real, checked to be creatable
        os.makedirs(folder, exist_ok=True)
    try:
        write_atomic_path(path, draw)
    except ImportError:
        print("matplotlib is not installed: no plot written (pip install 'jaxnav[plot]')")
    else:
        print(f"wrote {path}")


def _cmd_demo(args: argparse.Namespace) -> int:
    out = _out_file(args)
    # about 64 numbers a particle (one MCL step's arrays) and a step (the recorded run), doubled for XLA
    _check_memory(
        2 * 4 * (64 * args.particles + 64 * args.steps), f"--particles ({args.particles}) or --steps ({args.steps})"
    )
    from jaxnav.demo import plot_demo, run_demo

    print(
        f"jaxnav {__version__} demo: Monte Carlo localization ([A] Alg. 3), {args.particles} particles, "
        f"10 m room, 8 landmarks, {args.steps} steps, seed {args.seed}"
    )
    _compiling("compiling the filter (first call)…")
    result = run_demo(seed=args.seed, num_steps=args.steps, num_particles=args.particles)
    print(f"{'step':>6} {'time [s]':>9} {'position error [m]':>19}")
    every = max(1, args.steps // 10)
    for i in range(0, args.steps, every):
        print(f"{i + 1:>6} {(i + 1) * result.dt:>9.2f} {result.position_error[i]:>19.3f}")
    last = args.steps - 1
    if last % every:
        print(f"{last + 1:>6} {(last + 1) * result.dt:>9.2f} {result.position_error[last]:>19.3f}")
    print(f"mean position error over the run: {result.position_error.mean():.3f} m")
    if out:
        _write_plot(lambda path: plot_demo(result, path), out)
    return 0


def _robots(text: str) -> list[int]:
    """``--robots``: a comma-separated list of robot numbers 1-5."""
    try:
        robots = [int(r) for r in text.split(",") if r.strip()]
    except ValueError:
        robots = []
    if not robots or any(r not in MRCLAM_ROBOTS for r in robots):
        raise ValueError(f"--robots must be a comma-separated list of robots 1-5 (MRCLAM has five), got {text!r}")
    return robots


def _cmd_mrclam(args: argparse.Namespace) -> int:
    robots = _robots(args.robots)
    if args.calibrate is not None:
        return _mrclam_calibration(args, robots)
    algorithms = _names("--algorithms", args.algorithms, MRCLAM_ALGORITHMS, "algorithm")
    pngs = dict(zip(robots, _out_folder(args, [f"robot{r}.png" for r in robots])))
    from jaxnav.experiments import mrclam as xp
    from jaxnav.io import mrclam as data

    folder = data.data_dir(args.data)
    span = "the whole log" if args.duration is None else f"{args.duration:g} s"
    print(f"jaxnav {__version__}: UTIAS MRCLAM dataset 7 from {folder}, robots {robots}, {span}, seed {args.seed}")
    print("Leung et al., IJRR 30(8), 2011 (please cite the dataset)")
    rows = []
    for robot in robots:
        _compiling(f"robot {robot}: reading its log, compiling and running {len(algorithms)} filter(s)…")
        try:
            seq, results = xp.run_robot(robot, algorithms, duration=args.duration, seed=args.seed, root=args.data)
        except ValueError as err:
            text = str(err)
            if text.startswith("duration "):  # the Python argument is the --duration option here
                text = "--" + text
            raise ValueError(f"robot {robot}: {text}") from None
        rows += [(robot, r) for r in results]
        print(
            f"robot {robot}: {seq.controls.shape[0]} steps of {seq.dt:g} s, {seq.num_placed} measurements "
            f"({seq.num_outliers} of other robots or unknown barcodes, ignored by the filters)"
        )
        if pngs:
            _write_plot(lambda path: xp.plot_robot(seq, results, path), pngs[robot])
    print(xp.format_table(rows))
    return 0


MRCLAM_CALIBRATION_SECONDS = 300.0
"""The segment of robot 1's log that ``jaxnav mrclam --calibrate`` learns the noise on (s)."""


def _mrclam_calibration(args: argparse.Namespace, robots: list[int]) -> int:
    """``jaxnav mrclam --calibrate METHOD``: learn the noise on robot 1's first 300 s, then compare."""
    known_map = ("ekf", "ukf", "mcl")
    chosen = args.algorithms if args.algorithms != ",".join(MRCLAM_ALGORITHMS) else ",".join(known_map)
    algorithms = _names("--algorithms", chosen, known_map, "known-map filter (with --calibrate)")
    from jaxnav.experiments import mrclam as xp
    from jaxnav.experiments.mrclam import calibration as cal
    from jaxnav.io import mrclam as data

    folder = data.data_dir(args.data)
    print(f"jaxnav {__version__}: UTIAS MRCLAM dataset 7 from {folder}; noise learned by {args.calibrate.upper()}")
    print("Leung et al., IJRR 30(8), 2011 (please cite the dataset)")
    settings = xp.MRCLAMSettings()
    seq = data.to_filter_steps(
        data.load_robot(1, args.data),
        dt=settings.dt,
        duration=MRCLAM_CALIBRATION_SECONDS,
        max_obs=settings.max_obs,
        keep_outliers=True,
    )
    _compiling(f"robot 1, first {MRCLAM_CALIBRATION_SECONDS:g} s: fitting the motion and sensor noise…")
    fit = cal.fit_noise(seq, settings, args.calibrate, args.calibration_steps, args.seed, progress=True)
    losses = fit.result.losses
    print(
        f"fitted in {fit.seconds:.0f} s ({losses.size} steps; mean log-likelihood per step "
        f"{-losses[0]:.3f} -> {-losses[-1]:.3f})"
    )
    for name, hand, learned in (
        ("alphas", settings.alphas, fit.settings.alphas),
        ("pose_sd (m, m, rad)", settings.pose_sd, fit.settings.pose_sd),
        ("sensor_sd (m, rad)", settings.sensor_sd, fit.settings.sensor_sd),
    ):
        print(f"  {name}: {', '.join(f'{v:.4g}' for v in hand)} -> {', '.join(f'{v:.4g}' for v in learned)}")
    span = "the whole log" if args.duration is None else f"{args.duration:g} s"
    _compiling(f"robots {robots}, {span}: running {', '.join(algorithms)} with both settings…")
    rows = cal.compare(
        {"hand-chosen": settings, "learned": fit.settings},
        robots,
        algorithms,
        duration=args.duration,
        seed=args.seed,
        root=args.data,
    )
    print(cal.format_comparison(rows))
    return 0


def _cmd_uwb(args: argparse.Namespace) -> int:
    if args.calibrate is not None:
        return _uwb_calibration(args)
    algorithms = _names("--algorithms", args.algorithms, UWB_ALGORITHMS, "algorithm")
    out = _out_file(args)
    from jaxnav.experiments import uwb as xp
    from jaxnav.io import uwb as data

    folder = data.data_dir(args.data)
    print(
        f"jaxnav {__version__}: TU Chemnitz Labyrinth UWB dataset from {folder}, {args.runs} run(s), seed {args.seed}"
    )
    print("Labyrinth dataset, Copyright 2017-2023 Tim Pfeifer (TU Chemnitz), CC BY-SA 4.0, distributed with libRSF")
    _compiling(f"reading the log, compiling and running {len(algorithms)} algorithm(s)…")
    seq, results = xp.run_study(algorithms, runs=args.runs, seed=args.seed, root=args.data)
    print(
        f"{seq.times.size} steps over {seq.times[-1] - seq.times[0]:.1f} s, one range per step, {seq.anchors.shape[0]} anchors"
    )
    if out:
        _write_plot(lambda path: xp.plot_study(seq, results, path), out)
    print(xp.format_table(results))
    return 0


def _hf_setting(args: argparse.Namespace):
    """The :class:`~jaxnav.experiments.hf_slam.HFSetting` of the options, its sizes checked first."""
    from jaxnav.experiments import hf_slam as xp

    carpet, jitter = xp.HFSetting.carpet, xp.HFSetting.installation_jitter
    side = min(carpet)
    low, high = 1.0 / side**2, 1.0 / (2.0 * jitter) ** 2
    if not low <= args.density < high:
        raise ValueError(
            f"--density must be at least {low:.3g} tags/m² (a pitch of at most the carpet's {side:g} m) and below "
            f"{high:g} (a pitch of more than twice the {1000 * jitter:g} mm installation error), got {args.density:g}"
        )
    if args.reader_mm > 1000.0 * side:
        raise ValueError(
            f"--reader-mm must be at most {1000 * side:g} (a reader fits on the {carpet[0]:g} m × {carpet[1]:g} m "
            f"carpet; [W] uses 60 to 500), got {args.reader_mm:g}"
        )
    setting = xp.HFSetting(
        density=args.density,
        reader_side=args.reader_mm / 1000.0,
        trajectory=args.trajectory,
        laps=args.laps,
        random_steps=args.steps,
        robot_particles=args.robot_particles,
        tag_particles=args.tag_particles,
        lag=args.lag,
    )
    length = f"--steps ({args.steps})" if args.trajectory == "random" else f"--laps ({args.laps})"
    lag = f", --lag ({args.lag})" if args.method == "ps_slam" else ""
    _check_memory(
        xp.memory_estimate(args.method, setting),
        f"--robot-particles ({args.robot_particles}), --tag-particles ({args.tag_particles}), "
        f"--density ({args.density:g}), --reader-mm ({args.reader_mm:g}){lag} or {length}",
    )
    return setting


def _cmd_hf_slam(args: argparse.Namespace) -> int:
    setting = _hf_setting(args)
    out = _out_file(args, old_adds_png=True)
    import jax
    import numpy as np

    from jaxnav.experiments import hf_slam as xp

    print(
        f"jaxnav {__version__} hf-slam: {args.method} on {setting.density:g} tags/m² (pitch {1000 * setting.pitch:.0f} mm), "
        f"{args.reader_mm:g} mm readers, {setting.trajectory} trajectory, {setting.robot_particles} robot particles, seed {args.seed}"
    )
    _compiling("compiling the simulation and the filter (first call)…")
    errors, world, result = xp.run_once_compiled(jax.random.PRNGKey(args.seed), args.method, setting)
    run = world.run
    steps = run.odometry.shape[0]
    detections = int(np.asarray(run.detections.mask).sum())
    dead = xp.dead_reckoning(run)
    odo = 1000 * float(np.mean(np.linalg.norm(np.asarray(dead)[:, :2] - np.asarray(run.true_poses)[:, :2], axis=1)))
    print(
        f"{steps} steps of {setting.dt:g} s, {detections} detections, {int(np.asarray(result.seen).sum())} of "
        f"{world.carpet.layout.num_tags} tags mapped; odometry alone: dr = {odo:.1f} mm"
    )
    if np.asarray(run.kidnapped).any():
        print(
            f"kidnapped at step {int(np.argmax(np.asarray(run.kidnapped)))}; recovery fired at steps "
            f"{np.nonzero(np.asarray(result.lost))[0].tolist()[:10]}"
        )
    print(xp.format_errors([(args.method, errors)]))
    shift = xp.map_shift(world, result)
    if shift is not None:
        dx, dy = shift.shift_mm
        print(
            f"the map as a whole lies ({dx:+.1f}, {dy:+.1f}) mm off, which no detection can see;\n"
            f"without that shift the tags' error is {shift.tag_unshifted_mm:.1f} mm and the robot's "
            f"{shift.robot_unshifted_mm:.1f} mm"
        )
    if out:
        _write_plot(lambda path: xp.plot_run(setting, args.method, world, result, path), out)
    return 0


def _ir_setting(args: argparse.Namespace):
    """The :class:`~jaxnav.experiments.ir.positioning.IRSetting` of the options, its sizes checked first."""
    from jaxnav.experiments.ir import positioning as xp

    if args.failed_code not in IR_CODES:
        raise ValueError(f"--failed-code must be a repeated ID 1-9, or 0 for none, got {args.failed_code}")
    setting = xp.IRSetting(
        layout=args.layout,
        drive=args.drive,
        height=args.height,
        speed=args.speed_mm / 1000.0,
        laps=args.laps,
        failed_code=args.failed_code,
        num_particles=args.particles,
    )
    laps = f", --laps ({args.laps})" if args.drive == "loop" else ""
    _check_memory(
        xp.memory_estimate(setting), f"--particles ({args.particles}){laps}, or raise --speed-mm ({args.speed_mm:g})"
    )
    return setting


def _cmd_ir(args: argparse.Namespace) -> int:
    setting = _ir_setting(args)
    out = _out_file(args, old_adds_png=True)
    import jax
    import numpy as np

    from jaxnav.experiments.ir import positioning as xp

    _compiling("compiling the simulation and the filter (first call)…")
    drive = xp.drive_once(jax.random.PRNGKey(args.seed), setting)
    steps = drive.sim.controls.shape[0]
    det = int(np.asarray(drive.sim.detections.valid).sum())
    print(
        f"jaxnav {__version__} ir: {setting.drive} drive, {setting.layout} layout"
        f"{f', code {setting.failed_code} failed' if setting.failed_code else ''}, height {setting.height:g} m, "
        f"{args.speed_mm:g} mm/s, {setting.num_particles} particles, seed {args.seed}"
    )
    print(
        f"{steps} steps of {setting.dt:g} s, {det} receiver detections; {xp.describe_start(drive.mcl)}; scored: "
        f"{int((np.asarray(drive.inputs.record) >= 0).sum())} steps"
    )
    print(xp.format_errors([("IR MCL", drive.mcl), ("odometry", drive.dead)]))
    if out:
        _write_plot(lambda path: xp.plot_drive(drive, path), out)
    return 0


def _cmd_uhf_real(args: argparse.Namespace) -> int:
    weightings = tuple(_names("--weightings", args.weightings, UHF_WEIGHTINGS, "weighting"))
    from jaxnav.experiments.uhf import real as xp
    from jaxnav.io import adarf

    setting = xp.RealSetting(
        num_particles=args.particles,
        reads_per_channel=args.reads_per_channel,
        phase_sigma_fraction=args.phase_sigma,
    )
    _check_memory(
        xp.memory_estimate(setting, args.seeds),
        f"--particles ({args.particles}), --reads-per-channel ({args.reads_per_channel}) or --seeds ({args.seeds})",
    )
    available = adarf.available_experiments(args.data)
    names = available if args.experiment == "all" else (args.experiment,)
    if not names or not set(names) <= set(available):
        raise ValueError(
            f"--experiment: unknown experiment {args.experiment!r}; {adarf.data_dir(args.data)} holds "
            f"{', '.join(available) or 'none'} with its {adarf.NUM_POINTS} files and a ground truth"
        )
    if args.calibrate:
        return _uhf_calibrate(args, setting, names)
    pngs = _out_folder(args, [f"{name}.png" for name in names])
    print(
        f"jaxnav {__version__} uhf-real: [A] Alg. 6 in 2D on the AdaRF reads ({adarf.data_dir(args.data)}), "
        f"{setting.num_particles} particles, {setting.reads_per_channel} read(s) per channel and point, "
        f"σ_phase = {setting.phase_sigma_fraction:g} λ, {args.seeds} seed(s) from {args.seed}"
    )
    results = []
    _compiling("compiling the filter…")
    for name in names:
        res = xp.localize(name, weightings, setting, seeds=args.seeds, seed=args.seed, root=args.data)
        results.append(res)
        print(xp.format_results(res), flush=True)
    for png, res in zip(pngs, results):
        _write_plot(lambda path, res=res: xp.plot_results(res, path), png)
    return 0


def _uhf_calibrate(args: argparse.Namespace, setting, names) -> int:
    """``jaxnav uhf-real --calibrate``: (k, θ, σ_phase) learned two ways against the closed-form fit."""
    from jaxnav.experiments.uhf import calibration as cal
    from jaxnav.io import adarf

    print(
        f"jaxnav {__version__} uhf-real --calibrate: (k, θ, σ_phase) by maximum likelihood on the AdaRF reads "
        f"({adarf.data_dir(args.data)}): 'anchor' from the anchor tag at its known position (L-BFGS), 'filter' "
        f"from each tag's own reads through the particle filter (Adam); 'closed-form' is [A]'s (k, θ) with "
        f"σ_phase = {setting.phase_sigma_fraction:g} λ. Final error of the combined weighting, "
        f"{setting.num_particles} particles, mean of {args.seeds} seed(s) from {args.seed}"
    )
    _compiling("fitting and filtering…")
    rows = cal.run_study(names, seeds=args.seeds, seed=args.seed, root=args.data, setting=setting)
    print(cal.format_table(rows))
    return 0


def _cmd_experiments(args: argparse.Namespace) -> int:
    from jaxnav.experiments import registry

    if args.action is None:  # the actions and examples, as for a missing argument: exit status 2
        print(args.help_text(), end="", file=sys.stderr)
        return 2
    if args.action == "list":
        width = max(map(len, registry.names()))
        for name in registry.names():
            print(f"{name:<{width}}  {registry.get(name).title}")
        return 0
    if not args.name:
        raise ValueError("name an experiment (see 'jaxnav experiments list')")
    exp = registry.get(args.name)
    distributed = args.distributed or any(
        x is not None for x in (args.coordinator, args.num_processes, args.process_id)
    )
    if distributed:  # before anything starts a device
        from jaxnav.core import processes

        processes.initialize(args.coordinator, args.num_processes, args.process_id)
    if args.out == "":  # every other command reads '' as "write nothing"; here it named the current folder
        args.out = "."
        _deprecated(
            args,
            "--out '' is read as the current folder, as before; give --out . for it "
            "(the next release refuses '': a run's results are its files)",
        )
    _check_out_dir("--out", args.out)
    stem = registry.output_stem(args.out, exp.name, args.quick)
    _check_out_kinds("--out", args.out, [stem + ext for ext in (".runs.json", ".json", ".md", ".png")])
    cells = len(exp.cells(args.quick))
    _check_memory(2 * 8 * 64 * cells * args.runs, f"--runs ({args.runs})")  # keys and results: ~64 numbers a run
    import jax

    first = jax.process_index() == 0  # under jax.distributed, process 0 reports and writes
    if first:
        print(
            f"jaxnav {__version__}: {exp.name}: {exp.title}; {args.runs} runs per setting, seed {args.seed}, "
            f"output in {args.out}{' (quick variant)' if args.quick else ''}"
        )
    with warnings.catch_warnings():  # a warning (a checkpoint read unverified) is one line too
        warnings.showwarning = _warn_line(f"jaxnav {args.command}")
        result = registry.run(
            exp.name,
            args.runs,
            jax.random.PRNGKey(args.seed),
            args.out,
            quick=args.quick,
            chunk_size=args.chunk,
            progress=not args.no_progress,
            workers=args.workers,
            fresh=args.fresh,
            plot=False,
            devices=args.devices,
        )
    if not first:
        return 0
    print(exp.render(result))
    print(f"wrote {stem}.json and {stem}.md")
    _write_plot(lambda path: exp.plot(result, path), f"{stem}.png")
    return 0


_THESES = """\
  [A] G. Apostolakis, "Unmanned Vehicle Navigation in GPS-Denied Environments", diploma thesis,
      Technical University of Crete, 2020: UHF-RFID localization, EKF/UKF/grid/MCL, EKF-SLAM, FastSLAM
  [W] J. Wang, "SLAM Method for A RFID Positioning System and A Low-cost IR Positioning System for The
      Indoor Mobile Robot", doctoral dissertation, University of Fukui, 2019: HF-RFID SLAM, IR positioning"""

_DOCS = (
    "Documentation: docs/ in the repository (build the site with 'sphinx-build docs docs/_build/html')\n"
    "and its README.md."
)

_DATA = (
    "The data are read from the folder --data names, else $JAXNAV_DATA, else ../shared/data relative to\n"
    "the repository (a source checkout; ~/.local/share/jaxnav for an installed copy; never the current\n"
    "folder): a folder holding {folder}/,\ndownloaded from {source}."
)

_DATA_HELP = "data folder (default $JAXNAV_DATA, else the default data folder: see below)"

_FIGURE_HELP = "figure file; its extension (.png, .pdf, .svg, …) sets the format ('' for none; default {default})"
_OLD_FIGURE_HELP = "; a name without a figure extension gets .png, as before (deprecated)"
_FOLDER_HELP = "folder for {what}, created if missing ('' for none; default {default})"
_OLD_FOLDER_HELP = (
    "; a name that is no folder and does not end in / is, as before, a prefix of the file names (deprecated)"
)


class _HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Descriptions and examples as written; option help wrapped at spaces only (``jaxnav-mrclam/`` whole)."""

    def _split_lines(self, text: str, width: int) -> list[str]:
        return textwrap.wrap(self._whitespace_matcher.sub(" ", text).strip(), width, break_on_hyphens=False)


def _examples(*pairs: tuple[str, str]) -> str:
    """An ``Examples:`` section: each command line under a ``#`` comment saying what it does."""
    return "Examples:\n" + "\n".join(f"  # {what}\n  {command}" for what, command in pairs)


def _command(sub, name: str, help: str, description: str, examples: str) -> argparse.ArgumentParser:
    """A subcommand whose ``--help`` shows ``description`` above the options and ``examples`` below."""
    return sub.add_parser(
        name,
        help=help,
        description=description,
        epilog=examples,
        formatter_class=_HelpFormatter,
    )


def _add_demo_command(sub) -> None:
    """``jaxnav demo``: Monte Carlo localization in a simulated room."""
    demo = _command(
        sub,
        "demo",
        "MCL in a simulated 10 m room ([A] Alg. 3): the quickest look",
        """\
Monte Carlo localization, MCL ([A] Alg. 3), in a simulated 10 m x 10 m room: a robot drives
circles of radius 2.4 m (120 steps of 0.25 s a lap), measuring range and bearing to 8 landmarks
on the walls, and the filter starts from a guess 1 m off. Prints the position error at every tenth
of the run and its mean, and draws the true and estimated paths into a PNG (which needs matplotlib:
pip install 'jaxnav[plot]').""",
        _examples(
            ("one lap with 1000 particles; writes jaxnav-demo.png", "jaxnav demo"),
            (
                "half a lap with 200 particles and another seed, no PNG",
                "jaxnav demo --steps 60 --particles 200 --seed 3 --out ''",
            ),
        ),
    )
    demo.add_argument("--steps", type=_positive_int, default=120, help="time steps of 0.25 s (default 120, one lap)")
    demo.add_argument("--particles", type=_positive_int, default=1000, help="number of particles (default 1000)")
    demo.add_argument("--seed", type=_seed, default=0, help="random seed (default 0)")
    demo.add_argument(
        "--out", metavar="FILE", default="jaxnav-demo.png", help=_FIGURE_HELP.format(default="jaxnav-demo.png")
    )
    demo.set_defaults(func=_cmd_demo)


def _uwb_calibration(args: argparse.Namespace) -> int:
    """``jaxnav uwb --calibrate METHOD``: the range bias and spread learned on the first half, tested on the second."""
    chosen = args.algorithms if args.algorithms != ",".join(UWB_ALGORITHMS) else "ekf,mcl"
    algorithms = _names("--algorithms", chosen, UWB_ALGORITHMS, "algorithm")
    from jaxnav.experiments.uwb import calibration as cal
    from jaxnav.io import uwb as data

    folder = data.data_dir(args.data)
    print(
        f"jaxnav {__version__}: TU Chemnitz Labyrinth UWB dataset from {folder}; range model learned by "
        f"{args.calibrate.upper()} on the first half, filters run on the second half, seed {args.seed}"
    )
    print("Labyrinth dataset, Copyright 2017-2023 Tim Pfeifer (TU Chemnitz), CC BY-SA 4.0, distributed with libRSF")
    _compiling(f"fitting the range bias and spread, then running {', '.join(algorithms)} with three range models…")
    fit, rows = cal.run_study(args.calibrate, algorithms, runs=args.runs, seed=args.seed, root=args.data)
    print(
        f"fitted in {fit.seconds:.0f} s: bias {fit.settings.range_bias:.3f} m, spread {fit.settings.range_sd:.3f} m "
        f"(mean log-likelihood per step {-fit.result.losses[0]:.3f} -> {-fit.result.losses[-1]:.3f})"
    )
    print(cal.format_table(rows))
    return 0


def _add_mrclam_command(sub) -> None:
    """``jaxnav mrclam``: the filters of [A] ch. 2 on the MRCLAM dataset."""
    mr = _command(
        sub,
        "mrclam",
        "the filters of [A] ch. 2 on the real UTIAS MRCLAM dataset",
        f"""\
Dead reckoning, EKF and UKF localization, MCL with the known map, EKF-SLAM, FastSLAM 1.0 and 2.0
([A] ch. 2), and PF-SLAM and PS-SLAM ([W], a particle set per landmark) on the real logs of the
UTIAS MRCLAM dataset 7 (Leung et al., IJRR 30(8), 2011): the odometry of five robots and their
range-bearing measurements of barcoded landmarks, with a Vicon ground truth. Prints, for each
robot and filter, the position and heading RMSE, the ATE, the landmark RMSE of the SLAM filters
and the time taken, and draws a PNG per robot into the folder --out (needs matplotlib).

{_DATA.format(folder="utias-mrclam-dataset7", source="http://asrl.utias.utoronto.ca/datasets/mrclam/")}""",
        _examples(
            (
                "robot 1, EKF and MCL, the first 60 s of its log, no PNG",
                "jaxnav mrclam --robots 1 --algorithms ekf,mcl --duration 60 --out ''",
            ),
            (
                "robot 2: EKF, EKF-SLAM and FastSLAM 2.0 over the first 2 minutes; writes mrclam/robot2.png",
                "jaxnav mrclam --robots 2 --algorithms ekf,ekf_slam,fastslam2 --duration 120 --out mrclam/",
            ),
            (
                "noise learned on robot 1's first 300 s by MCL's likelihood; EKF, UKF, MCL on robots 1-3 with both",
                "jaxnav mrclam --calibrate mcl",
            ),
        ),
    )
    mr.add_argument("--robots", default="1,2,3", help="comma-separated robots (default 1,2,3)")
    mr.add_argument(
        "--algorithms",
        default=",".join(MRCLAM_ALGORITHMS),
        help=f"comma-separated subset of {','.join(MRCLAM_ALGORITHMS)} (default all)",
    )
    mr.add_argument(
        "--duration",
        type=_positive_number,
        default=None,
        help="seconds from the start of each log (default: all 900 s)",
    )
    mr.add_argument("--seed", type=_seed, default=0, help="seed of the particle filters (default 0)")
    mr.add_argument("--data", default=None, help=_DATA_HELP)
    mr.add_argument(
        "--out",
        metavar="DIR",
        default="jaxnav-mrclam/",
        help=_FOLDER_HELP.format(what="the PNGs, robotN.png", default="jaxnav-mrclam/") + _OLD_FOLDER_HELP,
    )
    mr.add_argument(
        "--calibrate",
        choices=("mcl", "ekf"),
        default=None,
        help="learn the motion and sensor noise on robot 1's first 300 s by MCL's likelihood (score gradient, "
        "Adam) or the ungated EKF's (L-BFGS), then run the known-map filters (--algorithms among ekf,ukf,mcl; "
        "default all three) on --robots with the hand-chosen and the learned noise; draws no PNG",
    )
    mr.add_argument(
        "--calibration-steps",
        type=_positive_int,
        default=None,
        help="optimiser steps of --calibrate (default 60 for mcl, 20 for ekf)",
    )
    mr.set_defaults(func=_cmd_mrclam)


def _add_uwb_command(sub) -> None:
    """``jaxnav uwb``: range-only localization and SLAM on real UWB ranges."""
    uw = _command(
        sub,
        "uwb",
        "range-only localization and SLAM on the real TU Chemnitz UWB ranges",
        f"""\
Dead reckoning from the wheel speeds; EKF, UKF and MCL with the four surveyed anchors (ranges with a
bias; MCL also with Student-t noise); and range-only FastSLAM 2.0, PF-SLAM and PS-SLAM with the
anchors unknown (PF- and PS-SLAM: a particle set per anchor, started on the ring of its first range;
FastSLAM: one Gaussian per anchor and particle), on the TU Chemnitz "Labyrinth" log: a
differential-drive robot ranging one UWB anchor per step, with a ground-truth path. Prints, per
algorithm, the mean position error and (SLAM) the anchors' mean error over --runs seeded runs,
and draws a PNG (needs matplotlib).

{_DATA.format(folder="tuc-labyrinth-uwb", source="https://github.com/TUC-ProAut/libRSF (datasets/Indoor_UWB)")}""",
        _examples(
            ("every algorithm, 10 runs each; writes jaxnav-uwb.png", "jaxnav uwb"),
            (
                "MCL with Student-t ranges and range-only PF-SLAM, 3 runs, no PNG",
                "jaxnav uwb --algorithms mcl_t,pf_slam --runs 3 --out ''",
            ),
            (
                "range bias and spread learned by the EKF on the first half; EKF and MCL on the second half",
                "jaxnav uwb --calibrate ekf",
            ),
        ),
    )
    uw.add_argument(
        "--algorithms",
        default=",".join(UWB_ALGORITHMS),
        help=f"comma-separated subset of {','.join(UWB_ALGORITHMS)} (default all)",
    )
    uw.add_argument("--runs", type=_positive_int, default=10, help="seeded runs of each particle filter (default 10)")
    uw.add_argument("--seed", type=_seed, default=0, help="seed of the particle filters (default 0)")
    uw.add_argument("--data", default=None, help=_DATA_HELP)
    uw.add_argument(
        "--out", metavar="FILE", default="jaxnav-uwb.png", help=_FIGURE_HELP.format(default="jaxnav-uwb.png")
    )
    uw.add_argument(
        "--calibrate",
        choices=("ekf", "mcl"),
        default=None,
        help="learn the range bias and spread on the log's first half by the EKF's likelihood (L-BFGS) or MCL's "
        "(score gradient, Adam), then run --algorithms (default ekf,mcl) on the second half with the learned, the "
        "hand-set and an unbiased range model; draws no PNG",
    )
    uw.set_defaults(func=_cmd_uwb)


def _add_hf_slam_command(sub) -> None:
    """``jaxnav hf-slam``: HF-RFID SLAM on a simulated tag carpet."""
    hf = _command(
        sub,
        "hf-slam",
        "HF-RFID SLAM on a simulated tag carpet ([W] ch. 3-4)",
        """\
HF-RFID SLAM ([W] ch. 3-4): a robot with HF-RFID readers under it drives over a 3 m x 2.5 m carpet
of passive tags laid on a grid (--density tags per m², each ±10 mm off its grid point) and
detects the tags under each reader's square footprint (--reader-mm). From the odometry and these
detections alone, PF-SLAM or PS-SLAM ([W]'s methods) or FastSLAM estimate the robot's path and
the tags' positions. Prints the robot's mean errors (x, y, θ, dr) and the tags' (tx, ty, dt) in mm
as [W]'s tables do, and draws the run into a PNG (needs matplotlib). 'jaxnav experiments' runs
[W]'s tables and figures with many seeded runs.""",
        _examples(
            (
                "PF-SLAM, 16 tags/m², 60 mm readers, six laps of the rectangle; writes jaxnav-hf-slam.png",
                "jaxnav hf-slam",
            ),
            (
                "PS-SLAM with 100 mm readers ([W] ch. 4), one lap, 200 robot particles, no PNG",
                "jaxnav hf-slam --method ps_slam --reader-mm 100 --laps 1 --robot-particles 200 --out ''",
            ),
            (
                "a kidnapping ([W] §3.4.3): the robot is carried off and PF-SLAM recovers",
                "jaxnav hf-slam --trajectory kidnapping --laps 1 --out ''",
            ),
        ),
    )
    hf.add_argument("--method", choices=HF_METHODS, default="pf_slam", help="SLAM method (default pf_slam)")
    hf.add_argument(
        "--density", type=_positive_number, default=16.0, help="tags per m² (100, 16 or 4 in [W]; default 16)"
    )
    hf.add_argument(
        "--reader-mm",
        type=_positive_number,
        default=60.0,
        help="reader footprint side in mm (60 in [W] ch. 3, 100-500 in ch. 4)",
    )
    hf.add_argument("--trajectory", choices=HF_TRAJECTORIES, default="rectangle", help="default rectangle")
    hf.add_argument(
        "--laps",
        type=_positive_int,
        default=6,
        help="laps of the rectangle (after the kidnapping for 'kidnapping'; default 6; [W]'s tables: 3)",
    )
    hf.add_argument(
        "--steps", type=_positive_int, default=2000, help="steps of 0.1 s of the random trajectory (default 2000)"
    )
    hf.add_argument(
        "--robot-particles", type=_positive_int, default=500, help="robot particles I (default 500, as [W])"
    )
    hf.add_argument(
        "--tag-particles", type=_positive_int, default=100, help="particles per tag J (default 100, as [W])"
    )
    hf.add_argument("--lag", type=_positive_int, default=20, help="PS-SLAM lag L (default 20)")
    hf.add_argument("--seed", type=_seed, default=0, help="seed of the world and the filter (default 0)")
    hf.add_argument(
        "--out",
        metavar="FILE",
        default="jaxnav-hf-slam.png",
        help=_FIGURE_HELP.format(default="jaxnav-hf-slam.png") + _OLD_FIGURE_HELP,
    )
    hf.set_defaults(func=_cmd_hf_slam)


def _add_ir_command(sub) -> None:
    """``jaxnav ir``: IR ceiling-emitter positioning, one simulated drive."""
    irp = _command(
        sub,
        "ir",
        "IR ceiling-emitter positioning, one simulated drive ([W] ch. 5)",
        """\
The low-cost IR positioning system of [W] ch. 5: IR LEDs on the ceiling blink ID codes (a unique
ID is an array of LEDs used once, a repeated ID a single LED used many times), a photodiode
receiver on the robot decodes the IDs above it, and MCL ([W] Alg. 3) fuses them with the
odometry, starting from an unknown pose once a unique ID is decoded. One simulated drive: laps of
the predetermined trajectory (loop), the 70 marked spots (spots), or the trajectory with five turns
(rotation). Prints the mean and maximum errors of the filter and of the odometry alone, and draws
the drive into a PNG (needs matplotlib). 'jaxnav experiments' runs [W]'s tables with many seeded
runs.""",
        _examples(
            ("three laps with the proposed layout and 1000 particles; writes jaxnav-ir.png", "jaxnav ir"),
            ("the trajectory with five turns, no PNG", "jaxnav ir --drive rotation --out ''"),
            (
                "two laps with both emitters of repeated ID 2 switched off ([W] §5.4.5), no PNG",
                "jaxnav ir --failed-code 2 --laps 2 --out ''",
            ),
        ),
    )
    irp.add_argument(
        "--layout",
        choices=IR_LAYOUTS,
        default="proposed",
        help="proposed (3 unique + 8 repeated IDs) or unique-11 (default proposed)",
    )
    irp.add_argument(
        "--drive",
        choices=IR_DRIVES,
        default="loop",
        help="loop (laps of the predetermined trajectory), spots (the 70 marked spots) or rotation",
    )
    irp.add_argument(
        "--height",
        type=_positive_number,
        default=1.2,
        help="emitter-receiver height in m (eq. 5.3 is for 1.2; default 1.2)",
    )
    irp.add_argument("--speed-mm", type=_positive_number, default=200.0, help="robot speed in mm/s (default 200)")
    irp.add_argument("--laps", type=_positive_int, default=3, help="laps of the loop (default 3; laps 2+ are scored)")
    irp.add_argument(
        "--failed-code",
        type=_integer,
        default=0,
        help="switch off the emitters of this repeated ID (the proposed layout has 1, 2, 4 and 5; default none)",
    )
    irp.add_argument("--particles", type=_positive_int, default=1000, help="particles (default 1000, as [W])")
    irp.add_argument("--seed", type=_seed, default=0, help="seed (default 0)")
    irp.add_argument(
        "--out",
        metavar="FILE",
        default="jaxnav-ir.png",
        help=_FIGURE_HELP.format(default="jaxnav-ir.png") + _OLD_FIGURE_HELP,
    )
    irp.set_defaults(func=_cmd_ir)


def _add_uhf_real_command(sub) -> None:
    """``jaxnav uhf-real``: UHF-RFID tag localization on the AdaRF reads."""
    ur = _command(
        sub,
        "uhf-real",
        "UHF-RFID tag localization on the real AdaRF reads ([A] Alg. 6)",
        f"""\
UHF-RFID tag localization ([A] Alg. 6) on real reads: in the AdaRF dataset a reader's antenna
moves along a 1 m track and reads the RSSI and phase of three target tags on 8 channels at 50
points. A particle filter over a tag's 2D position (its height is known) weighs the reads by
RSSI, by phase or by both (--weightings); the RSSI model's (k, θ) are fitted on another of the
three tags, whose position is taken as known ([A] §4.3.1). Prints each tag's final error against
the ground truth beside that of a uniform guess, and draws the estimates into a PNG per experiment
in the folder --out (needs matplotlib).

{_DATA.format(folder="adarf-uhf-rfid-phase", source="https://github.com/dapowan/AdaRF")}""",
        _examples(
            (
                "the phase-only filter on the default experiment with 2000 particles, no PNG",
                "jaxnav uhf-real --weightings phase --particles 2000 --out ''",
            ),
            (
                "every weighting over 3 seeds; writes jaxnav-uhf-real/181218-01-50-8.png",
                "jaxnav uhf-real --seeds 3",
            ),
            (
                "σ_phase and (k, θ) learned by maximum likelihood on every experiment, against [A]'s fit",
                "jaxnav uhf-real --calibrate --experiment all --seeds 5",
            ),
        ),
    )
    ur.add_argument(
        "--experiment", default="181218-01-50-8", help="AdaRF experiment folder, or 'all' (default 181218-01-50-8)"
    )
    ur.add_argument(
        "--weightings",
        default=",".join(UHF_WEIGHTINGS),
        help=f"comma-separated subset of {','.join(UHF_WEIGHTINGS)} (default all)",
    )
    ur.add_argument("--particles", type=_positive_int, default=5000, help="particles (default 5000)")
    ur.add_argument(
        "--reads-per-channel",
        type=_positive_int,
        default=1,
        help="reads of each of the 8 channels per aperture point (default 1)",
    )
    ur.add_argument(
        "--phase-sigma", type=_positive_number, default=0.1, help="σ_phase as a fraction of λ (default 0.1)"
    )
    ur.add_argument("--seeds", type=_positive_int, default=1, help="seeded runs per tag and weighting (default 1)")
    ur.add_argument("--seed", type=_seed, default=0, help="first seed (default 0)")
    ur.add_argument("--data", default=None, help=_DATA_HELP)
    ur.add_argument(
        "--out",
        metavar="DIR",
        default="jaxnav-uhf-real/",
        help=_FOLDER_HELP.format(what="the PNGs, EXPERIMENT.png", default="jaxnav-uhf-real/") + _OLD_FOLDER_HELP,
    )
    ur.add_argument(
        "--calibrate",
        action="store_true",
        help="learn (k, θ, σ_phase) by maximum likelihood (anchor; filter) and compare with the closed form",
    )
    ur.set_defaults(func=_cmd_uhf_real)


def _add_experiments_command(sub) -> None:
    """``jaxnav experiments``: list and run the reproductions of [A] and [W]."""
    xp = _command(
        sub,
        "experiments",
        "reproduce the tables and figures of [A] and [W] (list, run)",
        """\
The tables and figures of [A] and [W], reproduced by batch Monte Carlo: each setting of a table or
point of a figure is run --runs times with seeded keys, its runs vmapped in chunks of --chunk.
'run NAME' writes into --out NAME.json (means and 95 % intervals, beside the thesis's values where
it gives them), NAME.md (the table), NAME.png (needs matplotlib) and NAME.runs.json, the runs so
far, saved after every chunk: the same command run again resumes an interrupted sweep. --quick
runs the seconds-long variant (short runs, few particles) into NAME.quick.*.

actions:
  list        the experiments' names and what each reproduces
  run NAME    run experiment NAME (see 'list')""",
        _examples(
            ("the experiments that can be run", "jaxnav experiments list"),
            (
                "[W] Table 3.1, the seconds-long variant, 2 runs per setting, into the folder xp",
                "jaxnav experiments run table-3.1 --quick --runs 2 --out xp",
            ),
            (
                "[W] Table 5.2 in the thesis's setting, 5 runs per setting, into the folder xp",
                "jaxnav experiments run table-5.2 --runs 5 --out xp",
            ),
        ),
    )
    xp.usage = "%(prog)s [-h] {list,run} [NAME] [options]"
    xp.add_argument("action", nargs="?", choices=("list", "run"), help="list the experiments, or run one")
    xp.add_argument("name", nargs="?", metavar="NAME", help="experiment name (see 'list')")
    xp.add_argument("--runs", type=_positive_int, default=20, help="seeded runs per setting (default 20)")
    xp.add_argument(
        "--out",
        metavar="DIR",
        default="jaxnav-experiments/",
        help="folder for NAME.json, NAME.md, NAME.png and NAME.runs.json, created if missing "
        "(default jaxnav-experiments/)",
    )
    xp.add_argument("--seed", type=_seed, default=0, help="master seed (default 0)")
    xp.add_argument("--chunk", type=_positive_int, default=25, help="runs per vmapped call (bounds memory; default 25)")
    xp.add_argument(
        "--workers",
        type=_positive_int,
        default=None,
        help="chunks run at once (default: up to 4 on a CPU, its core count; 1 on a GPU or over devices)",
    )
    xp.add_argument(
        "--devices",
        type=_positive_int,
        default=None,
        help="local devices a call spreads its chunks over, one each (default: all; the numbers do not change)",
    )
    xp.add_argument(
        "--distributed",
        action="store_true",
        help="join a jax.distributed job, read from the environment (SLURM, Open MPI); process 0 writes",
    )
    xp.add_argument("--coordinator", default=None, metavar="HOST:PORT", help="address of process 0 (--distributed)")
    xp.add_argument(
        "--num-processes", type=_positive_int, default=None, metavar="N", help="processes in the job (--distributed)"
    )
    xp.add_argument(
        "--process-id", type=_non_negative_int, default=None, metavar="ID", help="this process's id (--distributed)"
    )
    xp.add_argument(
        "--fresh",
        action="store_true",
        help="discard DIR/NAME.runs.json instead of resuming it (after changing the code, or when it is "
        "refused as damaged or edited by hand)",
    )
    xp.add_argument("--quick", action="store_true", help="the seconds-long variant (short runs, few particles)")
    xp.add_argument("--no-progress", action="store_true", help="no progress display")
    xp.set_defaults(func=_cmd_experiments, help_text=xp.format_help)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="jaxnav",
        description="Vectorised JAX particle filters for indoor robot localization and SLAM: the systems of "
        "two theses,\ncited as [A] and [W] in the help of every command, and the classical filters they "
        f"build on.\n\n{_THESES}",
        epilog=_examples(
            ("Monte Carlo localization in a simulated room; writes jaxnav-demo.png", "jaxnav demo"),
            ("HF-RFID PF-SLAM of [W] on a simulated tag carpet, one lap, no PNG", "jaxnav hf-slam --laps 1 --out ''"),
            ("the tables and figures of [A] and [W] that can be reproduced", "jaxnav experiments list"),
            (
                "[W] Table 3.1 in its seconds-long variant, 2 runs per setting, results in xp/",
                "jaxnav experiments run table-3.1 --quick --runs 2 --out xp",
            ),
        )
        + f"\n\n'jaxnav COMMAND --help' tells what a command does, its options and examples.\n{_DOCS}",
        formatter_class=_HelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"jaxnav {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    _add_demo_command(sub)
    _add_mrclam_command(sub)
    _add_uwb_command(sub)
    _add_hf_slam_command(sub)
    _add_ir_command(sub)
    _add_uhf_real_command(sub)
    _add_experiments_command(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    command = f"jaxnav {args.command}"
    try:
        return args.func(args)
    except BrokenPipeError:  # output piped into `head` and the like
        return 0
    except KeyboardInterrupt:
        print(f"{command}: interrupted", file=sys.stderr)
        return 130
    except _REFUSED as err:
        print(f"{command}: error: {_one_line(err)}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
