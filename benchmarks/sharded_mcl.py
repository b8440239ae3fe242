"""One MCL filter's particles spread over D CPU devices (``mcl.run_sharded``) against ``mcl.run`` on one.

``python -m benchmarks.sharded_mcl [--sizes 100000,1000000] [--steps 20] [--devices 2] [--repeats 3]``

Each size runs MCL in the demo's landmark world (10 landmarks, range-bearing, velocity model,
resampling every step) for ``steps`` steps, and times, after one compiling call, the median of
``repeats`` calls of ``run`` (one device) and of ``run_sharded`` over ``D`` forced host devices
(the particles spread before the call). It reports the time per step and whether the two runs
ended with the same particles. The device count is set in ``XLA_FLAGS`` before JAX starts, so both
run in one process with ``D`` devices (``run`` uses the first).
"""

from __future__ import annotations

import argparse
import os
import sys


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.sharded_mcl", description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", default="100000,1000000", help="particle counts, comma-separated")
    p.add_argument("--steps", type=int, default=20, help="steps per run (default 20)")
    p.add_argument("--devices", type=int, default=2, help="host devices to spread over (default 2)")
    p.add_argument("--repeats", type=int, default=3, help="timed calls per measurement (default 3)")
    args = p.parse_args(argv)
    if "jax" in sys.modules:
        raise SystemExit("run as a program: the device count must be set before JAX starts")
    flag = f"--xla_force_host_platform_device_count={args.devices}"
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {flag}".strip()

    import jax
    import jax.numpy as jnp
    import numpy as np
    from jax.sharding import Mesh, NamedSharding
    from jax.sharding import PartitionSpec as P

    from benchmarks.sharded_resampling import median_seconds
    from jaxnav.core import sharded
    from jaxnav.demo import demo_setting
    from jaxnav.localization import mcl
    from jaxnav.sim import landmark_world, trajectories

    devices = jax.devices()[: args.devices]
    spread_at = NamedSharding(Mesh(np.array(devices), (sharded.PARTICLE_AXIS,)), P(sharded.PARTICLE_AXIS))
    start = jnp.asarray([5.0, 1.5, 0.0])
    _, params = demo_setting(10)
    controls = trajectories.loop_controls(args.steps, 0.5, 0.21, 0.25)
    obs = landmark_world.simulate(
        jax.random.PRNGKey(1), params.landmarks, start, controls, params.motion, params.sensor
    ).observations

    def timed(fn, *inputs):
        return median_seconds(fn, inputs, args.repeats)

    print(f"| N | one device (ms/step) | {args.devices} devices (ms/step) | ratio | same particles |")
    print("|---|---|---|---|---|")
    for n in (int(s) for s in args.sizes.split(",")):
        config = mcl.MCLConfig(num_particles=n)
        state = mcl.init(jax.random.PRNGKey(0), config, params, start, jnp.full(3, 0.3))
        key = jax.random.PRNGKey(2)
        one_s, (one, _) = timed(lambda s: mcl.run(key, s, config, params, controls, obs), state)
        spread = jax.tree_util.tree_map(lambda x: jax.device_put(x, spread_at), state)
        many_s, (many, _) = timed(
            lambda s: mcl.run_sharded(key, s, config, params, controls, obs, devices=devices), spread
        )
        same = bool(np.array_equal(np.asarray(one.particles), np.asarray(many.particles)))
        per_step = 1e3 / args.steps
        print(f"| {n:,} | {one_s * per_step:.2f} | {many_s * per_step:.2f} | {many_s / one_s:.2f} | {same} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
