"""[W]'s HF-RFID SLAM error tables (3.1, 3.2, 4.1, 4.2) as experiments.

Each table row is a method on a setting; a row's value in a column is the
mean over the row's runs with its 95 % interval, printed beside [W]'s single
run. The per-run errors are those of :func:`jaxnav.experiments.hf_slam.simulation.score`
(robot x, y, θ, distance over all steps; tag x, y, distance at the end, mm
and rad). A run that mapped no tag has no tag errors (NaN): it is left out
of the tag columns' means and counted in their ``unscored_runs``, and a
column no run could score reads "n/a (nothing mapped)". A run whose robot
errors are not finite diverged: it is left out of every column of its row,
counted in the row's ``diverged_runs`` (always present) and named under the
table ("2 of 100 runs diverged"). Settings and noise
levels are listed in :mod:`jaxnav.experiments.hf_slam.simulation`; the quick
variants shorten the trajectory and cut the particles so that the test suite
runs them in seconds. The four tables are :data:`EXPERIMENTS`.
"""

from __future__ import annotations

import re
import textwrap
from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from jaxnav.experiments import report, stats
from jaxnav.experiments import sweep as sw
from jaxnav.experiments.experiment import Cell, Experiment
from jaxnav.experiments.hf_slam import simulation as hf
from jaxnav.experiments.hf_slam.simulation import (
    COLUMN_HEADS,
    ERROR_COLUMNS,
    METHOD_LABELS,
    NOTHING_MAPPED,
    TAG_COLUMNS,
)

__all__ = [
    "TableRow",
    "table_experiment",
    "summarize_column",
    "diverged_in",
    "ROBOT_COLUMNS",
    "QUICK",
    "quick_setting",
    "setting_label",
    "FIVE_RECTANGLES",
    "METHOD_LABELS",
    "EXPERIMENTS",
]

ROBOT_COLUMNS = tuple(c for c in ERROR_COLUMNS if c not in TAG_COLUMNS)
"""The error columns every run has (robot x, y, θ, dr); a non-finite one means the run diverged."""

QUICK = dict(robot_particles=100, tag_particles=30, laps=1, random_steps=300)
"""What the quick variants change — particles, laps, random-trajectory length (and a smaller world)."""

FIVE_RECTANGLES = (
    (0.5, 0.5, 2.0, 1.5),
    (0.75, 0.5, 2.5, 1.0),
    (0.5, 0.75, 1.5, 2.0),
    (1.0, 1.0, 2.25, 1.25),
    (0.6, 0.6, 1.75, 1.75),
)
"""The five predetermined rectangles of [W] §4.4.1 (ours, as [W] does not give them), ``(x0, y0, w, h)``
in m, on a 4 m × 3.5 m carpet; perimeters 6.5–7.5 m."""


class TableRow:
    """One row of a table: a method on one or more settings (pooled), and [W]'s values."""

    def __init__(self, label: str, method: str, settings: Sequence[hf.HFSetting], paper: Sequence[float | None]):
        self.label, self.method, self.settings, self.paper = label, method, tuple(settings), tuple(paper)


def setting_label(s: hf.HFSetting, method: str = "") -> dict:
    """The JSON ``setting`` of a row: density, reader size, trajectory, and for a FastSLAM row its Gaussian
    (``HFSetting.fastslam_gaussian``) and, where it is 2, its version."""
    out = {"density": s.density, "reader_mm": round(1000 * s.reader_side, 3), "trajectory": s.trajectory}
    if method == "fastslam":
        out["fastslam_gaussian"] = s.fastslam_gaussian
        if s.fastslam_version != 1:
            out["fastslam_version"] = s.fastslam_version
    return out


def quick_setting(s: hf.HFSetting) -> hf.HFSetting:
    """The seconds-long variant of a setting: a smaller world, one lap, fewer particles."""
    q = replace(s, **QUICK)
    if s.trajectory == "random":
        return replace(q, carpet=(1.5, 1.5))
    x0, y0, w, h = s.rectangle
    scale = 0.5
    return replace(
        q,
        carpet=(min(s.carpet[0], x0 + scale * w + 0.5), min(s.carpet[1], y0 + scale * h + 0.5)),
        rectangle=(x0, y0, scale * w, scale * h),
    )


