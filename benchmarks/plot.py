"""One log-log PNG per workload: time against size, one line per implementation and mode,
the memory floor as a dashed black line. Saved beside the JSON file.
"""

from __future__ import annotations

import json
import math
import os
from collections import defaultdict
from collections.abc import Sequence

__all__ = ["plot_workload", "plot_all", "machine_line", "plot_w1", "plot_s1", "plot_s2", "plot_w5", "plot_u1"]

_STYLE = {
    # implementation -> (colour, marker)
    "jaxnav": ("tab:blue", "o"),
    "jaxnav-nocheck": ("tab:cyan", "o"),
    "jax-baseline": ("tab:purple", "^"),
    "numpy": ("tab:orange", "s"),
    "filterpy": ("tab:red", "D"),
    "particles": ("tab:green", "v"),
    "blackjax": ("tab:brown", "P"),
}


def plot_workload(
    name: str,
    title: str,
    rows: Sequence[dict],
    x_key: str,
    path: str,
    series_key: str | None = None,
    subtitle: str = "",
) -> str | None:
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
        ax.plot(
            [p[0] for p in pts],
            [p[1] for p in pts],
            marker=marker,
            color=colour,
            linestyle="-" if mode == "in_scan" else ":",
            linewidth=1.6,
            markersize=5,
            label=label,
        )
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


# ---------------------------------------------------------------------------
# W1: one panel per resampling scheme

_W1_SCHEMES = ("systematic", "stratified", "multinomial", "residual")
_DTYPE_FLOOR_STYLE = {"float32": ("k", "--"), "float64": ("0.45", "--")}


