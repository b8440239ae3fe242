"""The ``jaxnav`` command line: ``--version``, ``demo``, ``mrclam``, ``hf-slam``, ``ir``, ``uhf-real``, ``experiments``.

Bad input never ends in a traceback: every refusal is one line on stderr,
``jaxnav COMMAND: error: MESSAGE``, naming the option or the file, with exit
status 2. Options are checked before anything is computed: numbers must be
finite and in range, ``--out`` must be writable, and the sizes of a run must
fit in this machine's memory.
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import sys
import tempfile
import zlib

from jaxnav._version import __version__

# the help text lists these without importing the experiment; tests/test_cli.py checks they match
MRCLAM_ALGORITHMS = ("dead_reckoning", "ekf", "ukf", "mcl", "ekf_slam", "fastslam1", "fastslam2")
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


def _check_out_files(option: str, value: str, paths: list[str]) -> None:
    """The files ``paths`` (derived from ``--out``) can be written: their folder takes files, none is a folder."""
    for path in paths:
        if os.path.isdir(path):
            raise ValueError(f"{option} {value!r}: {path} is a folder, not a file")
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


def _memory_bytes() -> int:
    """This machine's physical memory (bytes); 0 when unknown."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (AttributeError, ValueError, OSError):
        return 0


def _check_memory(need: int, options: str) -> None:
    """Refuse a run whose estimated memory exceeds this machine's, naming the options that size it."""
    have = _memory_bytes()
    if have and need > have:
        raise ValueError(
            f"this run would need about {need / 2**30:.3g} GiB of memory, more than this machine's "
            f"{have / 2**30:.3g} GiB: reduce {options}"
        )


def _names(option: str, text: str, choices: tuple[str, ...], what: str) -> list[str]:
    """A comma-separated list of ``choices`` (each a ``what``): at least one, all known."""
    names = [n for n in text.split(",") if n]
    unknown = [n for n in names if n not in choices]
    if unknown or not names:
        found = f"unknown {what}(s) {', '.join(unknown)}" if unknown else f"no {what} in {text!r}"
        raise ValueError(f"{option}: {found}; choose a comma-separated subset of {','.join(choices)}")
    return names


def _write_plot(draw, path: str) -> None:
    """Call ``draw(path)`` and say where the PNG went, or that matplotlib is missing."""
    try:
        draw(path)
    except ImportError:
        print("matplotlib is not installed: no plot written (pip install 'jaxnav[plot]')")
    else:
        print(f"wrote {path}")


