"""Where W5's time goes: the simulation, the filter and the scoring of R PF-SLAM runs, each on its own.

``python -m benchmarks.w5_breakdown [--runs R] [--chunk C] [--out FILE]``

W5's cell ([W] Table 3.1's PF-SLAM setting: 143 tags, 1290 steps, 500 robot and 100 tag particles)
is one function of a key, :func:`jaxnav.experiments.hf_slam.run_once`: lay the carpet and simulate
the drive and its detections (``make_world``), filter (``run_method``), score (``score``). Here each
stage is its own ``jit(vmap(...))`` over chunks of ``C`` keys (those of
:func:`jaxnav.core.batch.run_keys`, as ``monte_carlo`` uses them), compiled once (timed) and then
called on every chunk (timed, ``block_until_ready``), one after the other on one device, beside the
whole function compiled and run the same way. Prints a Markdown table; ``--out`` writes the JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.w5_breakdown", description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=int, default=1000, help="runs (default 1000)")
    p.add_argument("--chunk", type=int, default=25, help="runs per call (default 25)")
    p.add_argument("--out", default=None, help="JSON file for the rows")
    args = p.parse_args(argv)

    import jax
    import numpy as np

    from benchmarks.workloads.w5_monte_carlo import setting
    from jaxnav.core.batch import run_keys
    from jaxnav.experiments.hf_slam import simulation as hs

    s = setting()
    keys = np.asarray(run_keys(jax.random.PRNGKey(0), args.runs))
    chunks = [keys[i : i + args.chunk] for i in range(0, args.runs - args.runs % args.chunk, args.chunk)]

    def halves(key):
        return jax.random.split(key)  # (world, filter), as run_once splits its key

    stages = {
        "simulation": jax.jit(jax.vmap(lambda key: hs.make_world(halves(key)[0], s))),
        "filter": jax.jit(jax.vmap(lambda key, world: hs.run_method(halves(key)[1], "pf_slam", s, world))),
        "scoring": jax.jit(jax.vmap(hs.score)),
        "whole run": jax.jit(jax.vmap(lambda key: hs.run_once(key, "pf_slam", s)[0])),
    }

    def compile_seconds(fn, *example):
        start = time.perf_counter()
        fn.lower(*example).compile()
        return time.perf_counter() - start

    rows = {name: {"compile_s": 0.0, "run_s": 0.0} for name in stages}
    worlds = jax.eval_shape(stages["simulation"], chunks[0])
    results = jax.eval_shape(stages["filter"], chunks[0], worlds)
    for name, example in (
        ("simulation", (chunks[0],)),
        ("filter", (chunks[0], worlds)),
        ("scoring", (worlds, results)),
        ("whole run", (chunks[0],)),
    ):
        rows[name]["compile_s"] = compile_seconds(stages[name], *example)

    def timed(name, *inputs):
        start = time.perf_counter()
        out = jax.block_until_ready(stages[name](*inputs))
        rows[name]["run_s"] += time.perf_counter() - start
        return out

    staged, whole = [], []
    for chunk in chunks:
        world = timed("simulation", chunk)
        result = timed("filter", chunk, world)
        staged.append(np.asarray(timed("scoring", world, result).dr_mm))
        whole.append(np.asarray(timed("whole run", chunk).dr_mm))
    runs = len(chunks) * args.chunk
    same = bool(np.array_equal(np.concatenate(staged), np.concatenate(whole)))
    total = {k: sum(rows[n][k] for n in ("simulation", "filter", "scoring")) for k in ("compile_s", "run_s")}
    print(f"\nPF-SLAM, [W] Table 3.1 setting, {runs} runs in calls of {args.chunk}, one device, one thread")
    print(f"(the stages' robot errors equal the whole run's, bit for bit: {same})\n")
    print("| stage | compile (s) | run (s) | share of the stages' run |")
    print("|---|---|---|---|")
    for name, r in rows.items():
        share = "" if name == "whole run" else f"{r['run_s'] / total['run_s']:.0%}"
        print(f"| {name} | {r['compile_s']:.1f} | {r['run_s']:.1f} | {share} |")
    print(f"| the three stages | {total['compile_s']:.1f} | {total['run_s']:.1f} | 100% |")
    if args.out:
        record = {
            "machine": {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count()},
            "runs": runs,
            "chunk": args.chunk,
            "rows": rows,
            "same_errors": same,
        }
        with open(args.out, "w") as f:
            json.dump(record, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
