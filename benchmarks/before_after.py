"""Before-and-after markdown table of two benchmark result files.

``python -m benchmarks.before_after BEFORE.json AFTER.json [--only W2,W4] [--implementation jaxnav]``

One line per measurement found in either file (workload, size, method or scheme,
implementation, mode, dtype), with both medians and their ratio ``after / before``.
Both files should come from the same machine; each file's ``machine`` line is printed first.
"""

from __future__ import annotations

import argparse
import json


def _fmt(seconds: float | None) -> str:
    if seconds is None:
        return ""
    return f"{seconds * 1e3:.2f} ms" if seconds >= 1e-3 else f"{seconds * 1e6:.1f} µs"


def _size(size: dict) -> str:
    return ",".join(f"{k}={v:g}" if isinstance(v, (int, float)) else f"{k}={v}" for k, v in size.items())


def _key(row: dict) -> tuple:
    variant = row.get("method") or row.get("scheme") or ""
    return (row["workload"], _size(row["size"]), variant, row["implementation"], row["mode"], row.get("dtype", ""))


def _rows(path: str) -> tuple[dict, dict]:
    with open(path) as f:
        data = json.load(f)
    return data.get("machine", {}), {_key(r): r for r in data["rows"] if r.get("median_s") is not None}


def table(before: str, after: str, only: list[str] | None = None, implementation: str | None = None) -> str:
    """The markdown table (with a machine line per file) of the rows of ``before`` and ``after``."""
    (m_before, b), (m_after, a) = _rows(before), _rows(after)
    lines = [
        f"before: {m_before.get('cpu')}, {m_before.get('cores')} cores, "
        f"{m_before.get('bandwidth_GB_per_s', 0):.1f} GB/s; after: {m_after.get('cpu')}, "
        f"{m_after.get('cores')} cores, {m_after.get('bandwidth_GB_per_s', 0):.1f} GB/s",
        "",
        "| workload | size | method / scheme | implementation | mode | dtype | before | after | after / before |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    order = {k: i for i, k in enumerate([*b, *a])}
    for k in sorted(set(a) | set(b), key=lambda k: (k[0], order[k])):
        if (only and k[0] not in only) or (implementation and k[3] != implementation):
            continue
        mb = b[k]["median_s"] if k in b else None
        ma = a[k]["median_s"] if k in a else None
        ratio = f"{ma / mb:.2f}" if mb and ma else ""
        lines.append(f"| {' | '.join(k)} | {_fmt(mb)} | {_fmt(ma)} | {ratio} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.before_after", description=__doc__.split("\n\n")[0])
    p.add_argument("before")
    p.add_argument("after")
    p.add_argument("--only", default=None, help="comma-separated workloads")
    p.add_argument("--implementation", default=None, help="only this implementation's rows")
    args = p.parse_args(argv)
    print(table(args.before, args.after, args.only.split(",") if args.only else None, args.implementation))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