def plot_w1(rows: Sequence[dict], path: str, title: str = "W1", subtitle: str = "") -> str | None:
    """W1: a log-log panel per scheme, time per resampling against N; a line per implementation, mode and
    dtype (colour: implementation; solid: in_scan, dotted: per_call; filled markers: float32, open: float64),
    the memory floor of each dtype dashed. One legend for all panels."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    rows = [r for r in rows if r["workload"] == "W1" and r.get("median_s") is not None and "N" in r["size"]]
    if not rows:
        return None
    schemes = [s for s in _W1_SCHEMES if any(r.get("scheme", "systematic") == s for r in rows)]
    schemes += sorted({r["scheme"] for r in rows if r.get("scheme") and r["scheme"] not in schemes})
    ncols = 2 if len(schemes) > 1 else 1
    nrows = math.ceil(len(schemes) / ncols)
    fig, axes = plt.subplots(
        nrows, ncols, figsize=(6.2 * ncols, 4.6 * nrows + 1.4), dpi=110, squeeze=False, sharex=True, sharey=True
    )
    handles: dict[str, Line2D] = {}
    for ax, scheme in zip(axes.flat, schemes):
        sel = [r for r in rows if r.get("scheme", "systematic") == scheme]
        series: dict[tuple, list[tuple[float, float]]] = defaultdict(list)
        floors: dict[str, dict[float, float]] = defaultdict(dict)
        for r in sel:
            dtype = str(r.get("dtype", "float32")).split()[0]
            x = float(r["size"]["N"])
            series[(r["implementation"], r["mode"], dtype)].append((x, r["median_s"]))
            if r.get("floor_s"):
                floors[dtype][x] = r["floor_s"]
        order = ["jaxnav", "blackjax", "numpy", "particles", "filterpy"]
        for key in sorted(series, key=lambda k: (order.index(k[0]) if k[0] in order else 99, k)):
            impl, mode, dtype = key
            pts = sorted(series[key])
            colour, marker = _STYLE.get(impl, (None, "x"))
            label = f"{impl} ({mode}, {dtype})"
            (line,) = ax.plot(
                [p[0] for p in pts],
                [p[1] for p in pts],
                marker=marker,
                color=colour,
                markerfacecolor=colour if dtype != "float64" else "white",
                linestyle="-" if mode == "in_scan" else ":",
                linewidth=1.5,
                markersize=5,
                label=label,
            )
            handles.setdefault(label, line)
        for dtype in sorted(floors):
            fx = sorted(floors[dtype])
            colour, style = _DTYPE_FLOOR_STYLE.get(dtype, ("k", "--"))
            label = f"memory floor, {dtype} weights"
            (line,) = ax.plot(
                fx, [floors[dtype][x] for x in fx], color=colour, linestyle=style, linewidth=1.1, label=label
            )
            handles.setdefault(label, line)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(scheme, fontsize=10)
        ax.grid(True, which="major", alpha=0.4)
        ax.grid(True, which="minor", alpha=0.12)
        ax.tick_params(labelbottom=True, labelleft=True)
        ax.set_xlabel("particles N")
        ax.set_ylabel("median time per resampling (s)")
    for ax in list(axes.flat)[len(schemes) :]:
        ax.set_visible(False)
    import textwrap

    fig.suptitle("\n".join(textwrap.wrap(title, 60 * ncols)) + (f"\n{subtitle}" if subtitle else ""), fontsize=10)
    legend_cols = 2 * ncols
    # 10 pt: the figure is drawn about 0.6 times its size in a page's column, where 8 pt could not be read
    fig.legend(list(handles.values()), list(handles), loc="lower center", ncol=legend_cols, fontsize=10, frameon=False)
    legend_rows = math.ceil(len(handles) / legend_cols)
    fig.tight_layout(rect=(0, min(0.4, (0.2 + 0.2 * legend_rows) / fig.get_figheight()), 1, 1))
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path


# ---------------------------------------------------------------------------
# HF-RFID SLAM seed curves (S1, S2) and the Monte Carlo workload (W5), drawn like [W]'s figures

_METHOD_STYLE = {
    # method -> (colour, marker)
    "pf_slam": ("tab:blue", "o"),
    "ps_slam": ("tab:green", "s"),
    "fastslam": ("tab:red", "^"),
}
_MODE_LINE = {"per_call": ":", "in_scan": "-"}


def _timed(rows: Sequence[dict], name: str) -> list[dict]:
    return [r for r in rows if r["workload"] == name and r.get("median_s") is not None]


def _method_lines(ax, rows: Sequence[dict], x_key: str, label_extra=None) -> None:
    """One line per (method, mode): milliseconds per update against ``size[x_key]``."""
    series: dict[tuple, list[tuple[float, float]]] = defaultdict(list)
    for r in rows:
        series[(r.get("method", "?"), r["mode"])].append((float(r["size"][x_key]), 1e3 * r["median_s"]))
    order = list(_METHOD_STYLE)
    for key in sorted(series, key=lambda k: (order.index(k[0]) if k[0] in order else 99, k[1])):
        pts = sorted(series[key])
        colour, marker = _METHOD_STYLE.get(key[0], (None, "x"))
        label = f"{key[0]} ({key[1]})" + (label_extra(key, pts) if label_extra else "")
        ax.plot(
            [p[0] for p in pts],
            [p[1] for p in pts],
            marker=marker,
            color=colour,
            linestyle=_MODE_LINE.get(key[1], "--"),
            linewidth=1.6,
            markersize=5,
            label=label,
        )


def _title(title: str, subtitle: str) -> str:
    import textwrap

    return "\n".join(textwrap.wrap(title, 95)) + (f"\n{subtitle}" if subtitle else "")


def _plain_log_ticks(ax, axes: str = "y") -> None:
    """Log axes labelled 0.5, 1, 2 … instead of 5×10⁻¹, 10⁰, 2×10⁰."""
    from matplotlib.ticker import FuncFormatter

    fmt = FuncFormatter(lambda v, _: f"{v:g}")
    for a in axes:
        axis = ax.yaxis if a == "y" else ax.xaxis
        axis.set_major_formatter(fmt)
        axis.set_minor_formatter(FuncFormatter(lambda v, _: f"{v:g}" if f"{v:.0e}"[0] in "25" else ""))


def _save(fig, path: str) -> str:
    fig.tight_layout()
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    fig.savefig(path)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path


def plot_s1(rows: Sequence[dict], path: str, title: str = "S1", subtitle: str = "") -> str | None:
    """[W] Figs. 3.6 / 4.1a: time per update against robot particles, one panel per setting, one line per method and mode."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = _timed(rows, "S1")
    if not rows:
        return None
    settings = sorted({r.get("setting", "?") for r in rows})
    fig, axes = plt.subplots(1, len(settings), figsize=(6.4 * len(settings), 5.0), dpi=110, squeeze=False)
    for ax, name in zip(axes[0], settings):
        sel = [r for r in rows if r.get("setting", "?") == name]
        _method_lines(ax, sel, "robot_particles")
        r0 = sel[0]
        desc = ""
        if "density_tags_per_m2" in r0:
            desc = (
                f": {r0['density_tags_per_m2']:g} tags/m², {1000 * r0['reader_side_m']:g} mm readers, "
                f"{r0['size']['tags']} tags"
            )
        ax.set_title(f"{name}{desc}", fontsize=10)
        ax.set_yscale("log")
        _plain_log_ticks(ax, "y")
        ax.set_xlabel("robot particles I")
        ax.set_ylabel("time per update (ms)")
        ax.grid(True, which="major", alpha=0.4)
        ax.grid(True, which="minor", alpha=0.12)
        ax.legend(fontsize=8, loc="upper left")
    fig.suptitle(_title(title, subtitle), fontsize=10)
    return _save(fig, path)