def diverged_in(values: dict) -> np.ndarray:
    """``[R]``: the runs of per-run errors ``{column: [R]}`` whose robot errors are not finite (diverged)."""
    return stats.diverged_runs(*(values[c] for c in ROBOT_COLUMNS))


def summarize_column(values: np.ndarray, paper: float | None, diverged: np.ndarray | None = None) -> dict:
    """``{"mean", "ci95": [lo, hi], "paper"}`` of one column's per-run values, the ``diverged`` runs left
    out (and ``"unscored_runs"`` when other runs have no value: :func:`jaxnav.experiments.stats.column_summary`)."""
    s = stats.column_summary(values, diverged)
    out = {"mean": s["mean"], "ci95": s["ci95"], "paper": paper}
    if "unscored_runs" in s:
        out["unscored_runs"] = s["unscored_runs"]
    return out


def table_experiment(name: str, title: str, rows: Sequence[TableRow], notes: str = "") -> Experiment:
    """A table experiment from its rows."""

    def cells(quick: bool) -> list[Cell]:
        out = []
        for row in rows:
            # the quick variant runs a pooled row's first setting only
            for i, s in enumerate(row.settings[:1] if quick else row.settings):
                s = quick_setting(s) if quick else s
                cell_id = f"{row.label}|{row.method}|{i}"
                out.append(Cell(cell_id, row.label, row.method, s, hf.error_cell(row.method, s)))
        return out

    def summarize(raw: dict, cell_list: list[Cell], quick: bool) -> dict:
        out_rows = []
        for row in rows:
            members = [c for c in cell_list if c.row == row.label and c.method == row.method]
            values = {col: np.concatenate([raw[c.id][col] for c in members]) for col in ERROR_COLUMNS}
            diverged = diverged_in(values)
            entry = {
                "row": row.label,
                "setting": setting_label(members[0].setting, row.method),
                "method": row.method,
                "cells": len(members),
                "runs": int(diverged.size),
                "diverged_runs": int(diverged.sum()),
            }
            for col, paper in zip(ERROR_COLUMNS, row.paper):
                entry[col] = summarize_column(values[col], paper, diverged)
            out_rows.append(entry)
        return {"rows": out_rows, "notes": notes}

    CELLS_BY_NAME[name] = cells
    return Experiment(
        name,
        title,
        cells,
        summarize,
        render_table,
        markdown_table,
        plot_table,
        notes,
        compiler_options=sw.LIGHT_COMPILE,
    )


def _digits(col: str) -> int:
    return 3 if col == "theta_rad" else 1


def _nan(col: str) -> str:
    return NOTHING_MAPPED if col in TAG_COLUMNS else report.NA


GAUSSIAN_TEXT = {"footprint": "σ = s/√12", "half_side": "σ = s/2", "small_reader": "σ = 60 mm/√12"}
"""How a table names FastSLAM's Gaussian (``HFSetting.fastslam_gaussian``)."""


def _setting_text(s: dict, short: bool) -> str:
    if short:
        text = f"{s['density']:g}/m², {s['reader_mm']:g} mm, {s['trajectory'][:4]}"
    else:
        text = f"{s['density']:g} tags/m², {s['reader_mm']:g} mm, {s['trajectory']}"
    return f"{text}, {_fastslam_text(s)}" if _fastslam_text(s) else text


def _fastslam_text(s: dict) -> str:
    """FastSLAM's Gaussian and version where a row's setting names them (``"σ = s/2"``, ``"σ = s/√12, 2.0"``), else ``""``."""
    if "fastslam_gaussian" not in s and "fastslam_version" not in s:
        return ""
    text = GAUSSIAN_TEXT[s.get("fastslam_gaussian", "footprint")]
    return f"{text}, FastSLAM {s['fastslam_version']}.0" if "fastslam_version" in s else text


def _diverged_footer(result: dict) -> list[str]:
    """One line per row with diverged runs (``"16 tags/m², 60 mm, rectangle, PF-SLAM: 2 of 100 runs diverged …"``)."""
    lines = []
    for r in result["rows"]:
        label = f"{_setting_text(r['setting'], False)}, {METHOD_LABELS[r['method']]}"
        runs = r.get("runs", result["runs"] * r.get("cells", 1))
        if line := report.diverged_line(label, r.get("diverged_runs", 0), runs):
            lines.append(line)
    return lines


