"""[W] ch. 5 reproduced: the IR emitter positioning experiments of §5.4 as tables.

Five experiments of [W], each a table of rows with the mean over ``R`` seeded
runs, its 95 % interval and [W]'s value where [W] prints one
(:data:`EXPERIMENTS`, run by name with :func:`jaxnav.experiments.registry.run`):

* ``table-5.2`` ([W] §5.4.2): errors at 70 marked spots with the proposed
  layout (3 unique + 8 repeated IDs), with 11 unique IDs, and with odometry
  alone; average and maximum over the spots.
* ``table-5.3`` ([W] §5.4.5): the proposed layout at the 70 spots with the
  emitter–receiver height from 1.10 to 1.30 m while the filter keeps eq. 5.3
  calibrated at 1.2 m.
* ``ir-failure`` ([W] §5.4.5, Fig. 5.16): three laps of the predetermined
  trajectory with both emitters of one repeated ID switched off (the filter
  is not told), against all emitters on.
* ``ir-speeds`` ([W] §5.4.4, Fig. 5.15): three laps at 100–300 mm/s.
* ``ir-rotation`` ([W] §5.4.3, Fig. 5.14): the trajectory with five turns
  on the spot, from an unknown start, against odometry.

and one of ours: ``ir-installation``, the 70 spots with the emitters
installed off their map positions (sd 0–30 mm), the error source [W]
§5.4.2 names and our other experiments leave out.

A run and its errors are those of :mod:`jaxnav.experiments.ir.positioning`.
A row's ``mean`` and ``ci95`` are over the runs' averages, its ``median``
the median of those averages, its ``max`` the mean over runs of each run's
maximum ([W]'s maximum is that of its single run). Runs with nothing to
score (NaN: no scored record) are left out and counted in
``unscored_runs``; ``start_s`` is the mean over the runs whose filter
started, with ``never_started_runs`` counting the others (both keys appear
only when nonzero). A run whose errors are not finite although its drive has
scored records diverged: it is left out of every column of its row (errors,
maxima, median, restarts, start) and counted in the row's ``diverged_runs``
(always present), and the tables name it ("2 of 20 runs diverged").

Batching: the runs of a chunk are evaluated one after the other inside one
compiled ``lax.map`` (``Experiment.batching = "map"``): the filter's start is
a ``lax.cond`` whose 16,000-candidate re-draw a ``vmap`` would compute at
every step, which makes a vmapped run several times slower. Cells that
differ only in arrays (height, layout, path, speed) share one compilation.
"""

from __future__ import annotations

import re
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from jaxnav.experiments import report, stats
from jaxnav.experiments.experiment import Cell, Experiment
from jaxnav.experiments.ir.positioning import (
    COLUMN_HEADS,
    COLUMNS,
    FAILED_CODE,
    HEIGHTS,
    QUICK,
    ROTATION_SCORED_FROM,
    SPEEDS,
    IRSetting,
    drive_inputs,
    path_and_record,
    run_once,
)

__all__ = ["IRRow", "ir_experiment", "summarize_errors", "diverged_in", "INSTALLATION_SDS", "EXPERIMENTS"]


@dataclass(frozen=True)
class IRRow:
    """One result row: ``name`` (the JSON ``method``), the algorithm, the setting and [W]'s values.

    ``paper`` and ``paper_max``: [W]'s average and maximum of x, y, θ, dr
    (mm, rad), or ``None`` where [W] prints none.
    """

    name: str
    algorithm: str
    setting: IRSetting
    paper: tuple | None = None
    paper_max: tuple | None = None
    label: str | None = None

    @property
    def row(self) -> str:
        return self.label or self.name


def _setting_json(s: IRSetting) -> dict:
    return {
        "layout": s.layout,
        "failed_code": s.failed_code,
        "height_m": s.height,
        "speed_mm_s": round(1000 * s.speed, 3),
        "drive": s.drive,
        "num_particles": s.num_particles,
        "installation_mm": round(1000 * s.installation_sd, 3),
    }


def _quick(s: IRSetting, num_steps: int | None) -> IRSetting:
    return replace(s, **QUICK, num_steps=num_steps)


def _padded(rows: Sequence[IRRow], quick: bool) -> list[IRSetting]:
    """The rows' settings (quick or not) padded to the longest drive of each kind: one compilation per kind."""
    settings = [_quick(r.setting, None) if quick else r.setting for r in rows]
    longest: dict[str, int] = {}
    for s in settings:
        longest[s.drive] = max(longest.get(s.drive, 0), len(path_and_record(s)[1]))
    return [replace(s, num_steps=longest[s.drive]) for s in settings]


