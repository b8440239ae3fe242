"""Print a results JSON as Markdown tables (the README's benchmark section).

``python -m benchmarks.markdown [benchmarks/results/latest.json]``

One table per workload (per workload and scheme where rows carry a ``scheme``,
as W1's do): a row per size, a column per implementation and mode (and method
where rows name one, as S1's and S2's do, and dtype where an implementation was
timed in several), median seconds per call or per
step, then jaxnav's best time over the fastest peer's and over the memory
floor (each jaxnav row over the floor of its own dtype). Rows that were not
measured are listed after the tables with their reason.
"""

from __future__ import annotations

import json
import sys

from benchmarks.harness import annotate_ratios, fmt_time, is_peer, size_label


def _table(title: str, wrows: list[dict]) -> list[str]:
    """One Markdown table: a row per size, a column per implementation and mode (and method, where rows
    name one, and dtype, where one implementation and mode was timed in several dtypes), then the floor
    and jaxnav's ratios; a column that no row fills is left out."""
    out = []
    dtypes: dict[tuple, set] = {}
    for r in wrows:
        dtypes.setdefault((r["implementation"], r["mode"]), set()).add(r.get("dtype"))
    with_dtype = any(len(d) > 1 for d in dtypes.values())
    with_method = any(r.get("method") for r in wrows)  # S1, S2: PF-SLAM, PS-SLAM and FastSLAM side by side

    def column(r):
        return (
            (r["implementation"], r["mode"])
            + ((r.get("method"),) if with_method else ())
            + ((r.get("dtype"),) if with_dtype else ())
        )

    columns = []
    for r in wrows:
        if column(r) not in columns:
            columns.append(column(r))
    sizes = []
    for r in wrows:
        if r["size"] not in sizes:
            sizes.append(r["size"])
    head = (
        ["size"]
        + [f"{c[0]} ({', '.join(str(v) for v in c[1:] if v)})" for c in columns]
        + ["floor", "jaxnav best / fastest peer", "jaxnav best / floor"]
    )
    body = []
    for size in sizes:
        srows = [r for r in wrows if r["size"] == size]
        cells = [size_label(size)]
        for c in columns:
            hit = [r for r in srows if column(r) == c]
            cells.append(fmt_time(hit[0]["median_s"]) if hit else "")
        floors: dict = {}
        for r in srows:
            if r.get("floor_s"):
                floors.setdefault(r.get("dtype") if with_dtype else None, r["floor_s"])
        if len(set(floors.values())) > 1:  # floors that depend on the dtype (W1): one per dtype
            cells.append(
                ", ".join(f"{fmt_time(f)} ({dt})" for dt, f in sorted(floors.items(), key=lambda kv: str(kv[0])))
            )
        else:
            cells.append(fmt_time(next(iter(floors.values()))) if floors else "")
        ours = [r for r in srows if r["implementation"] == "jaxnav"]
        peers = [r for r in srows if is_peer(r["implementation"])]
        if ours and peers:
            best = min(r["median_s"] for r in ours)
            cells.append(f"{best / min(r['median_s'] for r in peers):.2f}")
        else:
            cells.append("")
        to_floor = [r["median_s"] / r["floor_s"] for r in ours if r.get("floor_s")]  # each row over its own floor
        cells.append(f"{min(to_floor):.0f}" if to_floor else "")
        body.append(cells)
    # a column no row fills (no peer, no floor: S1, S2) is left out rather than shown empty
    keep = [j for j in range(len(head)) if j == 0 or any(cells[j] for cells in body)]
    out.append(f"\n**{title}** (median time per call or step)\n")
    out.append("| " + " | ".join(head[j] for j in keep) + " |")
    out.append("|" + "---|" * len(keep))
    out += ["| " + " | ".join(cells[j] for j in keep) + " |" for cells in body]
    return out


def tables(payload: dict) -> str:
    rows = [r for r in payload["rows"] if r.get("median_s") is not None]
    annotate_ratios(rows)
    out = []
    m = payload.get("machine", {})
    out.append(
        f"Measured on {m.get('cpu', '?')}, {m.get('cores', '?')} cores, copy bandwidth "
        f"{m.get('bandwidth_GB_per_s', 0):.1f} GB/s; jaxnav {payload.get('versions', {}).get('jaxnav_git', '')}, "
        f"jax {payload.get('versions', {}).get('jax', '?')}. Command: `{payload.get('options', {}).get('command', '')}`."
    )
    if m.get("device"):  # a preset run: the rows time JAX's device, the floors use its measured bandwidth
        from benchmarks.plot import machine_line

        out[-1] += f" Device: {machine_line(payload)}; the floors use that bandwidth."
    for workload in sorted({r["workload"] for r in rows}):
        wrows = [r for r in rows if r["workload"] == workload]
        schemes = []
        for r in wrows:
            if r.get("scheme") not in schemes:
                schemes.append(r.get("scheme"))
        for scheme in schemes:  # rows that name a scheme (W1) get one table per scheme
            title = workload if scheme is None else f"{workload} {scheme}"
            out += _table(title, [r for r in wrows if r.get("scheme") == scheme])
    skipped = [r for r in payload["rows"] if r.get("median_s") is None and r.get("skipped")]
    if skipped:
        out.append("\nNot measured:\n")
        for r in skipped:
            variant = " ".join(str(r[k]) for k in ("scheme", "dtype") if r.get(k) and "scheme" in r)
            out.append(
                f"* {r['workload']} {size_label(r['size'])} {r['implementation']} ({r['mode']}"
                f"{', ' + variant if variant else ''}): {r['skipped']}"
            )
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    path = argv[0] if argv else "benchmarks/results/latest.json"
    with open(path) as f:
        print(tables(json.load(f)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