def render_table(result: dict) -> str:
    """Terminal table: per row, ours (mean ± half-interval) and [W]'s value."""
    title = [
        f"{result['experiment']}: {result['title']}  ({result['runs']} runs per setting"
        f"{', quick variant' if result.get('quick') else ''}; ours = mean ± 95 % half-interval, [W] = thesis)"
    ]
    width = max([22] + [len(_setting_text(r["setting"], True)) + 1 for r in result["rows"]])
    columns = [report.Column("setting", width, "<"), report.Column("method", 10, "<"), report.Column("", 5, "<")]
    columns += [report.Column(h, 16) for h in COLUMN_HEADS]
    rows = []
    for r in result["rows"]:
        ours = [report.plus_minus(r[c], _digits(c), _nan(c)) for c in ERROR_COLUMNS]
        paper = [report.number(r[c]["paper"], _digits(c)) for c in ERROR_COLUMNS]
        rows.append([_setting_text(r["setting"], True), METHOD_LABELS[r["method"]], "ours", *ours])
        rows.append(["", "", "[W]", *paper])
    return report.text(columns, rows, title, _diverged_footer(result))


def markdown_table(result: dict) -> str:
    """Markdown table: ``ours [lo, hi] ([W] value)`` per column."""
    title = (
        f"**{result['experiment']}** — {result['title']} ({result['runs']} runs per setting; "
        "mean [95 % interval] (thesis value))"
    )
    rows = []
    for r in result["rows"]:
        cells = [
            f"{report.interval(r[c], _digits(c), _nan(c), note=False)} ({report.number(r[c]['paper'], _digits(c))})"
            + (f"; {note}" if (note := report.unscored_note(r[c])) else "")
            for c in ERROR_COLUMNS
        ]
        rows.append([_setting_text(r["setting"], False), METHOD_LABELS[r["method"]], *cells])
    return report.markdown(["setting", "method", *COLUMN_HEADS], rows, title, _diverged_footer(result))


def wrap_title(text: str, width: int) -> str:
    """``text`` wrapped at ``width`` characters, never inside a reference ("[W] §5.4.5, Fig. 5.16")."""
    text = re.sub(r"(Fig\.|Table|\[[AW]\]|§[\d.]+,) ", "\\1\u00a0", text)
    return textwrap.fill(text, int(width))


CELLS_BY_NAME: dict[str, Callable[[bool], list[Cell]]] = {}
"""The cells of each HF experiment (tables and figures) by name: a plot says from them what a quick variant ran."""


def quick_text(name: str) -> str:
    """What the quick variant of experiment ``name`` runs, e.g. ``"3 of the 15 settings, 100 robot particles,
    30 tag particles, 1 lap, 2 × 1.5 m carpet"``; a field its cells differ in (a curve's x) is left out."""
    if name not in CELLS_BY_NAME:
        return ""
    settings = [c.setting for c in CELLS_BY_NAME[name](True)]
    full = len(CELLS_BY_NAME[name](False))
    parts = [] if len(settings) == full else [f"{len(settings)} of the {full} settings"]
    for field, text in (("robot_particles", "{} robot particles"), ("tag_particles", "{} tag particles")):
        if len(values := {getattr(s, field) for s in settings}) == 1:
            parts.append(text.format(*values))
    for s in settings:
        parts.append(
            f"{s.random_steps} random steps" if s.trajectory == "random" else f"{s.laps} lap{'s' * (s.laps != 1)}"
        )
    for s in settings:
        parts.append(f"{s.carpet[0]:g} × {s.carpet[1]:g} m carpet")
    return ", ".join(dict.fromkeys(parts))  # each once, in order


def plot_title(result: dict) -> str:
    """``"NAME: title"``, and a second line naming a quick variant and what it cuts (its numbers are not
    the experiment's)."""
    head = f"{result['experiment']}: {result['title']}"
    if not result.get("quick"):
        return head
    details = quick_text(result["experiment"])
    return f"{head}\nquick variant{f' ({details})' if details else ''}: not the full experiment"