def diverged_in(values: dict, scored: bool = True) -> np.ndarray:
    """``[R]``: the runs of per-run :class:`~jaxnav.experiments.ir.positioning.IRErrors` fields whose errors
    are not finite although the drive has scored records (``scored``; without any, NaN means nothing to score)."""
    errors = [values[c] for c in COLUMNS] + [values[c + "_max"] for c in COLUMNS]
    if scored:
        return stats.diverged_runs(*errors)
    return np.zeros(np.shape(errors[0])[0], bool)


def summarize_errors(
    values: dict, paper: tuple | None, paper_max: tuple | None, diverged: np.ndarray | None = None
) -> dict:
    """Per column: ``{"mean", "ci95": [lo, hi], "median", "max", "max_ci95", "paper", "paper_max"}``.

    ``mean``, ``ci95`` and ``median`` are over the runs' averages (the median shows a run
    that lost the robot for what it is: one run, not a shift of all); ``max`` is the
    mean over runs of each run's maximum. The ``diverged`` runs (``[R]`` booleans) are left
    out of all of them (the row counts them); other runs without a value (NaN: nothing scored)
    are left out too and counted in ``"unscored_runs"`` (present only when nonzero).
    """
    gone = np.zeros(np.shape(values[COLUMNS[0]])[0], bool) if diverged is None else np.asarray(diverged, bool)
    out = {}
    for i, col in enumerate(COLUMNS):
        avg = stats.summarize(values[col], diverged=gone)
        worst = stats.summarize(values[col + "_max"], diverged=gone)
        out[col] = {
            "mean": avg.mean,
            "ci95": [avg.lo, avg.hi],
            "median": stats.finite_median(np.asarray(values[col])[~gone])[0],
            "max": worst.mean,
            "max_ci95": [worst.lo, worst.hi],
            "paper": None if paper is None else paper[i],
            "paper_max": None if paper_max is None else paper_max[i],
        }
        if avg.unscored:
            out[col]["unscored_runs"] = avg.unscored
    return out


def ir_experiment(
    name: str,
    title: str,
    rows: Sequence[IRRow],
    notes: str = "",
    row_key: str | None = None,
    quick_rows: Sequence[int] | None = None,
) -> Experiment:
    """An IR experiment from its rows.

    ``row_key``: an extra JSON field per row (``"height_m"``, ``"speed_mm_s"``);
    ``quick_rows``: the indices of the rows the quick variant runs (default all).
    """
    rows = tuple(rows)
    by_label = {r.row: r for r in rows}
    if len(by_label) != len(rows):
        raise ValueError(f"row labels must be unique in {name}")
    quick_subset = rows if quick_rows is None else tuple(rows[i] for i in quick_rows)

    def cells(quick: bool) -> list[Cell]:
        out = []
        chosen = quick_subset if quick else rows
        for row, s in zip(chosen, _padded(chosen, quick)):
            fn = run_once(row.algorithm, s.num_particles)
            out.append(Cell(f"{row.row}|{row.algorithm}", row.row, row.algorithm, s, fn, (drive_inputs(s),)))
        return out

    def summarize(raw: dict, cell_list: list[Cell], quick: bool) -> dict:
        out_rows = []
        for cell in cell_list:
            row, vals = by_label[cell.row], raw[cell.id]
            entry = {
                "row": row.row,
                "method": row.name,
                "algorithm": row.algorithm,
                "setting": _setting_json(cell.setting),
            }
            if row_key == "height_m":
                entry["height_m"] = row.setting.height
            if row_key == "speed_mm_s":
                entry["speed_mm_s"] = round(1000 * row.setting.speed, 3)
            if row_key == "installation_mm":
                entry["installation_mm"] = round(1000 * row.setting.installation_sd, 3)
            diverged = diverged_in(vals, scored=bool(np.any(np.asarray(cell.args[0].record) >= 0)))
            kept = ~diverged
            entry["runs"], entry["diverged_runs"] = int(diverged.size), int(diverged.sum())
            entry.update(summarize_errors(vals, row.paper, row.paper_max, diverged))
            entry["restarts"] = stats.finite_mean(np.asarray(vals["restarts"])[kept])[0]
            entry["start_s"], never = stats.finite_mean(np.asarray(vals["start_s"])[kept])
            if never:
                entry["never_started_runs"] = never
            out_rows.append(entry)
        return {"rows": out_rows, "notes": notes}

    return Experiment(name, title, cells, summarize, render_table, markdown_table, plot_table, notes, batching="map")


