"""Entry point: ``python -m benchmarks.run [--only W1,W2] [--quick] [--out FILE] [--repeats K]``.

Runs the registered workloads (all by default), or a preset's plan (``--preset gpu``, see
:mod:`benchmarks.presets`; ``--scale-down`` divides its sizes), writes one JSON file
(default ``benchmarks/results/latest.json``) holding ``machine`` (CPU, cores,
the memory bandwidth measured at the start of this run), ``versions`` and
``rows`` (one per measurement, :func:`benchmarks.harness.make_row`), draws one PNG per workload beside it and
prints a table. Workloads are discovered from :mod:`benchmarks.workloads`; a
new workload is a new module there, this file does not change. A preset run also records JAX's
default device (``machine["device"]``: kind, platform, memory, and its bandwidth measured at the
start, which the floors then use).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import traceback

import jax

from benchmarks import harness
from benchmarks.harness import Context
from benchmarks.presets import PRESETS
from benchmarks.workloads import discover

DISTURBED = 0.2  # cores used by other processes above which a measurement is repeated
RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")
DEFAULT_OUT = os.path.join(RESULTS, "latest.json")


def default_out(preset: str | None, scale_down: bool) -> str:
    """``results/latest.json``; for a preset ``results/<preset>_preset.json`` (``_scaled`` added when scaled down)."""
    if preset is None:
        return DEFAULT_OUT
    return os.path.join(RESULTS, f"{preset}_preset{'_scaled' if scale_down else ''}.json")


def budget_reason(budget_s: float | None, spent_s: float, previous_s: float) -> str | None:
    """Why a size is not started under a run budget of ``budget_s`` seconds, or None to start it.

    A started size runs to its end, so the guard is at its start: no size starts once ``spent_s``
    reaches the budget, nor when ``spent_s`` plus ``previous_s`` (the wall time of the workload's
    previous, smaller size: a lower estimate of the next one's) would pass it. Seconds throughout.
    """
    if budget_s is None:
        return None
    if spent_s >= budget_s:
        return f"run budget: {spent_s:.0f} s of {budget_s:g} s spent before this size"
    if spent_s + previous_s > budget_s:
        return f"run budget: {spent_s:.0f} s of {budget_s:g} s spent, and the previous size took {previous_s:.0f} s"
    return None


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m benchmarks.run", description=__doc__.split("\n\n")[0])
    p.add_argument("--only", default=None, help="comma-separated workload names, e.g. W1,W2 (default: all)")
    p.add_argument("--quick", action="store_true", help="the two smallest sizes of each workload")
    p.add_argument(
        "--out",
        default=None,
        help="JSON output file, plots beside it (default results/latest.json; preset: results/<preset>_preset.json)",
    )
    p.add_argument(
        "--preset",
        choices=sorted(PRESETS),
        default=None,
        help="a preset's workloads, sizes and implementations on JAX's default device (benchmarks/presets.py)",
    )
    p.add_argument(
        "--scale-down",
        action="store_true",
        help="with --preset: every size divided by the preset's factor (1000 for gpu), to run on a small CPU",
    )
    p.add_argument(
        "--budget",
        type=float,
        default=None,
        metavar="SECONDS",
        help="start no size once the run has taken SECONDS (default: the preset's, 480 s for gpu; else none)",
    )
    p.add_argument(
        "--repeats",
        type=int,
        default=None,
        help="timed repeats (or passes of a trajectory) per measurement; default per workload",
    )
    p.add_argument("--no-plot", action="store_true", help="skip the PNGs")
    p.add_argument(
        "--wait-quiet",
        type=float,
        default=0.0,
        metavar="SECONDS",
        help="before each size, wait up to SECONDS for other processes to leave the CPUs idle",
    )
    p.add_argument(
        "--retries",
        type=int,
        default=1,
        help="re-measure an implementation this many times when other processes used > 0.2 cores "
        "during it (after waiting for a quiet machine; keeps the least disturbed attempt; default 1)",
    )
    return p.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    registry = discover()
    preset = PRESETS[args.preset] if args.preset else None
    if args.scale_down and preset is None:
        print("--scale-down needs --preset", file=sys.stderr)
        return 2
    if preset is not None and args.quick:
        print("--quick and --preset both choose sizes; give one (--scale-down shrinks a preset)", file=sys.stderr)
        return 2
    if preset is not None:
        plan = preset.plan(args.scale_down)
        registry = {n: w for n, w in registry.items() if n in plan}
    out_path = args.out or default_out(args.preset, args.scale_down)
    budget_s = args.budget if args.budget is not None else (preset.budget_s if preset else None)
    if args.only:
        wanted = [w.strip() for w in args.only.split(",") if w.strip()]
        unknown = [w for w in wanted if w not in registry]
        if unknown:
            print(f"unknown workload(s) {unknown}; registered: {list(registry)}", file=sys.stderr)
            return 2
        selected = {w: registry[w] for w in registry if w in wanted}
    else:
        selected = registry
    if args.repeats is not None and args.repeats < 1:
        print("--repeats must be >= 1", file=sys.stderr)
        return 2

    t_start = time.perf_counter()
    harness.import_all_jaxnav()  # freeze the code version timed by this run
    print("measuring memory bandwidth …", flush=True)
    bw = harness.measure_bandwidth()
    machine = harness.machine_info(bw)
    vers = harness.versions()
    print(f"{machine['cpu']}, {machine['cores']} cores, copy bandwidth {bw['bandwidth_GB_per_s']:.2f} GB/s", flush=True)
    floor_bw = bw["bandwidth_bytes_per_s"]
    if preset is not None:
        # The preset times the device, so its floors are the device's memory traffic, not the host's.
        print("measuring the device's memory bandwidth …", flush=True)
        device = harness.device_info()
        device.update(harness.measure_device_bandwidth())
        machine["device"] = device
        floor_bw = device["bandwidth_bytes_per_s"]
        mem = device["memory_bytes"]
        print(
            f"device {device['kind']} ({device['platform']}), measured bandwidth {device['bandwidth_GB_per_s']:.1f} "
            f"GB/s (copy), memory {'not reported' if mem is None else f'{mem / 2**30:.1f} GiB'}",
            flush=True,
        )
    print("versions: " + ", ".join(f"{k} {v}" for k, v in vers.items()), flush=True)
    ctx = Context(
        quick=args.quick,
        repeats=args.repeats,
        bandwidth=floor_bw,
        retries=args.retries,
        disturbed=DISTURBED,
        implementations=preset.implementations if preset else None,
        sizes={n: plan[n] if preset else w.sizes_for(args.quick) for n, w in selected.items()},
    )

    rows: list[dict] = []

    def payload(complete: bool) -> dict:
        return {
            "machine": machine,
            "versions": vers,
            "options": {
                "only": args.only,
                "quick": args.quick,
                "repeats": args.repeats,
                "command": " ".join([os.path.basename(sys.executable), "-m", "benchmarks.run"] + sys.argv[1:]),
                "budget_s": budget_s,
                **(
                    {
                        "preset": preset.name,
                        "scale_down": args.scale_down,
                        "scale_factor": preset.scale_factor if args.scale_down else 1,
                        "plan": ctx.sizes,
                        "implementations": sorted(preset.implementations),
                        "floors_from": "machine.device bandwidth (measured)",
                    }
                    if preset
                    else {}
                ),
            },
            "workloads": {n: {"title": w.title, "floor": w.floor_doc} for n, w in selected.items()},
            "notes": ctx.notes,
            "complete": complete,
            "total_wall_s": time.perf_counter() - t_start,
            "rows": rows,
        }

    for name, wl in selected.items():
        previous_s = 0.0  # wall time of this workload's previous size
        for size in ctx.sizes_of(wl):
            label = harness.size_label(size)
            why = budget_reason(budget_s, time.perf_counter() - t_start, previous_s)
            if why:
                print(f"[{name}] {label} not started ({why})", flush=True)
                rows.append(harness.skipped_row(name, "(all)", size, "per_call", why))
                ctx.note(f"run budget of {budget_s:g} s: the sizes not started are skipped rows")
                continue
            print(f"[{name}] {label} …", flush=True)
            if args.wait_quiet > 0:
                harness.wait_for_quiet(args.wait_quiet)
            t0 = time.perf_counter()
            with harness.CpuMonitor() as mon:
                try:
                    new = wl.run(ctx, size)
                except Exception as exc:  # one broken workload must not lose the others' results
                    traceback.print_exc()
                    new = [harness.skipped_row(name, "(all)", size, "per_call", f"error: {type(exc).__name__}: {exc}")]
            load = mon.other_cores
            for r in new:
                r.setdefault("other_load_cores", load)
            worst = max((r["other_load_cores"] for r in new if r.get("other_load_cores") is not None), default=None)
            if worst is not None and worst > ctx.disturbed:
                ctx.note(
                    f"{name} {label}: some timings may be disturbed (up to {worst:.2f} cores used by other processes)"
                )
            for r in new:
                status = (
                    harness.fmt_time(r["median_s"])
                    if r.get("median_s") is not None
                    else f"skipped ({r.get('skipped')})"
                )
                variant = harness.variant_label(r)
                print(
                    f"    {r['implementation']:<15} {r['mode']:<9} {variant + ' ' if variant else ''}{status}",
                    flush=True,
                )
            busy = "" if load is None else f", other processes {load:.2f} cores"
            previous_s = time.perf_counter() - t0
            print(f"    ({previous_s:.1f} s{busy})", flush=True)
            rows.extend(new)
            # Written after every size, so a run that dies (an abort in XLA cannot be caught: a full
            # S1 run once died at 5000 particles with "LLVM ERROR: Unable to allocate section
            # memory") keeps what it measured; "complete" stays false until the end.
            harness.write_json(out_path, payload(complete=False))
            # Drop the compiled executables of finished sizes: a long run need not keep them.
            jax.clear_caches()

    src_end = harness.jaxnav_source_state()
    if (src_end["jaxnav_git"], src_end["jaxnav_dirty"]) != (vers["jaxnav_git"], vers["jaxnav_dirty"]):
        ctx.note(
            f"jaxnav source changed during the run (start {vers['jaxnav_git']} dirty={vers['jaxnav_dirty']}, "
            f"end {src_end['jaxnav_git']} dirty={src_end['jaxnav_dirty']}); all modules were imported at the "
            "start, so the rows time the start version"
        )
    if vers.get("jaxnav_dirty"):
        ctx.note("jaxnav/ had uncommitted changes when the run started")
    harness.annotate_ratios(rows)
    final = payload(complete=True)
    harness.write_json(out_path, final)
    print()
    print(harness.format_table(rows))
    print()
    print(f"wrote {out_path}")
    if not args.no_plot:
        from benchmarks.plot import plot_all

        for p in plot_all(final, out_path, selected):
            print(f"wrote {p}")
    print(f"total {time.perf_counter() - t_start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