def error_bars(means: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """``[2, n]`` ``yerr`` of errorbar for an error (≥ 0) with its interval ``[lo, hi]``.

    The intervals are mean ± t·s/√R, symmetric, so a wide one reaches below 0 although no error
    can; the lower whisker stops at 0 (the stored bound is unchanged)."""
    return np.array([means - np.maximum(lo, 0.0), hi - means])


def _draw_table(result: dict):
    """The figure of :func:`plot_table`."""
    import matplotlib.pyplot as plt

    rows = result["rows"]
    labels = [
        f"{r['setting']['density']:g}/m² {r['setting']['trajectory'][:4]}\n{METHOD_LABELS[r['method']]}"
        + (f"\n{_fastslam_text(r['setting'])}" if _fastslam_text(r["setting"]) else "")
        for r in rows
    ]
    x = np.arange(len(rows))
    fig, axes = plt.subplots(1, 2, figsize=(max(8, 1.6 * len(rows) + 3), 4.6), layout="constrained")
    for ax, col, what in zip(axes, ("dr_mm", "dt_mm"), ("robot error dr", "tag error dt")):
        means = np.array([r[col]["mean"] for r in rows], float)
        lo = np.array([r[col]["ci95"][0] for r in rows], float)
        hi = np.array([r[col]["ci95"][1] for r in rows], float)
        ax.bar(x, means, color="tab:blue", alpha=0.7, label=f"ours: mean of {result['runs']} runs")
        ax.errorbar(x, means, yerr=error_bars(means, lo, hi), fmt="none", color="k", capsize=3, label="95 % CI")
        for i in np.flatnonzero(~np.isfinite(means)):  # no run had anything to score
            ax.annotate(_nan(col), (x[i], 0), ha="center", va="bottom", rotation=90, fontsize=7)
        paper = [r[col]["paper"] for r in rows]
        px = [i for i, p in enumerate(paper) if p is not None]
        ax.plot(px, [paper[i] for i in px], "r_", ms=22, mew=3, label="[W] (single run)")
        ax.set_xticks(x)
        ax.set_xticklabels(labels, fontsize=8)
        ax.set_ylabel(f"{what} (mm)")
        ax.set_ylim(bottom=0)
    # one legend for both panels, under them: inside, it would hide the first bars
    handles, texts = axes[0].get_legend_handles_labels()
    order = sorted(range(len(texts)), key=lambda i: texts[i].startswith("[W]"))  # ours first
    fig.legend([handles[i] for i in order], [texts[i] for i in order], loc="outside lower center", ncol=3, fontsize=8)
    fig.suptitle(
        "\n".join(wrap_title(t, 13 * fig.get_figwidth()) for t in plot_title(result).split("\n")),
        fontsize=10,
    )
    return fig


def plot_table(result: dict, path: str) -> None:
    """Robot and tag distance errors per row (ours with 95 % intervals, [W] as markers)."""
    import matplotlib.pyplot as plt

    fig = _draw_table(result)
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ---------------------------------------------------------------------------
# the four tables of [W]

_S31 = {d: hf.HFSetting(density=d, reader_side=0.06, trajectory="rectangle") for d in (16.0, 100.0)}
_S32 = {d: hf.HFSetting(density=d, reader_side=0.06, trajectory="random") for d in (16.0, 100.0)}
_S41 = tuple(
    hf.HFSetting(density=4.0, reader_side=0.3, trajectory="rectangle", carpet=(4.0, 3.5), rectangle=r)
    for r in FIVE_RECTANGLES
)
_S42 = hf.HFSetting(density=4.0, reader_side=0.3, trajectory="random", carpet=(4.0, 3.5))

TABLE_3_1 = table_experiment(
    "table-3.1",
    "FastSLAM vs PF-SLAM, 60 mm readers, rectangle driven three times ([W] Table 3.1)",
    [
        TableRow("16", "fastslam", [_S31[16.0]], (27.6, 24.0, 0.022, 36.6, 19.0, 28.9, 34.6)),
        TableRow("16", "pf_slam", [_S31[16.0]], (20.8, 25.8, 0.015, 33.1, 26.7, 23.1, 35.3)),
        TableRow("100", "fastslam", [_S31[100.0]], (44.4, 43.7, 0.031, 62.3, 44.7, 33.2, 55.7)),
        TableRow("100", "pf_slam", [_S31[100.0]], (23.2, 23.9, 0.011, 33.3, 25.7, 24.1, 35.2)),
    ],
)
TABLE_3_2 = table_experiment(
    "table-3.2",
    "FastSLAM vs PF-SLAM, 60 mm readers, random trajectory ([W] Table 3.2)",
    [
        TableRow("16", "fastslam", [_S32[16.0]], (122.0, 72.6, 0.076, 142.0, 147.0, 71.3, 163.4)),
        TableRow("16", "pf_slam", [_S32[16.0]], (10.8, 26.8, 0.006, 28.9, 9.3, 26.9, 28.5)),
        TableRow("100", "fastslam", [_S32[100.0]], (47.5, 57.9, 0.019, 74.9, 52.0, 45.6, 69.2)),
        TableRow("100", "pf_slam", [_S32[100.0]], (20.3, 37.1, 0.003, 42.3, 13.6, 23.4, 27.1)),
    ],
)
TABLE_4_1 = table_experiment(
    "table-4.1",
    "PS vs PF vs FastSLAM, 300 mm readers, 4 tags/m², five rectangles ([W] Table 4.1)",
    [
        TableRow("4", "ps_slam", _S41, (25.4, 45.1, 0.006, 53.8, 50.3, 51.2, 79.0)),
        TableRow("4", "pf_slam", _S41, (41.4, 66.6, 0.003, 82.1, 66.1, 80.1, 110.5)),
        TableRow("4", "fastslam", _S41, (315.1, 204.5, 0.182, 420.8, 296.6, 210.1, 412.1)),
    ],
    notes="Each row pools the runs of the five rectangles.",
)
TABLE_4_2 = table_experiment(
    "table-4.2",
    "PS vs PF vs FastSLAM, 300 mm readers, 4 tags/m², random trajectory ([W] Table 4.2)",
    [
        # [W] prints the tag distance of Table 4.2 in "cm", but the values (50.4, 82.3, 280.0) follow
        # the mm of every other column and table; we read them as mm.
        TableRow("4", "ps_slam", [_S42], (21.0, 15.1, 0.010, 29.1, 31.9, 32.9, 50.4)),
        TableRow("4", "pf_slam", [_S42], (61.0, 25.3, 0.007, 66.7, 67.5, 38.5, 82.3)),
        TableRow("4", "fastslam", [_S42], (110.4, 198.6, 0.131, 245.7, 122.5, 234.1, 280.0)),
    ],
)

# [W]'s FastSLAM rows of Tables 4.1 and 4.2, beside each reading of its Gaussian
_W41_FASTSLAM = (315.1, 204.5, 0.182, 420.8, 296.6, 210.1, 412.1)
_W42_FASTSLAM = (110.4, 198.6, 0.131, 245.7, 122.5, 234.1, 280.0)
_FASTSLAM_READINGS = (
    ("footprint", {}),
    ("half_side", {"fastslam_gaussian": "half_side"}),
    ("small_reader", {"fastslam_gaussian": "small_reader"}),
    ("footprint-2.0", {"fastslam_version": 2}),
)


def _fastslam_rows() -> list[TableRow]:
    rows = []
    for table, settings, paper in (("4.1", _S41, _W41_FASTSLAM), ("4.2", [_S42], _W42_FASTSLAM)):
        for name, change in _FASTSLAM_READINGS:
            rows.append(TableRow(f"{table} {name}", "fastslam", [replace(s, **change) for s in settings], paper))
    return rows


FASTSLAM_READINGS = table_experiment(
    "fastslam-rfid-readings",
    "FastSLAM-RFID under the Gaussians [W]'s text allows, 300 mm readers ([W] Tables 4.1, 4.2)",
    _fastslam_rows(),
    notes=(
        "[W] §3.2 updates each tag with an EKF of a Gaussian detection but gives no σ. Each row is FastSLAM "
        "on the setting of Table 4.1 (five rectangles pooled) or 4.2 with one reading of that Gaussian, a "
        "point measurement at the detecting reader's centre: σ = s/√12, the 300 mm footprint's own variance "
        "(ours, the tables' default); σ = s/2, the half side; σ = 60 mm/√12, the 60 mm reader's σ of "
        "[W] ch. 3 kept for the large readers; and ours with FastSLAM 2.0. [W]'s values are its FastSLAM row."
    ),
)

EXPERIMENTS = (TABLE_3_1, TABLE_3_2, TABLE_4_1, TABLE_4_2, FASTSLAM_READINGS)
"""The four tables, in [W]'s order (listed by :mod:`jaxnav.experiments.catalog`)."""