def _digits(col: str) -> int:
    return 3 if col.startswith("theta") else 0


def _never_started(r: dict, runs: int) -> str:
    k = r.get("never_started_runs", 0)
    return f"{r['row']}: the filter never started in {k} of {runs} runs" if k else ""


def _footer(result: dict) -> list[str]:
    """Per row, its diverged runs and the runs whose filter never started; then the notes."""
    lines = []
    for r in result["rows"]:
        lines.append(report.diverged_line(r["row"], r.get("diverged_runs", 0), r.get("runs", result["runs"])))
        lines.append(_never_started(r, result["runs"]))
    lines = [line for line in lines if line]
    if result.get("notes"):
        lines.append(result["notes"])
    return lines


def render_table(result: dict) -> str:
    """Terminal table: per row, ours (mean ± half-interval, mean maximum) and [W]'s average / maximum."""
    title = [
        f"{result['experiment']}: {result['title']}  ({result['runs']} runs per row"
        f"{', quick variant' if result.get('quick') else ''}; average over records: mean ± 95 % half-interval "
        "over runs; max: mean over runs of the run's maximum)"
    ]
    columns = [report.Column("row", 16, "<"), report.Column("", 5, "<")]
    columns += [report.Column(h, 18) for h in COLUMN_HEADS]
    columns += [report.Column("max " + h, 14) for h in COLUMN_HEADS]
    columns += [report.Column("median dr", 12)]
    rows = []
    for r in result["rows"]:
        ours = [report.plus_minus(r[c], _digits(c)) for c in COLUMNS]
        ours += [report.number(r[c]["max"], _digits(c)) for c in COLUMNS]
        ours += [report.number(r["dr_mm"].get("median"), 0)]
        rows.append([r["row"], "ours", *ours])
        if any(r[c]["paper"] is not None for c in COLUMNS):
            paper = [report.number(r[c]["paper"], _digits(c)) for c in COLUMNS]
            paper += [report.number(r[c]["paper_max"], _digits(c)) for c in COLUMNS]
            rows.append(["", "[W]", *paper, ""])
    return report.text(columns, rows, title, _footer(result))


def markdown_table(result: dict) -> str:
    """Markdown: per column ``mean [lo, hi] ([W])`` for the average and ``max ([W])`` for the maximum."""
    title = (
        f"**{result['experiment']}** — {result['title']} ({result['runs']} runs per row; average: mean "
        "[95 % interval] (thesis); max: mean over runs of each run's maximum (thesis); median over runs of "
        "the average dr)"
    )
    heads = ["row", *COLUMN_HEADS, *("max " + h for h in COLUMN_HEADS), "median dr [mm]"]
    rows = []
    for r in result["rows"]:
        avg = [
            f"{report.interval(r[c], _digits(c), note=False)} ({report.number(r[c]['paper'], _digits(c))})"
            + (f"; {note}" if (note := report.unscored_note(r[c])) else "")
            for c in COLUMNS
        ]
        mx = [
            f"{report.number(r[c]['max'], _digits(c))} ({report.number(r[c]['paper_max'], _digits(c))})"
            for c in COLUMNS
        ]
        rows.append([r["row"], *avg, *mx, report.number(r["dr_mm"].get("median"), 0)])
    return report.markdown(heads, rows, title, _footer(result))


_AXIS = {
    "speed_mm_s": "robot speed",
    "height_m": "emitter-receiver height (eq. 5.3 calibrated at 1.2 m)",
    "installation_mm": "sd of the emitters' installation error, per axis",
}
"""The x-axis label of a sweep, by the row key its rows carry."""


def _quick_text(rows: Sequence[dict]) -> str:
    """What the quick variant of ``rows`` cuts, by their drives (the rotation drive runs in full)."""
    drives = {r["setting"]["drive"] for r in rows}
    parts = []
    if "spots" in drives:
        full = IRSetting().spots
        parts.append(
            f"{QUICK['spots'][0] * QUICK['spots'][1]} of the {full[0] * full[1]} spots, {QUICK['dwell']:g} s stays"
        )
    if "loop" in drives:
        parts.append(f"{QUICK['laps']} laps, the second scored")
    return ", ".join(parts) or "the full run's drive"


