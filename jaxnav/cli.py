"""The ``jaxnav`` command line: ``jaxnav --version``, ``jaxnav demo``."""

from __future__ import annotations

import argparse
import sys

from jaxnav._version import __version__


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
