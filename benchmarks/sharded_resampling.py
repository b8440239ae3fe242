"""Exact systematic resampling of N particles spread over D CPU devices against one device.

``python -m benchmarks.sharded_resampling [--sizes 1000000,10000000] [--devices 2] [--repeats 5]``

Each size draws lognormal weights (``exp(3·z)``) and particles ``[N, 3]``, then times, after one
compiling call, the median of ``repeats`` calls of:

* ``one device``: :func:`jaxnav.core.resampling.resample_weights` and a gather of the particles;
* ``D devices``: :func:`jaxnav.core.sharded.resample_weights` and :func:`jaxnav.core.sharded.take`
  inside ``jax.shard_map`` over ``D`` forced host devices (the weights and particles already
  spread), and checks that both give the same ancestors.

The device count is set in ``XLA_FLAGS`` before JAX starts (``--devices``), so both run in one
process with ``D`` devices (the one-device program uses the first).
"""

from __future__ import annotations

import argparse
import os
import sys
import time


def median_seconds(fn, inputs: tuple, repeats: int) -> tuple[float, object]:
    """``(median seconds of repeats calls of fn(*inputs), its output)``, after one untimed call (the compilation)."""
    import jax
    import numpy as np

    out = jax.block_until_ready(fn(*inputs))
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(*inputs))
        times.append(time.perf_counter() - start)
    return float(np.median(times)), out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.sharded_resampling", description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", default="1000000,10000000", help="particle counts, comma-separated")
    p.add_argument("--devices", type=int, default=2, help="host devices to spread over (default 2)")
    p.add_argument("--repeats", type=int, default=5, help="timed calls per measurement (default 5)")
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

    from jaxnav.core import resampling, sharded

    mesh = Mesh(np.array(jax.devices()[: args.devices]), ("particles",))
    spread_at = NamedSharding(mesh, P("particles"))

    def timed(fn, *inputs):
        return median_seconds(fn, inputs, args.repeats)

    print(f"| N | one device (ms) | {args.devices} devices (ms) | ratio | same ancestors |")
    print("|---|---|---|---|---|")
    for n in (int(s) for s in args.sizes.split(",")):
        key = jax.random.PRNGKey(0)
        w = jnp.exp(3.0 * jax.random.normal(jax.random.PRNGKey(1), (n,)))
        x = jax.random.normal(jax.random.PRNGKey(2), (n, 3))

        @jax.jit
        def one(key, w, x):
            a = resampling.resample_weights(key, w, n)
            return jnp.take(x, a, axis=0), a

        def block(key, w, x):
            a = sharded.resample_weights(key, w, n, "particles")
            return sharded.take(x, a, "particles"), a

        spread = jax.jit(
            jax.shard_map(
                block, mesh=mesh, in_specs=(P(), P("particles"), P("particles")), out_specs=(P("particles"),) * 2
            )
        )
        t_one, (_, a_one) = timed(one, key, w, x)
        t_spread, (_, a_spread) = timed(spread, key, jax.device_put(w, spread_at), jax.device_put(x, spread_at))
        same = bool(np.array_equal(np.asarray(a_one), np.asarray(a_spread)))
        print(f"| {n:.0e} | {t_one * 1e3:.1f} | {t_spread * 1e3:.1f} | {t_spread / t_one:.2f} | {same} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