def _wrap(text: str, width: int) -> str:
    """``text`` wrapped at ``width`` characters, never inside a reference ("[W] §5.4.5, Fig. 5.16")."""
    text = re.sub(r"(Fig\.|Table|\[[AW]\]|§[\d.]+,) ", "\\1\u00a0", text)
    return textwrap.fill(text, width)


def _plot_title(result: dict, width: int = 100) -> str:
    """The plot's title: the experiment's, but the speed sweep names the speeds and laps its rows ran (the quick
    variant runs two of the five speeds, two laps), and a quick variant says so."""
    rows = result["rows"]
    title = result["title"]
    if rows and all("speed_mm_s" in r for r in rows):
        speeds = sorted({float(r["speed_mm_s"]) for r in rows})
        laps = QUICK["laps"] if result.get("quick") else _LOOP.laps
        title = _SPEEDS_TITLE.format(speeds=", ".join(f"{v:g}" for v in speeds), laps=laps)
    head = _wrap(f"{result['experiment']}: {title}", width)
    if result.get("quick"):
        head += f"\nquick variant ({_quick_text(rows)}): not the full experiment"
    return head


def _draw_table(result: dict):
    """The figure of :func:`plot_table`."""
    import matplotlib.pyplot as plt

    rows = result["rows"]
    x = np.arange(len(rows))
    width = max(7.5, 0.9 * len(rows) + 3)
    fig, ax = plt.subplots(figsize=(width, 5.0), layout="constrained")
    means = np.array([r["dr_mm"]["mean"] for r in rows], float)
    lo = np.array([r["dr_mm"]["ci95"][0] for r in rows], float)
    hi = np.array([r["dr_mm"]["ci95"][1] for r in rows], float)
    ax.bar(x, means, color="tab:blue", alpha=0.7, label=f"ours: average (mean of {result['runs']} runs)")
    # The stored interval is mean ± t·s/√R, symmetric: with few, spread runs (one that lost the robot)
    # it reaches below 0 mm, which no error can; the lower whisker stops at 0.
    yerr = [means - np.maximum(lo, 0.0), hi - means]
    ax.errorbar(x, means, yerr=yerr, fmt="none", color="k", capsize=3, label="95 % CI of the average")
    ax.plot(x, [r["dr_mm"]["max"] for r in rows], "o", color="tab:blue", label="ours: maximum (mean over runs)")
    for key, style, label in (("paper", "r_", "[W] average"), ("paper_max", "rx", "[W] maximum")):
        px = [i for i, r in enumerate(rows) if r["dr_mm"][key] is not None]
        if px:
            ax.plot(px, [rows[i]["dr_mm"][key] for i in px], style, ms=18 if style == "r_" else 8, mew=3, label=label)
    ax.set_xticks(x)
    ax.set_xticklabels([r["row"] for r in rows], fontsize=8, rotation=30 if len(rows) > 6 else 0)
    if axis := next((_AXIS[k] for k in _AXIS if rows and all(k in r for r in rows)), None):
        ax.set_xlabel(axis)
    ax.set_ylabel("robot position error dr (mm)")
    ax.set_ylim(bottom=0)
    # under the axes (inside, it would hide bars and markers); ours first, then [W]'s
    handles, texts = ax.get_legend_handles_labels()
    order = sorted(range(len(texts)), key=lambda i: (texts[i].startswith("[W]"), "maximum" in texts[i]))
    fig.legend([handles[i] for i in order], [texts[i] for i in order], loc="outside lower center", ncol=3, fontsize=8)
    fig.suptitle(_plot_title(result, int(13 * width)), fontsize=9)
    return fig


def plot_table(result: dict, path: str) -> None:
    """dr per row: average (bar, 95 % interval) and mean maximum (dot), [W]'s as red marks."""
    import matplotlib.pyplot as plt

    fig = _draw_table(result)
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ---------------------------------------------------------------------------
# the five experiments of [W] §5.4

_SPOTS = IRSetting()
_LOOP = IRSetting(drive="loop")

TABLE_5_2 = ir_experiment(
    "table-5.2",
    "IR positioning at 70 marked spots: proposed layout, 11 unique IDs, odometry ([W] Table 5.2)",
    [
        IRRow("proposed", "mcl", _SPOTS, (22, 29, 0.06, 36), (69, 79, 0.23, 105)),
        IRRow("unique-11", "mcl", replace(_SPOTS, layout="unique-11"), (30, 25, 0.04, 39), (87, 91, 0.10, 126)),
        IRRow("odometry", "odometry", _SPOTS, (94, 55, 0.03, 108), (161, 99, 0.08, 189)),
    ],
)

