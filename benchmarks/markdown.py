"""Print a results JSON as Markdown tables (the README's benchmark section).

``python -m benchmarks.markdown [benchmarks/results/latest.json]``

One table per workload: a row per size, a column per implementation and mode
(median seconds per call or per step), then jaxnav's best time over the
fastest peer's and over the memory floor.
"""

from __future__ import annotations

import json
import sys

from benchmarks.harness import annotate_ratios, fmt_time, is_peer, size_label


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
    for workload in sorted({r["workload"] for r in rows}):
        wrows = [r for r in rows if r["workload"] == workload]
        columns = []
        for r in wrows:
            col = (r["implementation"], r["mode"])
            if col not in columns:
                columns.append(col)
        sizes = []
        for r in wrows:
            if r["size"] not in sizes:
                sizes.append(r["size"])
        head = ["size"] + [f"{impl} ({mode})" for impl, mode in columns] + ["floor", "jaxnav best / fastest peer", "jaxnav best / floor"]
        out.append(f"\n**{workload}** (median time per call or step)\n")
        out.append("| " + " | ".join(head) + " |")
        out.append("|" + "---|" * len(head))
        for size in sizes:
            srows = [r for r in wrows if r["size"] == size]
            cells = [size_label(size)]
            for impl, mode in columns:
                hit = [r for r in srows if (r["implementation"], r["mode"]) == (impl, mode)]
                cells.append(fmt_time(hit[0]["median_s"]) if hit else "")
            floor = next((r["floor_s"] for r in srows if r.get("floor_s")), None)
            cells.append(fmt_time(floor) if floor else "")
            ours = [r for r in srows if r["implementation"] == "jaxnav"]
            peers = [r for r in srows if is_peer(r["implementation"])]
            if ours and peers:
                best = min(r["median_s"] for r in ours)
                cells.append(f"{best / min(r['median_s'] for r in peers):.2f}")
                cells.append(f"{best / floor:.0f}" if floor else "")
            else:
                cells += ["", ""]
            out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    path = argv[0] if argv else "benchmarks/results/latest.json"
    with open(path) as f:
        print(tables(json.load(f)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
