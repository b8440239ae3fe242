"""The ``jaxnav`` command line: ``--version``, ``demo``, ``mrclam``, ``hf-slam``, ``ir``, ``uhf-real``, ``experiments``."""

from __future__ import annotations

import argparse
import sys

from jaxnav._version import __version__

# the help text lists these without importing the experiment; tests/test_cli.py checks they match
MRCLAM_ALGORITHMS = ("dead_reckoning", "ekf", "ukf", "mcl", "ekf_slam", "fastslam1", "fastslam2")
HF_METHODS = ("pf_slam", "ps_slam", "fastslam")
HF_TRAJECTORIES = ("rectangle", "random", "kidnapping")
IR_LAYOUTS = ("proposed", "unique-11")
IR_DRIVES = ("spots", "loop", "rotation")
UHF_WEIGHTINGS = ("combined", "rssi", "phase")


def _write_plot(draw, path: str) -> None:
    """Call ``draw(path)`` and say where the PNG went, or that matplotlib is missing."""
    try:
        draw(path)
    except ImportError:
        print("matplotlib is not installed: no plot written (pip install 'jaxnav[plot]')")
    else:
        print(f"wrote {path}")


def _cmd_demo(args: argparse.Namespace) -> int:
    from jaxnav.demo import plot_demo, run_demo

    if args.steps < 1 or args.particles < 1:
        print("jaxnav demo: --steps and --particles must be positive", file=sys.stderr)
        return 2
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


def _cmd_mrclam(args: argparse.Namespace) -> int:
    from jaxnav.experiments import mrclam as xp
    from jaxnav.io import mrclam as data

    try:
        robots = [int(r) for r in args.robots.split(",") if r]
    except ValueError:
        print(
            f"jaxnav mrclam: --robots must be a comma-separated list of integers, got {args.robots!r}", file=sys.stderr
        )
        return 2
    algorithms = [a for a in args.algorithms.split(",") if a]
    unknown = [a for a in algorithms if a not in xp.ALGORITHMS]
    if unknown or not algorithms:
        print(f"jaxnav mrclam: unknown algorithm(s) {unknown}; choose from {','.join(xp.ALGORITHMS)}", file=sys.stderr)
        return 2
    if args.duration is not None and args.duration <= 0:
        print("jaxnav mrclam: --duration must be positive", file=sys.stderr)
        return 2
    try:
        folder = data.data_dir(args.data)
    except FileNotFoundError as err:
        print(f"jaxnav mrclam: {err}", file=sys.stderr)
        return 2
    span = "the whole log" if args.duration is None else f"{args.duration:g} s"
    print(f"jaxnav {__version__}: UTIAS MRCLAM dataset 7 from {folder}, robots {robots}, {span}, seed {args.seed}")
    print("Leung et al., IJRR 30(8), 2011 (please cite the dataset)")
    rows = []
    for robot in robots:
        try:
            seq, results = xp.run_robot(robot, algorithms, duration=args.duration, seed=args.seed, root=args.data)
        except (ValueError, FileNotFoundError) as err:
            print(f"jaxnav mrclam: robot {robot}: {err}", file=sys.stderr)
            return 2
        rows += [(robot, r) for r in results]
        print(
            f"robot {robot}: {seq.controls.shape[0]} steps of {seq.dt:g} s, {seq.num_placed} measurements "
            f"({seq.num_outliers} of other robots or unknown barcodes, ignored by the filters)"
        )
        if args.out:
            _write_plot(lambda path: xp.plot_robot(seq, results, path), f"{args.out}-robot{robot}.png")
    print(xp.format_table(rows))
    return 0


def _cmd_hf_slam(args: argparse.Namespace) -> int:
    import jax
    import numpy as np

    from jaxnav.experiments import hf_slam as xp

    if not args.reader_mm > 0:
        print(f"jaxnav hf-slam: --reader-mm must be > 0, got {args.reader_mm:g}", file=sys.stderr)
        return 2
    try:
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
        setting.sensor()
    except ValueError as err:
        print(f"jaxnav hf-slam: {err}", file=sys.stderr)
        return 2
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
        f"{steps} steps of {setting.dt:g} s, {detections} detections, {int(np.asarray(result.seen).sum())} tags mapped; "
        f"odometry alone: dr = {odo:.1f} mm"
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