def _cmd_demo(args: argparse.Namespace) -> int:
    if args.out:
        _check_out_files("--out", args.out, [args.out])
    # about 64 numbers a particle (one MCL step's arrays) and a step (the recorded run), doubled for XLA
    _check_memory(
        2 * 4 * (64 * args.particles + 64 * args.steps), f"--particles ({args.particles}) or --steps ({args.steps})"
    )
    from jaxnav.demo import plot_demo, run_demo

    print(
        f"jaxnav {__version__} demo: Monte Carlo localization ([A] Alg. 3), {args.particles} particles, "
        f"10 m room, 8 landmarks, {args.steps} steps, seed {args.seed}"
    )
    result = run_demo(seed=args.seed, num_steps=args.steps, num_particles=args.particles)
    print(f"{'step':>6} {'time [s]':>9} {'position error [m]':>19}")
    every = max(1, args.steps // 10)
    for i in range(0, args.steps, every):
        print(f"{i + 1:>6} {(i + 1) * result.dt:>9.2f} {result.position_error[i]:>19.3f}")
    last = args.steps - 1
    if last % every:
        print(f"{last + 1:>6} {(last + 1) * result.dt:>9.2f} {result.position_error[last]:>19.3f}")
    print(f"mean position error over the run: {result.position_error.mean():.3f} m")
    if args.out:
        _write_plot(lambda path: plot_demo(result, path), args.out)
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
    algorithms = _names("--algorithms", args.algorithms, MRCLAM_ALGORITHMS, "algorithm")
    if args.out:
        _check_out_files("--out", args.out, [f"{args.out}-robot{r}.png" for r in robots])
    from jaxnav.experiments import mrclam as xp
    from jaxnav.io import mrclam as data

    folder = data.data_dir(args.data)
    span = "the whole log" if args.duration is None else f"{args.duration:g} s"
    print(f"jaxnav {__version__}: UTIAS MRCLAM dataset 7 from {folder}, robots {robots}, {span}, seed {args.seed}")
    print("Leung et al., IJRR 30(8), 2011 (please cite the dataset)")
    rows = []
    for robot in robots:
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
        if args.out:
            _write_plot(lambda path: xp.plot_robot(seq, results, path), f"{args.out}-robot{robot}.png")
    print(xp.format_table(rows))
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
    if args.out:
        _check_out_files("--out", args.out, [f"{args.out}.png"])
    import jax
    import numpy as np

    from jaxnav.experiments import hf_slam as xp

    print(
        f"jaxnav {__version__} hf-slam: {args.method} on {setting.density:g} tags/m² (pitch {1000 * setting.pitch:.0f} mm), "
        f"{args.reader_mm:g} mm readers, {setting.trajectory} trajectory, {setting.robot_particles} robot particles, seed {args.seed}"
    )
    errors, world, result = xp.run_once(jax.random.PRNGKey(args.seed), args.method, setting)
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
    if args.out:
        _write_plot(lambda path: xp.plot_run(setting, args.method, world, result, path), f"{args.out}.png")
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
    if args.out:
        _check_out_files("--out", args.out, [f"{args.out}.png"])
    import jax
    import numpy as np

    from jaxnav.experiments.ir import positioning as xp

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
    if args.out:
        _write_plot(lambda path: xp.plot_drive(drive, path), f"{args.out}.png")
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
    if args.out:
        _check_out_files("--out", args.out, [f"{args.out}-{name}.png" for name in names])
    print(
        f"jaxnav {__version__} uhf-real: [A] Alg. 6 in 2D on the AdaRF reads ({adarf.data_dir(args.data)}), "
        f"{setting.num_particles} particles, {setting.reads_per_channel} read(s) per channel and point, "
        f"σ_phase = {setting.phase_sigma_fraction:g} λ, {args.seeds} seed(s) from {args.seed}"
    )
    results = []
    for name in names:
        res = xp.localize(name, weightings, setting, seeds=args.seeds, seed=args.seed, root=args.data)
        results.append(res)
        print(xp.format_results(res), flush=True)
    if args.out:
        for name, res in zip(names, results):
            _write_plot(lambda path, res=res: xp.plot_results(res, path), f"{args.out}-{name}.png")
    return 0


def _cmd_experiments(args: argparse.Namespace) -> int:
    from jaxnav.experiments import registry

    if args.action == "list":
        for name in registry.names():
            print(f"{name:<12} {registry.get(name).title}")
        return 0
    if not args.name:
        raise ValueError("name an experiment (see 'jaxnav experiments list')")
    exp = registry.get(args.name)
    _check_out_dir("--out", args.out)
    cells = len(exp.cells(args.quick))
    _check_memory(2 * 8 * 64 * cells * args.runs, f"--runs ({args.runs})")  # keys and results: ~64 numbers a run
    import jax

    print(
        f"jaxnav {__version__}: {exp.name}: {exp.title}; {args.runs} runs per setting, seed {args.seed}, "
        f"output in {args.out}{' (quick variant)' if args.quick else ''}"
    )
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
    )
    print(exp.render(result))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="jaxnav", description="Vectorised JAX particle filters for indoor localization and SLAM.")
    parser.add_argument("--version", action="version", version=f"jaxnav {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    demo = sub.add_parser("demo", help="run Monte Carlo localization in a simulated 10 m room")
    demo.add_argument("--steps", type=_positive_int, default=120, help="time steps of 0.25 s (default 120, one lap)")
    demo.add_argument("--particles", type=_positive_int, default=1000, help="number of particles (default 1000)")
    demo.add_argument("--seed", type=_seed, default=0, help="random seed (default 0)")
    demo.add_argument("--out", default="jaxnav-demo.png", help="PNG to write ('' for none; default jaxnav-demo.png)")
    demo.set_defaults(func=_cmd_demo)
    mr = sub.add_parser("mrclam", help="run the classical filters on the UTIAS MRCLAM real dataset and score them")
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
    mr.add_argument("--data", default=None, help="data folder (default $JAXNAV_DATA or ../shared/data)")
    mr.add_argument("--out", default="jaxnav-mrclam", help="prefix of the PNGs ('' for none; default jaxnav-mrclam)")
    mr.set_defaults(func=_cmd_mrclam)
    hf = sub.add_parser(
        "hf-slam", help="run PF-SLAM, PS-SLAM or FastSLAM on a simulated HF-RFID tag carpet ([W] ch. 3-4)"
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
    hf.add_argument("--trajectory", choices=HF_TRAJECTORIES, default="rectangle", help="default rectangle (three laps)")
    hf.add_argument(
        "--laps", type=_positive_int, default=3, help="laps of the rectangle (after the kidnapping for 'kidnapping')"
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
        "--out", default="jaxnav-hf-slam", help="PNG path without .png ('' for none; default jaxnav-hf-slam)"
    )
    hf.set_defaults(func=_cmd_hf_slam)
    irp = sub.add_parser("ir", help="localise with IR ceiling emitters on one simulated drive ([W] ch. 5)")
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
        help="switch off the emitters of this repeated ID (1-9; default none)",
    )
    irp.add_argument("--particles", type=_positive_int, default=1000, help="particles (default 1000, as [W])")
    irp.add_argument("--seed", type=_seed, default=0, help="seed (default 0)")
    irp.add_argument("--out", default="jaxnav-ir", help="PNG path without .png ('' for none; default jaxnav-ir)")
    irp.set_defaults(func=_cmd_ir)
    ur = sub.add_parser("uhf-real", help="localise the three tags of the AdaRF real UHF-RFID reads ([A] Alg. 6, 2D)")
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
    ur.add_argument("--data", default=None, help="data folder (default $JAXNAV_DATA or ../shared/data)")
    ur.add_argument("--out", default="jaxnav-uhf-real", help="PNG prefix ('' for none; default jaxnav-uhf-real)")
    ur.set_defaults(func=_cmd_uhf_real)
    xp = sub.add_parser("experiments", help="reproduce [W]'s and [A]'s tables and figures with batch Monte Carlo")
    xp.add_argument("action", choices=("list", "run"), help="list the experiments, or run one")
    xp.add_argument("name", nargs="?", help="experiment name (see 'list')")
    xp.add_argument("--runs", type=_positive_int, default=20, help="seeded runs per setting (default 20)")
    xp.add_argument("--out", default="jaxnav-experiments", help="output directory for JSON, Markdown and PNG")
    xp.add_argument("--seed", type=_seed, default=0, help="master seed (default 0)")
    xp.add_argument("--chunk", type=_positive_int, default=25, help="runs per vmapped call (bounds memory; default 25)")
    xp.add_argument(
        "--workers",
        type=_positive_int,
        default=None,
        help="chunks run at once (default: up to 4 on a CPU, its core count; 1 on a GPU)",
    )
    xp.add_argument(
        "--fresh",
        action="store_true",
        help="discard DIR/NAME.runs.json instead of resuming it (after changing the code)",
    )
    xp.add_argument("--quick", action="store_true", help="the seconds-long variant (short runs, few particles)")
    xp.add_argument("--no-progress", action="store_true", help="no progress bar")
    xp.set_defaults(func=_cmd_experiments)
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