_T53 = {  # [W] Table 5.3: height -> (average x, y, θ, dr), (maximum x, y, θ, dr)
    1.10: ((54, 60, 0.20, 80), (129, 216, 0.22, 251)),
    1.12: ((74, 42, 0.12, 85), (141, 96, 0.16, 171)),
    1.14: ((38, 30, 0.10, 49), (103, 76, 0.16, 128)),
    1.16: ((29, 38, 0.11, 47), (56, 88, 0.15, 105)),
    1.18: ((25, 26, 0.04, 36), (45, 38, 0.08, 59)),
    1.20: ((22, 29, 0.07, 36), (69, 79, 0.23, 105)),
    1.22: ((26, 28, 0.05, 39), (53, 47, 0.07, 70)),
    1.24: ((36, 30, 0.01, 47), (63, 74, 0.02, 97)),
    1.26: ((22, 36, 0.06, 42), (50, 72, 0.08, 88)),
    1.28: ((87, 21, 0.04, 90), (122, 39, 0.05, 128)),
    1.30: ((56, 51, 0.07, 76), (98, 77, 0.11, 124)),
}

TABLE_5_3 = ir_experiment(
    "table-5.3",
    "IR positioning at the 70 spots against the emitter-receiver height, eq. 5.3 calibrated at 1.2 m ([W] Table 5.3)",
    [IRRow("proposed", "mcl", replace(_SPOTS, height=h), *_T53[h], label=f"{h:.2f} m") for h in HEIGHTS],
    row_key="height_m",
    quick_rows=(0, 5, 10),
)

IR_FAILURE = ir_experiment(
    "ir-failure",
    "IR positioning with both emitters of one repeated ID failed, three laps ([W] §5.4.5, Fig. 5.16)",
    [
        IRRow("proposed", "mcl", _LOOP, label="all emitters"),
        IRRow("failed-2", "mcl", replace(_LOOP, failed_code=FAILED_CODE), label="2 failed"),
    ],
    notes=f"The two emitters of repeated ID {FAILED_CODE} are dark in the simulator; the filter's map still has "
    "them. Laps 2-3 of three are scored. [W] shows the path only.",
)

_SPEEDS_TITLE = "IR positioning at {speeds} mm/s, {laps} laps ([W] §5.4.4, Fig. 5.15)"
"""``ir-speeds``' title; its plot fills in the speeds and laps of the rows it draws."""

IR_SPEEDS = ir_experiment(
    "ir-speeds",
    _SPEEDS_TITLE.format(speeds=f"{1000 * SPEEDS[0]:.0f}-{1000 * SPEEDS[-1]:.0f}", laps="three"),
    [IRRow("proposed", "mcl", replace(_LOOP, speed=v), label=f"{1000 * v:.0f} mm/s") for v in SPEEDS],
    notes="Laps 2-3 of three are scored. [W] shows the paths only and says speed does not change the accuracy.",
    row_key="speed_mm_s",
    quick_rows=(2, 4),
)

IR_ROTATION = ir_experiment(
    "ir-rotation",
    "IR positioning on the trajectory with five turns, unknown start ([W] §5.4.3, Fig. 5.14)",
    [
        IRRow("proposed", "mcl", IRSetting(drive="rotation")),
        IRRow("odometry", "odometry", IRSetting(drive="rotation")),
    ],
    notes=f"Steps from {ROTATION_SCORED_FROM:g} s on are scored (after the second emitter). [W] shows the path only.",
)

INSTALLATION_SDS = (0.0, 0.01, 0.02, 0.03)
"""The sds of the emitters' installation error in ``ir-installation`` (m)."""

IR_INSTALLATION = ir_experiment(
    "ir-installation",
    "IR positioning at the 70 spots with emitters installed off their map positions (ours, not in [W])",
    [
        IRRow("proposed", "mcl", replace(_SPOTS, installation_sd=sd), label=f"{1000 * sd:.0f} mm")
        for sd in INSTALLATION_SDS
    ],
    notes="Each run draws every emitter's true position around its map position with the given sd per axis; the filter "
    "keeps the map. [W] §5.4.2 names installation errors as a source of its 36 mm; our other experiments have none.",
    row_key="installation_mm",
    quick_rows=(0, 3),
)

EXPERIMENTS = (TABLE_5_2, TABLE_5_3, IR_FAILURE, IR_SPEEDS, IR_ROTATION, IR_INSTALLATION)
"""The IR experiments (listed by :mod:`jaxnav.experiments.catalog`)."""