def _cmd_ir(args: argparse.Namespace) -> int:
    import jax
    import numpy as np

    from jaxnav.experiments.ir import positioning as xp

    try:
        setting = xp.IRSetting(
            layout=args.layout,
            drive=args.drive,
            height=args.height,
            speed=args.speed_mm / 1000.0,
            laps=args.laps,
            failed_code=args.failed_code,
            num_particles=args.particles,
        )
        drive = xp.drive_once(jax.random.PRNGKey(args.seed), setting)
    except ValueError as err:
        print(f"jaxnav ir: {err}", file=sys.stderr)
        return 2
    steps = drive.sim.controls.shape[0]
    det = int(np.asarray(drive.sim.detections.valid).sum())
    trace = drive.trace
    print(
        f"jaxnav {__version__} ir: {setting.drive} drive, {setting.layout} layout"
        f"{f', code {setting.failed_code} failed' if setting.failed_code else ''}, height {setting.height:g} m, "
        f"{args.speed_mm:g} mm/s, {setting.num_particles} particles, seed {args.seed}"
    )
    print(
        f"{steps} steps of {setting.dt:g} s, {det} receiver detections; localization started at "
        f"{float(drive.mcl.start_s):.1f} s, {int(drive.mcl.restarts)} re-draws after it; scored: "
        f"{int((np.asarray(drive.inputs.record) >= 0).sum())} steps"
    )
    print(xp.format_errors([("IR MCL", drive.mcl), ("odometry", drive.dead)]))
    if not bool(np.asarray(trace.started)[-1]):
        print("the filter never saw a unique ID: no localization", file=sys.stderr)
    if args.out:
        _write_plot(lambda path: xp.plot_drive(drive, path), f"{args.out}.png")
    return 0


def _cmd_uhf_real(args: argparse.Namespace) -> int:
    from jaxnav.experiments.uhf import real as xp
    from jaxnav.io import adarf

    weightings = tuple(w for w in args.weightings.split(",") if w)
    try:
        setting = xp.RealSetting(
            num_particles=args.particles,
            reads_per_channel=args.reads_per_channel,
            phase_sigma_fraction=args.phase_sigma,
        )
        names = adarf.available_experiments(args.data) if args.experiment == "all" else (args.experiment,)
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
    except (ValueError, FileNotFoundError) as err:
        print(f"jaxnav uhf-real: {err}", file=sys.stderr)
        return 2
    if args.out:
        for name, res in zip(names, results):
            _write_plot(lambda path, res=res: xp.plot_results(res, path), f"{args.out}-{name}.png")
    return 0


