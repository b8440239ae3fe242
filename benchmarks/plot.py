"""One log-log PNG per workload: time against size, one line per implementation and mode,
the memory floor as a dashed black line. Saved beside the JSON file.
"""

from __future__ import annotations

import json
import os
from collections import defaultdict
from typing import Sequence

__all__ = ["plot_workload", "plot_all"]

_STYLE = {
    # implementation -> (colour, marker)
    "jaxnav": ("tab:blue", "o"),
    "jaxnav-nocheck": ("tab:cyan", "o"),
    "jax-baseline": ("tab:purple", "^"),
    "numpy": ("tab:orange", "s"),
    "filterpy": ("tab:red", "D"),
    "particles": ("tab:green", "v"),
}


def plot_workload(name: str, title: str, rows: Sequence[dict], x_key: str, path: str,
                  series_key: str | None = None, subtitle: str = "") -> str | None:
    """Draw workload ``name``'s rows to ``path``; returns the path, or None if nothing was timed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in rows if r["workload"] == name and r.get("median_s") is not None and x_key in r["size"]]
    if not rows:
        return None
    series: dict[tuple, list[tuple[float, float]]] = defaultdict(list)
    floors: dict[float, float] = {}
    for r in rows:
        key = (r["implementation"], r["mode"]) + ((r.get(series_key),) if series_key else ())
        x = float(r["size"][x_key])
        series[key].append((x, r["median_s"]))
        if r.get("floor_s"):
            floors[x] = r["floor_s"]

    fig, ax = plt.subplots(figsize=(7.5, 5.2), dpi=110)
    for key in sorted(series, key=lambda k: (not k[0].startswith("jax"), k)):
        pts = sorted(series[key])
        impl, mode = key[0], key[1]
        colour, marker = _STYLE.get(impl, (None, "x"))
        label = f"{impl} ({mode})" + (f" [{key[2]}]" if len(key) > 2 else "")
        ax.plot([p[0] for p in pts], [p[1] for p in pts], marker=marker, color=colour,
                linestyle="-" if mode == "in_scan" else ":", linewidth=1.6, markersize=5, label=label)
    if floors:
        fx = sorted(floors)
        ax.plot(fx, [floors[x] for x in fx], "k--", linewidth=1.2, label="memory floor")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(x_key)
    ax.set_ylabel("median time (s)")
    ax.set_title(title + (f"\n{subtitle}" if subtitle else ""), fontsize=10)
    ax.grid(True, which="major", alpha=0.4)
    ax.grid(True, which="minor", alpha=0.12)
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_all(payload: dict, json_path: str, workloads: dict) -> list[str]:
    """One PNG per workload in ``payload['rows']``, named ``<json stem>_<workload>.png``."""
    stem = os.path.splitext(os.path.abspath(json_path))[0]
    m = payload.get("machine", {})
    subtitle = f"{m.get('cpu', '?')}, {m.get('cores', '?')} cores, copy bandwidth {m.get('bandwidth_GB_per_s', 0):.1f} GB/s"
    out = []
    names = sorted({r["workload"] for r in payload["rows"]})
    for name in names:
        wl = workloads.get(name)
        title = wl.title if wl else name
        x_key = wl.x_key if wl else next(iter(payload["rows"][0]["size"]))
        p = plot_workload(name, title, payload["rows"], x_key, f"{stem}_{name}.png",
                          series_key=getattr(wl, "series_key", None), subtitle=subtitle)
        if p:
            out.append(p)
    return out


if __name__ == "__main__":  # re-plot an existing JSON: python -m benchmarks.plot FILE
    import sys

    from benchmarks.workloads import discover

    for f in sys.argv[1:]:
        with open(f) as fh:
            print("\n".join(plot_all(json.load(fh), f, discover())))
