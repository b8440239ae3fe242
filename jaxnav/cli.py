"""The ``jaxnav`` command line: ``jaxnav --version``, ``jaxnav demo``, ``jaxnav mrclam``."""

from __future__ import annotations

import argparse
import sys

from jaxnav._version import __version__

# the help text lists these without importing the experiment; tests/test_cli.py checks they match
_MRCLAM_ALGORITHMS = ("dead_reckoning", "ekf", "ukf", "mcl", "ekf_slam", "fastslam1", "fastslam2")


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
        try:
            path = plot_demo(result, args.out)
        except ImportError:
            print("matplotlib is not installed: no plot written (pip install 'jaxnav[plot]')")
        else:
            print(f"wrote {path}")
    return 0


def _cmd_mrclam(args: argparse.Namespace) -> int:
    from jaxnav.experiments import mrclam as xp
    from jaxnav.io import mrclam as data

    try:
        robots = [int(r) for r in args.robots.split(",") if r]
    except ValueError:
        print(f"jaxnav mrclam: --robots must be a comma-separated list of integers, got {args.robots!r}", file=sys.stderr)
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
        print(f"robot {robot}: {seq.controls.shape[0]} steps of {seq.dt:g} s, {seq.num_placed} measurements "
              f"({seq.num_outliers} of other robots or unknown barcodes, ignored by the filters)")
        if args.out:
            path = f"{args.out}-robot{robot}.png"
            try:
                xp.plot_robot(seq, results, path)
            except ImportError:
                print("matplotlib is not installed: no plot written (pip install 'jaxnav[plot]')")
            else:
                print(f"wrote {path}")
    print(xp.format_table(rows))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="jaxnav", description="Vectorised JAX particle filters for indoor localization and SLAM.")
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
    mr.add_argument("--algorithms", default=",".join(_MRCLAM_ALGORITHMS),
                    help=f"comma-separated subset of {','.join(_MRCLAM_ALGORITHMS)} (default all)")
    mr.add_argument("--duration", type=float, default=None, help="seconds from the start of each log (default: all 900 s)")
    mr.add_argument("--seed", type=int, default=0, help="seed of the particle filters (default 0)")
    mr.add_argument("--data", default=None, help="data folder (default $JAXNAV_DATA or ../shared/data)")
    mr.add_argument("--out", default="jaxnav-mrclam", help="prefix of the PNGs ('' for none; default jaxnav-mrclam)")
    mr.set_defaults(func=_cmd_mrclam)
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