def _cmd_experiments(args: argparse.Namespace) -> int:
    import jax

    from jaxnav.experiments import registry

    if args.action == "list":
        for name in registry.names():
            print(f"{name:<12} {registry.get(name).title}")
        return 0
    if not args.name:
        print("jaxnav experiments run: name an experiment (see 'jaxnav experiments list')", file=sys.stderr)
        return 2
    if args.runs < 1 or args.chunk < 1 or (args.workers is not None and args.workers < 1):
        print("jaxnav experiments run: --runs, --chunk and --workers must be positive", file=sys.stderr)
        return 2
    try:
        exp = registry.get(args.name)
    except ValueError as err:
        print(f"jaxnav experiments: {err}", file=sys.stderr)
        return 2
    print(
        f"jaxnav {__version__}: {exp.name}: {exp.title}; {args.runs} runs per setting, seed {args.seed}, "
        f"output in {args.out}{' (quick variant)' if args.quick else ''}"
    )
    try:
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
    except ValueError as err:
        print(f"jaxnav experiments: {err}", file=sys.stderr)
        return 2
    print(exp.render(result))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="jaxnav", description="Vectorised JAX particle filters for indoor localization and SLAM."
    )
    parser.add_argument("--version", action="version", version=f"jaxnav {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    demo = sub.add_parser("demo", help="run Monte Carlo localization in a simulated 10 m room")
    demo.add_argument("--steps", type=int, default=120, help="time steps of 0.25 s (default 120, one lap)")
    demo.add_argument("--particles", type=int, default=1000, help="number of particles (default 1000)")
    demo.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
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
        "--duration", type=float, default=None, help="seconds from the start of each log (default: all 900 s)"
    )
    mr.add_argument("--seed", type=int, default=0, help="seed of the particle filters (default 0)")
    mr.add_argument("--data", default=None, help="data folder (default $JAXNAV_DATA or ../shared/data)")
    mr.add_argument("--out", default="jaxnav-mrclam", help="prefix of the PNGs ('' for none; default jaxnav-mrclam)")
    mr.set_defaults(func=_cmd_mrclam)
    hf = sub.add_parser(
        "hf-slam", help="run PF-SLAM, PS-SLAM or FastSLAM on a simulated HF-RFID tag carpet ([W] ch. 3-4)"
    )
    hf.add_argument("--method", choices=HF_METHODS, default="pf_slam", help="SLAM method (default pf_slam)")
    hf.add_argument("--density", type=float, default=16.0, help="tags per m² (100, 16 or 4 in [W]; default 16)")
    hf.add_argument(
        "--reader-mm", type=float, default=60.0, help="reader footprint side in mm (60 in [W] ch. 3, 100-500 in ch. 4)"
    )
    hf.add_argument("--trajectory", choices=HF_TRAJECTORIES, default="rectangle", help="default rectangle (three laps)")
    hf.add_argument("--laps", type=int, default=3, help="laps of the rectangle (after the kidnapping for 'kidnapping')")
    hf.add_argument("--steps", type=int, default=2000, help="steps of 0.1 s of the random trajectory (default 2000)")
    hf.add_argument("--robot-particles", type=int, default=500, help="robot particles I (default 500, as [W])")
    hf.add_argument("--tag-particles", type=int, default=100, help="particles per tag J (default 100, as [W])")
    hf.add_argument("--lag", type=int, default=20, help="PS-SLAM lag L (default 20)")
    hf.add_argument("--seed", type=int, default=0, help="seed of the world and the filter (default 0)")
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
        "--height", type=float, default=1.2, help="emitter-receiver height in m (eq. 5.3 is for 1.2; default 1.2)"
    )
    irp.add_argument("--speed-mm", type=float, default=200.0, help="robot speed in mm/s (default 200)")
    irp.add_argument("--laps", type=int, default=3, help="laps of the loop (default 3; laps 2+ are scored)")
    irp.add_argument(
        "--failed-code", type=int, default=0, help="switch off the emitters of this repeated ID (1-9; default none)"
    )
    irp.add_argument("--particles", type=int, default=1000, help="particles (default 1000, as [W])")
    irp.add_argument("--seed", type=int, default=0, help="seed (default 0)")
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
    ur.add_argument("--particles", type=int, default=5000, help="particles (default 5000)")
    ur.add_argument(
        "--reads-per-channel",
        type=int,
        default=1,
        help="reads of each of the 8 channels per aperture point (default 1)",
    )
    ur.add_argument("--phase-sigma", type=float, default=0.1, help="σ_phase as a fraction of λ (default 0.1)")
    ur.add_argument("--seeds", type=int, default=1, help="seeded runs per tag and weighting (default 1)")
    ur.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    ur.add_argument("--data", default=None, help="data folder (default $JAXNAV_DATA or ../shared/data)")
    ur.add_argument("--out", default="jaxnav-uhf-real", help="PNG prefix ('' for none; default jaxnav-uhf-real)")
    ur.set_defaults(func=_cmd_uhf_real)
    xp = sub.add_parser("experiments", help="reproduce [W]'s and [A]'s tables and figures with batch Monte Carlo")
    xp.add_argument("action", choices=("list", "run"), help="list the experiments, or run one")
    xp.add_argument("name", nargs="?", help="experiment name (see 'list')")
    xp.add_argument("--runs", type=int, default=20, help="seeded runs per setting (default 20)")
    xp.add_argument("--out", default="jaxnav-experiments", help="output directory for JSON, Markdown and PNG")
    xp.add_argument("--seed", type=int, default=0, help="master seed (default 0)")
    xp.add_argument("--chunk", type=int, default=25, help="runs per vmapped call (bounds memory; default 25)")
    xp.add_argument(
        "--workers",
        type=int,
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
    try:
        return args.func(args)
    except BrokenPipeError:  # output piped into `head` and the like
        return 0


if __name__ == "__main__":
    sys.exit(main())
