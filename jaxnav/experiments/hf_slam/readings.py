"""PS-SLAM under each reading of [W] Alg. 2 against PF-SLAM: the ablation ``ps-slam-readings``.

[W] §4.4 reports PS-SLAM ahead of PF-SLAM on the robot error with large readers (Table 4.1: 53.8 against
82.1 mm; Table 4.2: 29.1 against 66.7 mm). Alg. 2 leaves choices open (:mod:`jaxnav.slam.ps_slam`,
"Readings"); this experiment runs PF-SLAM once and PS-SLAM under each reading on the same seeded
worlds, so that every difference PS − PF is paired by seed.

Settings (4 tags/m²): Table 4.1's first rectangle with 300 mm readers (also Fig. 4.4's 300 mm point),
Table 4.2's random trajectory with 300 mm readers, and Fig. 4.4's 500 mm point (the same rectangle).
Each run lays one world and runs every method on it with the same filter key; its cell ids differ
from the tables', so its seeds are fresh.

Rows per setting: PF-SLAM; PS-SLAM as jaxnav runs it (``default``); one row per non-default value of
each reading (:data:`READINGS`). Two values of ``robot_target``, the mixtures over a tag's ``J``
smoothed or current particles (``"smoothed_particles"``, ``"particles"``), are not run: they cost
``K·I·J`` likelihoods per step, about twelve times a row of the others here, and are covered by the
filter's tests only.

Per row: the robot error ``dr`` and the tag error ``dt`` (mm, :func:`~jaxnav.experiments.hf_slam.simulation.score`),
mean with 95 % interval, and for PS-SLAM rows the paired difference PS − PF with its interval
(negative: PS-SLAM better). A run in which any method diverged (robot error not finite) is left
out of every row of its setting and counted.
"""

from __future__ import annotations

import textwrap
from dataclasses import replace

import jax
import numpy as np

from jaxnav.experiments import report, stats
from jaxnav.experiments import sweep as sw
from jaxnav.experiments.experiment import Cell, Experiment
from jaxnav.experiments.hf_slam import simulation as hf
from jaxnav.experiments.hf_slam.tables import (
    CELLS_BY_NAME,
    FIVE_RECTANGLES,
    error_bars,
    plot_title,
    quick_setting,
    setting_label,
    wrap_title,
)

__all__ = [
    "READINGS",
    "SETTINGS",
    "PS_SLAM_READINGS",
    "EXPERIMENTS",
]

READINGS = (
    ("default", ()),
    ("current mean", (("robot_target", "current_mean"),)),
    ("feedback", (("resampled_state", "smoothed"),)),
    ("history in place", (("history", "in_place"),)),
    ("smooth before resampling", (("smoothing_order", "before_resampling"),)),
    ("init from robot particles", (("tag_init", "robot_particles"),)),
)
"""``(row label, PSSLAMConfig fields)``: PS-SLAM's readings run by the experiment, the defaults first."""

_RECT = hf.HFSetting(
    density=4.0, reader_side=0.3, trajectory="rectangle", carpet=(4.0, 3.5), rectangle=FIVE_RECTANGLES[0]
)
SETTINGS = (
    ("table-4.1 / fig-4.4 300 mm", _RECT),
    ("table-4.2", hf.HFSetting(density=4.0, reader_side=0.3, trajectory="random", carpet=(4.0, 3.5))),
    ("fig-4.4 500 mm", replace(_RECT, reader_side=0.5)),
)
"""``(label, setting)``: where each reading is run."""

_COLS = ("dr_mm", "dt_mm")


def _methods(setting: hf.HFSetting) -> list[tuple[str, str, hf.HFSetting]]:
    """``(row, method, setting)`` of PF-SLAM and of PS-SLAM under each reading."""
    out = [("PF-SLAM", "pf_slam", setting)]
    out += [(label, "ps_slam", replace(setting, smoother_readings=fields)) for label, fields in READINGS]
    return out


