"""PF-SLAM's (or PS-SLAM's) robot particles spread over D CPU devices (``run_sharded``) against ``run`` on one.

``python -m benchmarks.sharded_slam [--filter pf_slam] [--sizes 100000,1000000] [--steps 20] [--devices 2] [--repeats 3]``

Each size runs the filter on the first ``steps`` steps of [W]'s default HF-RFID setting (60 mm
readers, 16 tags/m², the rectangle; 100 tag particles, resampling every step), and times, after one
compiling call, the median of ``repeats`` calls of ``run`` (one device) and of ``run_sharded`` over
``D`` forced host devices (the robot particles spread before the call). It reports the time per step
and the largest difference of the two runs' robot estimates. The device count is set in
``XLA_FLAGS`` before JAX starts, so both run in one process with ``D`` devices (``run`` uses the first).
"""

from __future__ import annotations

import argparse
import os
import sys


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.sharded_slam", description=__doc__.split("\n\n")[0])
    p.add_argument("--filter", choices=("pf_slam", "ps_slam"), default="pf_slam", help="the filter (default pf_slam)")
    p.add_argument("--sizes", default="100000,1000000", help="robot particle counts, comma-separated")
    p.add_argument("--steps", type=int, default=20, help="steps per run (default 20)")
    p.add_argument("--devices", type=int, default=2, help="host devices to spread over (default 2)")
    p.add_argument("--repeats", type=int, default=3, help="timed calls per measurement (default 3)")
    args = p.parse_args(argv)
    if "jax" in sys.modules:
        raise SystemExit("run as a program: the device count must be set before JAX starts")
    flag = f"--xla_force_host_platform_device_count={args.devices}"
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {flag}".strip()

    import jax
    import numpy as np
    from jax.sharding import Mesh, NamedSharding
    from jax.sharding import PartitionSpec as P

    from benchmarks.sharded_resampling import median_seconds
    from jaxnav.core import sharded
    from jaxnav.experiments.hf_slam import simulation as hs
    from jaxnav.slam import pf_slam, ps_slam

    module = pf_slam if args.filter == "pf_slam" else ps_slam
    devices = jax.devices()[: args.devices]
    spread_at = NamedSharding(Mesh(np.array(devices), (sharded.PARTICLE_AXIS,)), P(sharded.PARTICLE_AXIS))
    setting = hs.HFSetting()
    world = hs.make_world(jax.random.PRNGKey(3), setting)
    num_tags = world.carpet.layout.num_tags
    odometry = world.run.odometry[: args.steps]
    detections = jax.tree_util.tree_map(lambda a: a[: args.steps], world.run.detections)
    sensor = setting.sensor()

    print(f"| I | one device (ms/step) | {args.devices} devices (ms/step) | ratio | largest estimate difference (m) |")
    print("|---|---|---|---|---|")
    for n in (int(s) for s in args.sizes.split(",")):
        if module is pf_slam:
            config = pf_slam.PFSLAMConfig(n, setting.tag_particles, num_tags)
            params = pf_slam.PFSLAMParams(setting.motion(), sensor)
        else:
            config = ps_slam.PSSLAMConfig(n, setting.tag_particles, num_tags, lag=setting.lag)
            params = ps_slam.PSSLAMParams(setting.motion(), sensor, ps_slam.default_jitter(sensor))
        state = module.init(jax.random.PRNGKey(0), config, params, world.run.start_pose)
        key = jax.random.PRNGKey(2)
        one_s, (_, one) = median_seconds(
            lambda s: module.run(key, s, config, params, odometry, detections), (state,), args.repeats
        )
        spread = state._replace(
            poses=jax.device_put(state.poses, spread_at), log_weights=jax.device_put(state.log_weights, spread_at)
        )
        many_s, (_, many) = median_seconds(
            lambda s: module.run_sharded(key, s, config, params, odometry, detections, devices=devices),
            (spread,),
            args.repeats,
        )
        gap = float(np.max(np.abs(np.asarray(one.estimate) - np.asarray(many.estimate))))
        per_step = 1e3 / args.steps
        print(f"| {n:,} | {one_s * per_step:.2f} | {many_s * per_step:.2f} | {many_s / one_s:.2f} | {gap:.1e} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
