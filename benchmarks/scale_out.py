"""Runs over devices against runs over threads: W5's Monte Carlo cell as a sweep, whole processes.

``python -m benchmarks.scale_out [--runs R] [--chunk C] [--layouts 1x1,1x2,2x1] [--out FILE]``

One cell of [W] Table 3.1 (PF-SLAM on ``HFSetting(density=16)``, the W5 workload's setting: 143
tags, 1290 steps, 500 robot and 100 tag particles), ``R`` seeded runs in chunks of ``C``
(:func:`jaxnav.experiments.sweep.sweep`), evaluated in each *layout* ``DxW``: ``D`` CPU devices
(``XLA_FLAGS=--xla_force_host_platform_device_count=D``, each call a chunk per device) and ``W``
worker threads (calls at once). Today's default on a 2-core CPU is ``1x2`` (one device, two
threads); ``2x1`` is two devices and one thread. Each layout runs in a fresh process (the device
count is fixed when JAX starts), one after the other: the wall time of the sweep including its
compilation, of the compilation alone (the cell's program, compiled first), of the whole process
(with the imports), and a check that every layout gave the same runs, bit for bit. Writes ``FILE`` (JSON) and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time

_CHILD = r"""
import hashlib, json, sys, time
import jax, numpy as np
from benchmarks.workloads.w5_monte_carlo import setting
from jaxnav.core.batch import compiled_vmap, run_devices
from jaxnav.experiments import sweep as sw
from jaxnav.experiments.hf_slam import run_once

runs, chunk, devices, workers = (int(x) for x in sys.argv[1:5])
s = setting()

def errors(key):
    return run_once(key, "pf_slam", s)[0]

# the cell's program first, timed alone (the sweep then finds it compiled): the keys of one call
start = time.perf_counter()
group = min(chunk, runs) * min(devices, -(-runs // chunk))
compiled_vmap(errors, jax.ShapeDtypeStruct((group, 2), np.uint32), devices=run_devices(devices)[: group // min(chunk, runs)])
compile_s = time.perf_counter() - start
out = sw.sweep([("pf_slam", errors)], runs, jax.random.PRNGKey(0), chunk_size=chunk, progress=False,
               devices=devices, workers=workers)
wall = time.perf_counter() - start
digest = hashlib.sha256(b"".join(np.asarray(v).tobytes() for _, v in sorted(out["pf_slam"].items()))).hexdigest()
print("RESULT " + json.dumps({"wall_s": wall, "compile_s": compile_s, "sha256": digest, "mean_dr_mm": float(np.nanmean(out["pf_slam"]["dr_mm"]))}))
"""


def _layout(text: str) -> tuple[int, int]:
    devices, workers = (int(x) for x in text.split("x"))
    return devices, workers


def measure(runs: int, chunk: int, devices: int, workers: int) -> dict:
    """One layout in a fresh process: ``{"wall_s", "sha256", "mean_dr_mm"}`` of its sweep."""
    env = dict(os.environ)
    env["XLA_FLAGS"] = f"{env.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={devices}".strip()
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    start = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-c", _CHILD, str(runs), str(chunk), str(devices), str(workers)],
        capture_output=True,
        text=True,
        env=env,
        cwd=root,
        check=False,
    )
    if proc.returncode:
        raise RuntimeError(proc.stderr[-3000:])
    line = next(x for x in proc.stdout.splitlines() if x.startswith("RESULT "))
    row = json.loads(line[len("RESULT ") :])
    row["process_s"] = time.perf_counter() - start
    return row


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.scale_out", description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=int, default=16, help="runs of the cell (default 16)")
    p.add_argument("--chunk", type=int, default=4, help="runs per chunk (default 4)")
    p.add_argument("--layouts", default="1x1,1x2,2x1", help="DEVICESxWORKERS, comma-separated (default 1x1,1x2,2x1)")
    p.add_argument("--out", default=None, help="JSON file for the rows")
    args = p.parse_args(argv)
    rows = []
    for text in args.layouts.split(","):
        devices, workers = _layout(text)
        row = {"devices": devices, "workers": workers, "runs": args.runs, "chunk": args.chunk}
        row.update(measure(args.runs, args.chunk, devices, workers))
        rows.append(row)
        print(f"{text}: {row['wall_s']:.1f} s sweep, {row['process_s']:.1f} s process", flush=True)
    base = rows[0]["wall_s"]
    same = len({r["sha256"] for r in rows}) == 1
    print(
        f"\nPF-SLAM, [W] Table 3.1 setting, {args.runs} runs in chunks of {args.chunk}; same runs bit for bit: {same}\n"
    )
    print("| devices | workers | sweep with compile (s) | of which compile (s) | process (s) | vs first |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['devices']} | {r['workers']} | {r['wall_s']:.1f} | {r['compile_s']:.1f} | {r['process_s']:.1f} "
            f"| {r['wall_s'] / base:.2f} |"
        )
    if args.out:
        record = {"machine": {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count()}, "rows": rows}
        record["same_runs"] = same
        with open(args.out, "w") as f:
            json.dump(record, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