def _cell_fn(setting: hf.HFSetting):
    """``key -> {"ROW/dr_mm", "ROW/dt_mm"}``: every row's errors on one world, with one filter key."""

    def fn(key):
        k_world, k_filter = jax.random.split(key)
        world = hf.make_world(k_world, setting)
        out = {}
        for row, method, s in _methods(setting):
            errors = hf.score(world, hf.run_method(k_filter, method, s, world))
            for col in _COLS:
                out[f"{row}/{col}"] = getattr(errors, col)
        return out

    return fn


def _cells(quick: bool) -> list[Cell]:
    chosen = SETTINGS[1:2] if quick else SETTINGS  # the quick variant: the random trajectory only
    out = []
    for label, s in chosen:
        s = quick_setting(s) if quick else s
        cell_id = f"readings|{label}"
        out.append(Cell(cell_id, label, "ps_slam", s, _cell_fn(s)))
    return out


def _row_labels() -> list[str]:
    return ["PF-SLAM"] + [label for label, _ in READINGS]


def _summary(raw: dict, cells: list[Cell], quick: bool) -> dict:
    out = []
    for c in cells:
        values = raw[c.id]
        labels = _row_labels()
        diverged = stats.diverged_runs(*(values[f"{r}/dr_mm"] for r in labels))
        rows = []
        for r in labels:
            entry = {"row": r, "method": "pf_slam" if r == "PF-SLAM" else "ps_slam"}
            for col in _COLS:
                entry[col] = stats.column_summary(values[f"{r}/{col}"], diverged)
                if r != "PF-SLAM":
                    diff = np.asarray(values[f"{r}/{col}"], np.float64) - np.asarray(
                        values[f"PF-SLAM/{col}"], np.float64
                    )
                    entry[f"{col}_minus_pf"] = stats.column_summary(diff, diverged)
            rows.append(entry)
        readings = dict(READINGS)
        for row in rows:
            row["readings"] = dict(readings.get(row["row"], ()))
        out.append(
            {
                "setting_label": c.row,
                "setting": setting_label(c.setting),
                "runs": int(diverged.size),
                "diverged_runs": int(diverged.sum()),
                "rows": rows,
            }
        )
    return {"settings": out, "notes": NOTES}


NOTES = (
    "PS − PF: the paired difference per seed (negative: PS-SLAM better). 'default' is PS-SLAM as jaxnav runs it "
    "(tag jitter σ/10, L = 20). Thesis: Table 4.1 PS 53.8 / PF 82.1 mm, Table 4.2 PS 29.1 / PF 66.7 mm."
)


def _cell(v: dict, digits: int = 1) -> str:
    return report.interval(v, digits, report.NA, note=False)


def render(result: dict) -> str:
    """Terminal: per setting, each row's ``dr`` and ``dt`` (mean [95 % interval]) and PS − PF."""
    lines = [
        f"{result['experiment']}: {result['title']}  ({result['runs']} runs per setting"
        f"{', quick variant' if result.get('quick') else ''}; mean [95 % interval])"
    ]
    columns = [report.Column("reading", 25, "<")] + [
        report.Column(h, 20) for h in ("dr [mm]", "dr PS − PF", "dt [mm]", "dt PS − PF")
    ]
    for s in result["settings"]:
        cells = [
            [
                r["row"],
                _cell(r["dr_mm"]),
                _cell(r["dr_mm_minus_pf"]) if "dr_mm_minus_pf" in r else "",
                _cell(r["dt_mm"]),
                _cell(r["dt_mm_minus_pf"]) if "dt_mm_minus_pf" in r else "",
            ]
            for r in s["rows"]
        ]
        title = [f"{s['setting_label']} — {_setting_text(s)}"]
        lines.append(report.text(columns, cells, title, _footer(s)))
    return "\n\n".join(lines + [textwrap.fill(result.get("notes", ""), 110)])


def _setting_text(s: dict) -> str:
    st = s["setting"]
    return f"{st['density']:g} tags/m², {st['reader_mm']:g} mm readers, {st['trajectory']}"


def _footer(s: dict) -> list[str]:
    line = report.diverged_line(s["setting_label"], s.get("diverged_runs", 0), s["runs"])
    return [line] if line else []


