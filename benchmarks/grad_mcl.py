"""What a gradient of MCL's log-likelihood costs against the forward run (``jaxnav.calibration``).

``python -m benchmarks.grad_mcl [--sizes 1000,10000] [--steps 100] [--repeats 5] [--out FILE]``

MCL in the demo's landmark world (8 landmarks, range-bearing, velocity model, resampling every
step, the default ``"score"`` gradient) for ``steps`` steps. For each particle count it times,
after one compiling call, the median of ``repeats`` calls of

* the forward run: ``calibration.log_likelihood`` of ``mcl.kernel``, jitted;
* one gradient: ``jax.value_and_grad`` of it with respect to the sensor and motion noise, jitted
  (the work of one step of ``calibration.fit`` with one seed);
* the same gradient with every step recomputed in the backward pass (``checkpoint=True``);

and reports their ratio, the compile time of each, and the memory XLA plans for each program
(``compiled.memory_analysis()``: arguments, outputs and temporaries; the backward pass keeps the
scan's residuals, so its temporaries grow with ``steps``).
"""

from __future__ import annotations

import argparse
import json
import time


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.grad_mcl", description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", default="1000,10000", help="particle counts, comma-separated")
    p.add_argument("--steps", type=int, default=100, help="steps per run (default 100)")
    p.add_argument("--repeats", type=int, default=5, help="timed calls per measurement (default 5)")
    p.add_argument("--out", default=None, help="also write the rows as JSON to this file")
    args = p.parse_args(argv)

    import jax
    import jax.numpy as jnp

    from benchmarks.sharded_resampling import median_seconds
    from jaxnav import calibration
    from jaxnav.demo import START, demo_setting
    from jaxnav.localization import mcl
    from jaxnav.sim import landmark_world, trajectories

    controls = trajectories.loop_controls(args.steps, speed=0.5, turn_rate=0.21, dt=0.25)
    rows = []
    print(
        "| N | T | forward (ms) | gradient (ms) | checkpointed gradient (ms) | compile fwd / grad / ckpt (s) "
        "| temporaries fwd / grad / ckpt (MB) |"
    )
    print("|---|---|---|---|---|---|---|")
    for n in (int(s) for s in args.sizes.split(",")):
        config, params = demo_setting(n)
        sim = landmark_world.simulate(
            jax.random.PRNGKey(3), params.landmarks, jnp.asarray(START), controls, params.motion, params.sensor
        )
        state = mcl.init(jax.random.PRNGKey(1), config, params, jnp.asarray(START), jnp.full(3, 0.05))
        inputs = (sim.controls, sim.observations)

        def log_lik(noise, key, state=state, config=config, params=params, inputs=inputs, remat=False):
            p = params._replace(motion=noise[0], sensor=noise[1])
            return calibration.log_likelihood(mcl.kernel, key, state, config, p, *inputs, checkpoint=remat)

        def remat_grad(noise, key):
            return jax.value_and_grad(lambda z, k: log_lik(z, k, remat=True))(noise, key)

        noise = (params.motion, params.sensor)
        key = jax.random.PRNGKey(2)
        row = {"num_particles": n, "steps": args.steps}
        programs = (
            ("forward", jax.jit(log_lik)),
            ("gradient", jax.jit(jax.value_and_grad(log_lik))),
            ("checkpointed", jax.jit(remat_grad)),
        )
        for name, fn in programs:
            start = time.perf_counter()
            compiled = fn.lower(noise, key).compile()
            row[f"{name}_compile_s"] = time.perf_counter() - start
            memory = compiled.memory_analysis()
            row[f"{name}_temp_mb"] = memory.temp_size_in_bytes / 2**20 if memory is not None else float("nan")
            row[f"{name}_ms"] = 1e3 * median_seconds(compiled, (noise, key), args.repeats)[0]
        row["ratio"] = row["gradient_ms"] / row["forward_ms"]
        row["checkpointed_ratio"] = row["checkpointed_ms"] / row["forward_ms"]
        rows.append(row)
        print(
            f"| {n:,} | {args.steps} | {row['forward_ms']:.1f} | {row['gradient_ms']:.1f} ({row['ratio']:.2f}×) | "
            f"{row['checkpointed_ms']:.1f} ({row['checkpointed_ratio']:.2f}×) | "
            f"{row['forward_compile_s']:.1f} / {row['gradient_compile_s']:.1f} / {row['checkpointed_compile_s']:.1f} | "
            f"{row['forward_temp_mb']:.1f} / {row['gradient_temp_mb']:.1f} / {row['checkpointed_temp_mb']:.1f} |"
        )
    if args.out:
        with open(args.out, "w") as f:
            json.dump({"device": str(jax.devices()[0]), "rows": rows}, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