def plot_s2(rows: Sequence[dict], path: str, title: str = "S2", subtitle: str = "") -> str | None:
    """[W] Figs. 3.8 / 4.1b: time per update against tags in the map (log x), with t(largest)/t(smallest) in the legend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = _timed(rows, "S2")
    if not rows:
        return None

    def ratio(key, pts):
        if len(pts) < 2:
            return ""
        return f"  t({pts[-1][0]:,.0f}) / t({pts[0][0]:,.0f}) = {pts[-1][1] / pts[0][1]:.2f}"

    fig, ax = plt.subplots(figsize=(7.8, 5.4), dpi=110)
    _method_lines(ax, rows, "tags", label_extra=ratio)
    ax.set_xscale("log")
    ax.set_yscale("log")
    _plain_log_ticks(ax, "y")
    ax.set_xlabel("tags in the map")
    ax.set_ylabel("time per update (ms)")
    ax.set_title(_title(title, subtitle), fontsize=10)
    ax.grid(True, which="major", alpha=0.4)
    ax.grid(True, which="minor", alpha=0.12)
    ax.legend(fontsize=8, loc="upper left")
    return _save(fig, path)


def plot_w5(rows: Sequence[dict], path: str, title: str = "W5", subtitle: str = "") -> str | None:
    """W5: seconds per run against the number of runs R in the call, and the compile time at each R."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = sorted(_timed(rows, "W5"), key=lambda r: r["size"]["runs"])
    if not rows:
        return None
    x = [r["size"]["runs"] for r in rows]
    fig, ax = plt.subplots(figsize=(7.2, 5.0), dpi=110)
    ax.plot(x, [r["median_s"] for r in rows], "o-", color="tab:blue", label="seconds per run (call / R)")
    comp = [(r["size"]["runs"], r["compile_s"]) for r in rows if r.get("compile_s") is not None]
    if comp:
        ax.plot([c[0] for c in comp], [c[1] for c in comp], "s--", color="tab:gray", label="compile (s, once per R)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    _plain_log_ticks(ax, "xy")
    ax.set_xlabel("runs R in one vmapped call")
    ax.set_ylabel("seconds")
    ax.set_title(_title(title, subtitle), fontsize=10)
    ax.grid(True, which="major", alpha=0.4)
    ax.grid(True, which="minor", alpha=0.12)
    ax.legend(fontsize=8)
    return _save(fig, path)


def plot_u1(rows: Sequence[dict], path: str, title: str = "U1", subtitle: str = "") -> str | None:
    """U1: time per step against particles N (NumPy/jaxnav written at each N), and against tags in one
    ``run_tags`` call at N = 1e4 (with the linear-scaling line G·t(1) and t(10)/t(1) in the legend)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = _timed(rows, "U1")
    if not rows:
        return None
    by_n = [r for r in rows if set(r["size"]) == {"N"}]
    by_tags = [r for r in rows if "tags" in r["size"]]
    fig, axes = plt.subplots(1, 2, figsize=(13.0, 5.2), dpi=110, gridspec_kw={"width_ratios": [1.5, 1]})
    ax = axes[0]
    series: dict[tuple, list[tuple[float, float]]] = defaultdict(list)
    floors: dict[float, float] = {}
    for r in by_n:
        series[(r["implementation"], r["mode"])].append((float(r["size"]["N"]), 1e3 * r["median_s"]))
        if r.get("floor_s"):
            floors[float(r["size"]["N"])] = 1e3 * r["floor_s"]
    for key in sorted(series, key=lambda k: (not k[0].startswith("jax"), k)):
        pts = sorted(series[key])
        colour, marker = _STYLE.get(key[0], (None, "x"))
        ax.plot(
            [p[0] for p in pts],
            [p[1] for p in pts],
            marker=marker,
            color=colour,
            linestyle="-" if key[1] == "in_scan" else ":",
            linewidth=1.6,
            markersize=5,
            label=f"{key[0]} ({key[1]})",
        )
    if floors:
        fx = sorted(floors)
        ax.plot(fx, [floors[x] for x in fx], "k--", linewidth=1.2, label="memory floor")
    ours = dict(series.get(("jaxnav", "in_scan"), []))
    for x, y in series.get(("numpy", "per_call"), []):
        if x in ours:
            ax.annotate(
                f"numpy / jaxnav = {y / ours[x]:.2f}",
                (x, y),
                textcoords="offset points",
                xytext=(6, -12),
                fontsize=8,
                color="tab:orange",
            )
    ax.set_xscale("log")
    ax.set_yscale("log")
    _plain_log_ticks(ax, "y")
    ax.set_xlabel("particles N (one tag)")
    ax.set_ylabel("time per step (ms)")
    ax.set_title("one tag: time per update against N", fontsize=10)
    ax.grid(True, which="major", alpha=0.4)
    ax.grid(True, which="minor", alpha=0.12)
    ax.legend(fontsize=8, loc="upper left")

    ax = axes[1]
    pts = sorted((int(r["size"]["tags"]), 1e3 * r["median_s"]) for r in by_tags)
    if pts:
        g = [p[0] for p in pts]
        label = "jaxnav run_tags (in_scan)"
        if len(pts) > 1:
            label += f"  t({g[-1]}) / t({g[0]}) = {pts[-1][1] / pts[0][1]:.2f}"
        ax.plot(g, [p[1] for p in pts], "o-", color="tab:blue", linewidth=1.6, markersize=5, label=label)
        t1 = pts[0][1] / pts[0][0]
        ax.plot(g, [t1 * x for x in g], "--", color="tab:gray", linewidth=1.2, label="G · t(first) (linear)")
        n_tag = by_tags[0]["size"]["N"]
        single = [r for r in by_n if r["implementation"] == "jaxnav" and r["size"]["N"] == n_tag]
        if single:
            ax.plot(
                [1],
                [1e3 * single[0]["median_s"]],
                "D",
                color="tab:cyan",
                markersize=6,
                label="jaxnav run, one tag, no vmap (in_scan)",
            )
        ax.set_title(f"N = {n_tag:g} particles per tag: time per update of all tags", fontsize=10)
    ax.set_xscale("log")
    ax.set_yscale("log")
    _plain_log_ticks(ax, "xy")
    ax.set_xlabel("tags G in one vmapped call")
    ax.set_ylabel("time per step, all tags (ms)")
    ax.grid(True, which="major", alpha=0.4)
    ax.grid(True, which="minor", alpha=0.12)
    ax.legend(fontsize=8, loc="upper left")
    fig.suptitle(_title(title, subtitle), fontsize=10)
    return _save(fig, path)


_CUSTOM = {"W1": plot_w1, "S1": plot_s1, "S2": plot_s2, "W5": plot_w5, "U1": plot_u1}


def machine_line(payload: dict) -> str:
    """What ran the rows, for a plot's subtitle: the CPU, or for a preset run JAX's device, its measured
    bandwidth and memory, and the scale-down factor where the sizes were divided."""
    m = payload.get("machine", {})
    dev = m.get("device")
    if not dev:
        return f"{m.get('cpu', '?')}, {m.get('cores', '?')} cores, copy bandwidth {m.get('bandwidth_GB_per_s', 0):.1f} GB/s"
    mem = dev.get("memory_bytes")
    line = (
        f"{dev.get('kind', '?')} ({dev.get('platform', '?')}), measured bandwidth {dev.get('bandwidth_GB_per_s', 0):.1f}"
        f" GB/s, memory {'not reported' if mem is None else f'{mem / 2**30:.0f} GiB'}"
    )
    if dev.get("platform") == "cpu":
        line += f", {m.get('cores', '?')} cores"
    opts = payload.get("options", {})
    if opts.get("scale_down"):
        line += f"; sizes ÷ {opts.get('scale_factor')}"
    return line


def plot_all(payload: dict, json_path: str, workloads: dict) -> list[str]:
    """One PNG per workload in ``payload['rows']``, named ``<json stem>_<workload>.png``."""
    stem = os.path.splitext(os.path.abspath(json_path))[0]
    subtitle = machine_line(payload)
    out = []
    names = sorted({r["workload"] for r in payload["rows"]})
    for name in names:
        wl = workloads.get(name)
        title = wl.title if wl else name
        x_key = wl.x_key if wl else next(iter(payload["rows"][0]["size"]))
        if name in _CUSTOM:
            p = _CUSTOM[name](payload["rows"], f"{stem}_{name}.png", title=title, subtitle=subtitle)
            if p:
                out.append(p)
            continue
        p = plot_workload(
            name,
            title,
            payload["rows"],
            x_key,
            f"{stem}_{name}.png",
            series_key=getattr(wl, "series_key", None),
            subtitle=subtitle,
        )
        if p:
            out.append(p)
    return out


if __name__ == "__main__":  # re-plot an existing JSON: python -m benchmarks.plot FILE
    import sys

    from benchmarks.workloads import discover

    for f in sys.argv[1:]:
        with open(f) as fh:
            print("\n".join(plot_all(json.load(fh), f, discover())))