def markdown(result: dict) -> str:
    """Markdown: one table per setting."""
    parts = [
        f"**{result['experiment']}** — {result['title']} ({result['runs']} runs per setting; "
        "mean [95 % interval]; PS − PF paired by seed)"
    ]
    for s in result["settings"]:
        rows = [
            [
                r["row"],
                _cell(r["dr_mm"]),
                _cell(r["dr_mm_minus_pf"]) if "dr_mm_minus_pf" in r else "",
                _cell(r["dt_mm"]),
                _cell(r["dt_mm_minus_pf"]) if "dt_mm_minus_pf" in r else "",
            ]
            for r in s["rows"]
        ]
        parts.append(
            report.markdown(
                ["reading", "dr [mm]", "dr PS − PF [mm]", "dt [mm]", "dt PS − PF [mm]"],
                rows,
                f"*{s['setting_label']}* — {_setting_text(s)}",
                _footer(s),
            )
        )
    parts.append(result.get("notes", ""))
    return "\n\n".join(parts)


def _draw_readings(result: dict):
    """The figure of :func:`plot_readings`: per setting (left to right), each row's mean error with its 95 %
    interval, robot ``dr`` on top and tag ``dt`` below; the dashed line is PF-SLAM's mean."""
    import matplotlib.pyplot as plt

    settings = result["settings"]
    n = len(settings)
    fig, axes = plt.subplots(2, n, figsize=(max(7.0, 5.2 * n), 7.8), layout="constrained", squeeze=False)
    colours = plt.get_cmap("tab10")
    for k, s in enumerate(settings):
        rows = s["rows"]
        x = np.arange(len(rows))
        for ax, col, what in zip(axes[:, k], _COLS, ("robot error dr (mm)", "tag error dt (mm)")):
            means = np.array([r[col]["mean"] for r in rows], float)
            lo = np.array([r[col]["ci95"][0] for r in rows], float)
            hi = np.array([r[col]["ci95"][1] for r in rows], float)
            ax.bar(x, means, color=[colours(i % 10) for i in range(len(rows))], alpha=0.8)
            ax.errorbar(x, means, yerr=error_bars(means, lo, hi), fmt="none", color="k", capsize=3)
            ax.axhline(means[0], color="k", ls="--", lw=1)
            ax.set_xticks(x)
            ax.set_xticklabels([r["row"] for r in rows], rotation=60, ha="right", fontsize=7)
            ax.set_ylabel(what)
            ax.set_ylim(bottom=0)
            if col == "dr_mm":
                ax.set_title(wrap_title(f"{s['setting_label']}: {_setting_text(s)}", 55), fontsize=8)
    handles = [
        plt.Line2D([], [], color="k", ls="--", lw=1, label="PF-SLAM's mean"),
        plt.Line2D([], [], color="k", marker="|", ls="none", ms=10, label=f"95 % interval ({result['runs']} runs)"),
    ]
    fig.legend(handles=handles, loc="outside lower center", ncol=2, fontsize=8)
    fig.suptitle("\n".join(wrap_title(t, 13 * fig.get_figwidth()) for t in plot_title(result).split("\n")), fontsize=10)
    return fig


def plot_readings(result: dict, path: str) -> None:
    """Each reading's robot and tag errors per setting, against PF-SLAM's; a PNG at ``path``."""
    import matplotlib.pyplot as plt

    fig = _draw_readings(result)
    fig.savefig(path, dpi=110)
    plt.close(fig)


CELLS_BY_NAME["ps-slam-readings"] = _cells
PS_SLAM_READINGS = Experiment(
    "ps-slam-readings",
    "PS-SLAM under each reading of [W] Alg. 2 vs PF-SLAM, 300 and 500 mm readers, 4 tags/m²",
    _cells,
    _summary,
    render,
    markdown,
    plot_readings,
    NOTES,
    compiler_options=sw.LIGHT_COMPILE,
)

EXPERIMENTS = (PS_SLAM_READINGS,)
"""The ablation, listed by :mod:`jaxnav.experiments.catalog`."""
