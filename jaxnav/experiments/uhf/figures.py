"""[A] §5.2 reproduced: UHF-RFID tag localization from RSSI and phase ([A] Alg. 6) as figures.

Five experiments (:data:`EXPERIMENTS`, run by name with
:func:`jaxnav.experiments.registry.run`), each a set of curves of the position
RMSE over time with its 95 % interval over ``R`` seeded runs, and [A]'s value
beside ours where [A] gives one:

* ``fig-5.3`` ([A] Fig. 5.3): RSSI-only, 3D, strong multipath, the anchor tag
  at 0.25, 0.5, 1, 2 and 4 λ from the tag (λ = 0.173 m, [A] §5.2). [A] prints
  no numbers, only the claim: the RMSE grows with the anchor-to-tag distance,
  sharply beyond λ/2.
* ``fig-5.3-correlated``: the same with the strong preset's fading drawn from
  the spatially correlated field of :mod:`jaxnav.sim.uhf_reader` (correlation
  length λ/2), so that the anchor's fading is the tag's when it is close and
  independent of it beyond λ/2; same cell ids as ``fig-5.3`` (common random
  numbers: only the fading differs).
* ``fig-5.5`` ([A] §5.2.1, Fig. 5.5): 3D (the 2 × 3 × 2 m box of [A]),
  light and strong multipath, the three weightings of Alg. 6 (RSSI only,
  phase only, combined), the anchor 0.05 m from the tag.
* ``fig-5.6`` ([A] §5.2.2, Fig. 5.6): the same in 2D (a 2 × 3 m search at
  the known tag height).
* ``uhf-refresh`` (ours): the combined weighting in 3D with [A]'s Gaussian
  refresh against a kernel (regularised) refresh.

A run, the RMSE and its interval are those of
:mod:`jaxnav.experiments.uhf.localization`. A run whose position error is not
finite at some step diverged: it is left out of its curve (RMSE, median, lost
runs), counted per method in the result's ``diagnostics`` (``diverged_runs``,
with ``runs``), and named under the tables ("2 of 100 runs diverged").

Compilation: a cell runs :func:`~jaxnav.experiments.uhf.localization.run_once`
``(weightings, dims, M)`` with the setting's arrays
(:class:`~jaxnav.experiments.uhf.localization.UHFInputs`: path, multipath
preset, anchor distance, filter parameters) as shared arguments, so cells that
differ only in data (light against strong multipath, the anchor distances of
fig-5.3) share one compilation; the three weightings of a fig-5.5/5.6 setting
are one function. The quick variant of fig-5.3 (anchor at λ/2 and 4λ only)
runs that three-weighting function too (and reports its RSSI curves: the same
runs, same keys) so that the test suite compiles one 3D function, not two.
"""

from __future__ import annotations

import re
import textwrap
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from jaxnav.core.resampling import REFRESHES
from jaxnav.experiments import report, stats
from jaxnav.experiments.experiment import Cell, Experiment
from jaxnav.experiments.uhf.localization import (
    ANCHOR_LAMBDAS,
    CLOSE_ANCHOR,
    FAILED_M,
    FINAL_FRACTION,
    METHODS,
    MULTIPATHS,
    QUICK,
    WAVELENGTH,
    UHFSetting,
    final_mse,
    prior_rmse,
    rmse_summary,
    run_inputs,
    run_once,
)

__all__ = ["PAPER", "FIG_5_3_NOTE", "EXPERIMENTS"]


# ---------------------------------------------------------------------------
# [A]'s values

_LIGHT = "< 0.20 m for all three weightings ([A] abstract, §5.2.1)"
_NO_2D = "[A] §5.2.2 gives no numbers: lower than the corresponding 3D curve"
PAPER: dict[tuple[str, int, str], tuple[float | None, str]] = {
    ("light", 3, "rssi"): (0.20, _LIGHT + "; about the same as phase-only"),
    ("light", 3, "phase"): (0.20, _LIGHT + "; phase-only 0.10–0.20 m, above 0.40 m for some time after the start"),
    ("light", 3, "combined"): (0.20, _LIGHT + "; the combination neither improves nor worsens it"),
    ("strong", 3, "rssi"): (0.60, "≈ 0.60 m ([A] abstract)"),
    ("strong", 3, "phase"): (0.20, "≈ 0.20 m ([A] abstract, §5.2.1); above 1.5 m before it converged"),
    ("strong", 3, "combined"): (0.40, "≈ 0.40 m ([A] abstract): below RSSI-only"),
    ("light", 2, "rssi"): (None, _NO_2D),
    ("light", 2, "phase"): (None, _NO_2D),
    ("light", 2, "combined"): (None, _NO_2D + "; below RSSI-only, not essentially below phase-only"),
    ("strong", 2, "rssi"): (None, _NO_2D),
    ("strong", 2, "phase"): (None, _NO_2D),
    ("strong", 2, "combined"): (None, _NO_2D + "; below RSSI-only, not essentially below phase-only"),
}
"""[A]'s final RMSE (m) per ``(multipath, dims, method)``, or None, with where it comes from."""

PRIOR_MARGINS = (0.0, 0.5, 1.0)
"""How far (m) ``uhf-prior`` grows the filter's search box on every side."""

FIG_5_3_NOTE = (
    f"[A] Fig. 5.3 gives no numbers: the RMSE grows with the anchor-to-tag distance, sharply beyond "
    f"λ/2 = {WAVELENGTH / 2:.4f} m"
)


def _setting_json(s: UHFSetting) -> dict:
    out = {
        "multipath": s.multipath,
        "dims": s.dims,
        "anchor_distance_m": round(s.anchor_distance, 6),
        "anchor_distance_lambda": round(s.anchor_distance / WAVELENGTH, 4),
        "refresh": s.refresh,
    }
    if s.correlation_length is not None:  # only then: the other experiments' settings keep their keys
        out["correlation_length_m"] = round(s.correlation_length, 6)
    if s.prior_margin:
        out["prior_margin_m"] = round(s.prior_margin, 6)
    return out


def _label(setting: dict) -> str:
    refresh = setting.get("refresh", "gaussian")
    ell = setting.get("correlation_length_m")
    grown = setting.get("prior_margin_m")
    return (
        f"{setting['multipath']}, {setting['dims']}D, anchor {setting['anchor_distance_m']:.3g} m "
        f"({setting['anchor_distance_lambda']:.2g} λ)"
        + ("" if refresh == "gaussian" else f", {refresh} refresh")
        + ("" if ell is None else f", fading ℓ = {ell:.3g} m")
        + ("" if grown is None else f", prior box +{grown:.3g} m")
    )


# ---------------------------------------------------------------------------
# rendering


def _curve_at(row: dict, frac: float) -> float:
    rm = row["rmse_m"]["mean"]
    return rm[min(len(rm) - 1, int(round(frac * (len(rm) - 1))))]


def _robust(result: dict, row: dict) -> tuple[float | None, str]:
    """The row's median final error and lost-run count from ``result["diagnostics"]`` (None, :data:`~jaxnav.experiments.report.NONE` if absent)."""
    d = _diagnostics(result, row)
    if d is None:
        return None, report.NONE
    return d["final_median_m"][row["method"]], str(d["final_lost_runs"][row["method"]])


def _diagnostics(result: dict, row: dict) -> dict | None:
    """The diagnostics of the row's setting that hold its method (None if absent)."""
    for d in result.get("diagnostics", ()):
        if d["setting"] == row["setting"] and row["method"] in d.get("final_median_m", {}):
            return d
    return None


def _diverged_footer(result: dict) -> list[str]:
    """One line per row with diverged runs (``"light, 3D, …, phase: 2 of 100 runs diverged …"``)."""
    lines = []
    for r in result["rows"]:
        d = _diagnostics(result, r) or {}
        k = d.get("diverged_runs", {}).get(r["method"], 0)
        if line := report.diverged_line(f"{_label(r['setting'])}, {r['method']}", k, d.get("runs", result["runs"])):
            lines.append(line)
    return lines


def render_table(result: dict) -> str:
    """Terminal table: per curve, the RMSE at 10 % and 25 % of the run, the final RMSE [95 % interval] and [A]'s."""
    t_end = result["rows"][0]["time_s"][-1] if result["rows"] else 0.0
    title = [
        f"{result['experiment']}: {result['title']}",
        f"  ({result['runs']} runs per curve{', quick variant' if result.get('quick') else ''}; RMSE in m; final: "
        f"last {FINAL_FRACTION:.0%} of {t_end:.1f} s, mean [95 % interval]; uniform prior: "
        + ", ".join(f"{report.number(v, 2)} m in {d}D" for d, v in sorted(result["prior_rmse_m"].items()))
        + ")",
    ]
    columns = [
        report.Column("setting", 38, "<"),
        report.Column("method", 10, "<"),
        report.Column("@10%", 7),
        report.Column("@25%", 7),
        report.Column("final", 8),
        report.Column("95 % interval", 16),
        report.Column("median", 8),
        report.Column("lost", 7),
        report.Column("[A]", 7),
        report.Column("note", 0, "<", gap="  "),
    ]
    rows = []
    for r in result["rows"]:
        f = r["final_rmse_m"]
        med, lost = _robust(result, r)
        rows.append(
            [
                _label(r["setting"]),
                r["method"],
                report.number(_curve_at(r, 0.1), 2),
                report.number(_curve_at(r, 0.25), 2),
                report.number(f["mean"], 2),
                f"[{report.number(f['ci95'][0], 2)}, {report.number(f['ci95'][1], 2)}]",
                report.number(med, 3),
                lost,
                report.number(f["paper"], 2),
                f["paper_note"],
            ]
        )
    footer = [f"  median: median over runs of the run's final error; lost: runs whose final error exceeds {FAILED_M} m"]
    footer += [f"  {line}" for line in _diverged_footer(result)]
    if result.get("notes"):
        footer += ["", textwrap.fill(result["notes"], 120)]
    return report.text(columns, rows, title, footer)


def markdown_table(result: dict) -> str:
    """Markdown: one line per curve."""
    title = (
        f"**{result['experiment']}** — {result['title']} ({result['runs']} runs per curve; RMSE in m; final = "
        f"last {FINAL_FRACTION:.0%} of the steps, mean [95 % interval]; uniform prior "
        + ", ".join(f"{report.number(v, 2)} m in {d}D" for d, v in sorted(result["prior_rmse_m"].items()))
        + ")"
    )
    heads = [
        "setting",
        "method",
        "RMSE @10 %",
        "RMSE @25 %",
        "final RMSE",
        "median final error",
        "lost runs",
        "[A]",
        "[A] says",
    ]
    rows = []
    for r in result["rows"]:
        f = r["final_rmse_m"]
        med, lost = _robust(result, r)
        rows.append(
            [
                _label(r["setting"]),
                r["method"],
                report.number(_curve_at(r, 0.1), 2),
                report.number(_curve_at(r, 0.25), 2),
                report.interval(f, 3),
                report.number(med, 3),
                f"{lost}/{result['runs']}",
                report.number(f["paper"], 2),
                f["paper_note"],
            ]
        )
    footer = [
        f"Median final error: median over runs of each run's final error (RMS over the last "
        f"{FINAL_FRACTION:.0%} of steps); lost runs: final error above {FAILED_M} m.",
        *_diverged_footer(result),
    ]
    if result.get("notes"):
        footer.append(result["notes"])
    return report.markdown(heads, rows, title, footer)


_COLORS = {"rssi": "tab:red", "phase": "tab:blue", "combined": "tab:green"}
_KERNEL_COLOR = "tab:purple"


def _wrap(text: str, width: int) -> str:
    """``text`` wrapped at ``width`` characters, never inside a reference ("[W] §5.4.5, Fig. 5.16")."""
    text = re.sub(r"(Fig\.|Table|\[[AW]\]|§[\d.]+,) ", "\\1\u00a0", text)
    return textwrap.fill(text, width)


def _title(result: dict, width: int = 140) -> str:
    """``"NAME: title (R runs)"``, wrapped at ``width`` characters, with a line naming a quick variant (its
    numbers are not the experiment's)."""
    head = _wrap(f"{result['experiment']}: {result['title']} ({result['runs']} runs)", width)
    if not result.get("quick"):
        return head
    rows = result["rows"]
    steps = len(rows[0]["time_s"]) if rows else 0
    return (
        f"{head}\nquick variant ({QUICK['num_particles']} particles, {steps} steps of "
        f"{result.get('step_period_s', 0):.2g} s): not the full experiment"
    )


def _band(ax, r, color, label, linestyle="-"):
    t = np.asarray(r["time_s"])
    m = np.asarray(r["rmse_m"]["mean"], float)
    ci = np.asarray(r["rmse_m"]["ci95"], float)
    ax.plot(t, m, linestyle=linestyle, color=color, lw=1.3, label=label)
    # an RMSE is ≥ 0: an interval's lower end below 0 is drawn at 0
    ax.fill_between(t, np.maximum(ci[:, 0], 0.0), ci[:, 1], color=color, alpha=0.15, lw=0)


def _legend_below(ax, ncol: int = 2) -> None:
    """The panel's legend, under it (inside, it would hide curves), in 9 pt: the figure is drawn about
    0.6 times its size in a page's column, where 7 pt could not be read."""
    ax.legend(fontsize=9, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=ncol)


def _draw_curves(result: dict):
    """The figure of :func:`plot_curves`."""
    import matplotlib.pyplot as plt

    panels = [m for m in MULTIPATHS if any(r["setting"]["multipath"] == m for r in result["rows"])]
    fig, axes = plt.subplots(
        1, len(panels), figsize=(6.2 * len(panels), 5.6), squeeze=False, sharey=True, layout="constrained"
    )
    for ax, mp in zip(axes[0], panels):
        rows = [r for r in result["rows"] if r["setting"]["multipath"] == mp]
        papers = {}  # [A]'s value per method: the kernel-refresh row has the Gaussian one's
        for r in rows:
            refresh = r["setting"].get("refresh", "gaussian")
            c = _COLORS[r["method"]] if refresh == "gaussian" else _KERNEL_COLOR
            f = r["final_rmse_m"]
            name = r["method"] if refresh == "gaussian" else f"{r['method']}, {refresh} refresh"
            grown = r["setting"].get("prior_margin_m")
            name += "" if grown is None else f", prior +{grown:g} m"
            style = _PRIOR_STYLES.get(grown or 0.0, "-.")
            _band(ax, r, c, f"{name} (final {f['mean']:.2f} m)", style)
            if f["paper"] is not None:
                papers.setdefault(r["method"], f["paper"])
        by_value: dict[float, list[str]] = {}
        for method, value in papers.items():
            by_value.setdefault(value, []).append(method)
        for value, methods in by_value.items():  # one line per value: [A] gives 0.20 m for all three in light
            color = _COLORS[methods[0]] if len(methods) == 1 else "0.3"
            label = f"[A] {', '.join(methods)}: {value:.2f} m"
            ax.axhline(value, color=color, ls="--", lw=1.0, alpha=0.8, label=label)
        dims = rows[0]["setting"]["dims"]
        ax.axhline(result["prior_rmse_m"][str(dims)], color="0.4", ls=":", lw=1.0, label="uniform prior")
        ax.set_title(f"{mp} multipath, {dims}D, anchor {rows[0]['setting']['anchor_distance_m']:g} m", fontsize=9)
        ax.set_xlabel("time (s)")
        ax.grid(alpha=0.3)
        longest = max(len(text) for text in ax.get_legend_handles_labels()[1])
        _legend_below(ax, ncol=2 if longest <= 40 else 1)  # long labels in two columns would run off the page
    # the panels share y: fix it once to hold every panel's curves (a limit set on the first panel
    # alone stops autoscaling and would cut the others' curves off); a few runs' wide bands may run off the top
    top = max(
        [float(np.nanmax(np.asarray(r["rmse_m"]["mean"], float))) for r in result["rows"]]
        + [float(v) for v in result["prior_rmse_m"].values()]
    )
    axes[0][0].set_ylim(0, 1.15 * top)
    axes[0][0].set_ylabel("RMSE (m); shaded: 95 % CI")
    fig.suptitle(_title(result, 70 * len(panels)), fontsize=9)
    return fig


_PRIOR_STYLES = {0.0: "-", 0.5: "--", 1.0: ":"}
"""Line style of a curve by how far its prior box is grown (m; ``uhf-prior``)."""


def plot_curves(result: dict, path: str) -> None:
    """fig-5.5/5.6: RMSE over time, one panel per multipath, three weightings, [A]'s values as dashed lines."""
    import matplotlib.pyplot as plt

    fig = _draw_curves(result)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _draw_anchor(result: dict):
    """The figure of :func:`plot_anchor`."""
    import matplotlib.pyplot as plt

    rows = result["rows"]
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 5.6), layout="constrained")
    cmap = plt.get_cmap("viridis")
    for i, r in enumerate(rows):
        _band(
            ax,
            r,
            cmap(i / max(1, len(rows) - 1)),
            f"{r['setting']['anchor_distance_lambda']:g} λ ({r['setting']['anchor_distance_m']:.3f} m)",
        )
    ax.axhline(result["prior_rmse_m"]["3"], color="0.4", ls=":", lw=1.0, label="uniform prior")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("RMSE (m); shaded: 95 % CI")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(  # 9 pt, as _legend_below's
        fontsize=9,
        title="anchor-to-tag distance",
        title_fontsize=9,
        loc="upper center",
        bbox_to_anchor=(0.5, -0.13),
        ncol=3,
    )
    x = np.array([r["setting"]["anchor_distance_lambda"] for r in rows])
    m = np.array([r["final_rmse_m"]["mean"] for r in rows], float)
    ci = np.array([r["final_rmse_m"]["ci95"] for r in rows], float)
    bx.errorbar(
        x,
        m,
        yerr=[m - np.maximum(ci[:, 0], 0.0), ci[:, 1] - m],  # an RMSE is ≥ 0: the lower whisker stops at 0
        fmt="o-",
        color="tab:red",
        capsize=3,
        label="RSSI-only, final RMSE (95 % CI)",
    )
    med = [_robust(result, r)[0] for r in rows]
    if all(v is not None for v in med):
        bx.plot(x, med, "s--", color="tab:red", mfc="none", label="RSSI-only, median final error")
    bx.axvline(0.5, color="k", ls="--", lw=1.0, label="λ/2 ([A]: RMSE grows sharply beyond)")
    bx.axhline(result["prior_rmse_m"]["3"], color="0.4", ls=":", lw=1.0, label="uniform prior")
    bx.set_xscale("log", base=2)
    bx.set_xticks(x)
    bx.set_xticklabels([f"{v:g} λ" for v in x])
    bx.minorticks_off()
    bx.set_xlabel(f"anchor-to-tag distance (λ = {WAVELENGTH} m)")
    bx.set_ylabel("final RMSE (m)")
    bx.set_ylim(bottom=0)
    bx.grid(alpha=0.3)
    handles, texts = bx.get_legend_handles_labels()
    order = sorted(range(len(texts)), key=lambda i: "final RMSE" not in texts[i])  # the curve first
    bx.legend(
        [handles[i] for i in order],
        [texts[i] for i in order],
        fontsize=9,
        loc="upper center",
        bbox_to_anchor=(0.5, -0.13),
        ncol=2,
    )
    fig.suptitle(_title(result), fontsize=9)
    return fig


def plot_anchor(result: dict, path: str) -> None:
    """fig-5.3: RMSE over time per anchor distance, and the final RMSE against the distance (λ/2 marked)."""
    import matplotlib.pyplot as plt

    fig = _draw_anchor(result)
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ---------------------------------------------------------------------------
# the experiments


def _summarize_cells(raw: dict, cells: Sequence[Cell], methods: Sequence[str], paper_fn) -> dict:
    """The rows (one per setting and method) and the diagnostics (one per setting) of the cells' runs.

    A run whose position error is not finite at some step diverged: it is left out of its
    row's RMSE, median and lost runs, and counted in the diagnostics' ``diverged_runs``
    per method (always present; the tables name rows with diverged runs).
    """
    rows, diagnostics = [], []
    for cell in cells:
        s, vals = cell.setting, raw[cell.id]
        setting = _setting_json(s)
        errors = {w: np.asarray(vals[f"err_{w}"], np.float64) for w in methods}
        kept = {w: ~stats.diverged_runs(e) for w, e in errors.items()}
        for w in methods:
            err = errors[w]
            curve, final = rmse_summary(err[kept[w]])
            paper, note = paper_fn(s, w)
            rows.append(
                {
                    "setting": setting,
                    "method": w,
                    "time_s": [round(t * s.step_period, 6) for t in range(err.shape[1])],
                    "rmse_m": curve,
                    "final_rmse_m": {**final, "paper": paper, "paper_note": note},
                }
            )
        k = np.asarray(vals["gamma_k"], np.float64)
        finals = {w: np.sqrt(final_mse(np.square(e[kept[w]]))) for w, e in errors.items()}
        diagnostics.append(
            {
                "setting": setting,
                "runs": int(k.size),
                "diverged_runs": {w: int(np.sum(~kept[w])) for w in methods},
                "final_median_m": {w: stats.finite_median(f)[0] for w, f in finals.items()},
                "final_lost_runs": {w: int(np.sum(f > FAILED_M)) for w, f in finals.items()},
                "gamma_k_median": float(np.median(k)),
                "gamma_theta_median": float(np.median(vals["gamma_theta"])),
                "gamma_default_fraction": float(np.mean(vals["gamma_default"])),
                "tag_reads_mean": float(np.mean(vals["tag_reads"])),
                "anchor_reads_mean": float(np.mean(vals["anchor_reads"])),
            }
        )
    return {"rows": rows, "diagnostics": diagnostics}


def _experiment(
    name: str,
    title: str,
    settings: Sequence[UHFSetting],
    methods: Sequence[str],
    paper_fn,
    plot,
    notes: str,
    quick_weightings: Sequence[str] | None = None,
    quick_settings: Sequence[int] | None = None,
) -> Experiment:
    """An experiment: one cell per setting, one row per (setting, method).

    ``quick_weightings``: the weightings the quick variant's cells compute (a superset of
    ``methods``, to share another experiment's function); ``quick_settings``: the indices of
    the settings the quick variant runs (default all).
    """
    methods = tuple(methods)
    settings = tuple(settings)

    def cells(quick: bool) -> list[Cell]:
        out = []
        chosen = settings if not quick or quick_settings is None else [settings[i] for i in quick_settings]
        for s in chosen:
            s = replace(s, **QUICK) if quick else s
            weightings = tuple(quick_weightings) if quick and quick_weightings else methods
            fn = run_once(weightings, s.dims, s.num_particles, s.refresh, s.fading_fields)
            # [A]'s Gaussian cells keep the ids of fig-5.5/5.6 (so the same seeded runs): common random numbers;
            # so do the correlated-fading cells of fig-5.3's: same tags, anchors, phase noise and filter keys
            cid = (
                f"{s.multipath}|{s.dims}d|anchor={s.anchor_distance:.6g}"
                + ("" if s.refresh == "gaussian" else f"|refresh={s.refresh}")
                + ("" if not s.prior_margin else f"|prior=+{s.prior_margin:.6g}")
            )
            out.append(Cell(cid, cid, "+".join(methods), s, fn, (run_inputs(s),)))
        return out

    def summarize(raw: dict, cell_list: list[Cell], quick: bool) -> dict:
        out = _summarize_cells(raw, cell_list, methods, paper_fn)
        step = cell_list[0].setting.step_period
        return {
            **out,
            "prior_rmse_m": {"2": prior_rmse(2), "3": prior_rmse(3)},
            "step_period_s": step,
            "final_fraction": FINAL_FRACTION,
            "wavelength_m": WAVELENGTH,
            "notes": notes,
        }

    return Experiment(name, title, cells, summarize, render_table, markdown_table, plot, notes)


_COMMON_NOTES = (
    "Ours, not [A]'s: the tag is drawn uniformly 0.3 m inside the 2 x 3 x 2 m box, its phase offset uniformly; "
    "the reader (boresight +y) drives a lawnmower of passes along x at y = -0.5, -0.2 m and z = 0.5, 1.5 m, one read "
    "per step, 0.2 m/s; multipath presets of jaxnav.sim.uhf_reader; (k, theta) fitted in closed form from all the "
    "anchor's reads; Alg. 6 with sigma_phase = 0.1 lambda, ESS threshold 0.1, Gaussian refresh. The three weightings "
    "run on the same draws. RMSE interval: Student-t interval of the mean squared error over runs, square-rooted. "
    "Final = last 10 % of the steps. The RMSE is ruled by the runs where the filter locks onto a wrong mode of its "
    "first reads (a tag in the antenna's side lobe reads like one ~3x farther in its main lobe) and never recovers: "
    "see the median and lost-run columns."
)

FIG_5_3 = _experiment(
    "fig-5.3",
    "RSSI-only tag localization against the anchor-to-tag distance, strong multipath, 3D ([A] Fig. 5.3)",
    [UHFSetting(multipath="strong", dims=3, anchor_distance=d * WAVELENGTH) for d in ANCHOR_LAMBDAS],
    ("rssi",),
    lambda s, w: (None, FIG_5_3_NOTE),
    plot_anchor,
    "Anchor at 0.25, 0.5, 1, 2, 4 lambda (lambda = 0.173 m, [A] §5.2) in a random direction from the tag, inside the "
    "box. " + _COMMON_NOTES,
    quick_weightings=METHODS,
    quick_settings=(1, 4),
)

FIG_5_3_CORRELATED = _experiment(
    "fig-5.3-correlated",
    "RSSI-only tag localization against the anchor-to-tag distance, strong multipath with spatially correlated "
    "fading (correlation length λ/2), 3D ([A] Fig. 5.3)",
    [
        UHFSetting(multipath="strong", dims=3, anchor_distance=d * WAVELENGTH, correlation_length=WAVELENGTH / 2)
        for d in ANCHOR_LAMBDAS
    ],
    ("rssi",),
    lambda s, w: (None, FIG_5_3_NOTE),
    plot_anchor,
    "fig-5.3 with the fading of the strong preset (Gamma(8, 0.125)) drawn from the spatially correlated field of "
    "jaxnav.sim.uhf_reader (correlation length l = lambda/2 = 0.0865 m: the anchor's and the tag's fading "
    "powers are correlated 0.41 at 0.25 lambda apart and 0.016, the floor of 64 waves, at 0.5, 1, 2 and 4 "
    "lambda) instead of independently for the two tags. Same cell ids as fig-5.3, so the same tags, anchors, "
    "phase noise and filter keys: only the fading differs. Anchor at 0.25, 0.5, 1, 2, 4 lambda (lambda = 0.173 m, "
    "[A] §5.2) in a random direction from the tag, inside the box. " + _COMMON_NOTES,
    quick_settings=(1, 4),
)

FIG_5_5 = _experiment(
    "fig-5.5",
    "Tag localization in 3D (2 x 3 x 2 m): RSSI, phase, combined, light and strong multipath ([A] Fig. 5.5)",
    [UHFSetting(multipath=m, dims=3) for m in MULTIPATHS],
    METHODS,
    lambda s, w: PAPER[(s.multipath, s.dims, w)],
    plot_curves,
    f"Anchor {CLOSE_ANCHOR} m from the tag. " + _COMMON_NOTES,
)

FIG_5_6 = _experiment(
    "fig-5.6",
    "Tag localization in 2D (2 x 3 m, known height): RSSI, phase, combined, light and strong multipath ([A] Fig. 5.6)",
    [UHFSetting(multipath=m, dims=2) for m in MULTIPATHS],
    METHODS,
    lambda s, w: PAPER[(s.multipath, s.dims, w)],
    plot_curves,
    f"Anchor {CLOSE_ANCHOR} m from the tag; the filter knows the tag's height, the error is over x, y. "
    + _COMMON_NOTES,
)

UHF_REFRESH = _experiment(
    "uhf-refresh",
    "Ours, not [A]'s: Alg. 6 combined in 3D with [A]'s Gaussian refresh against a kernel (regularised) "
    "refresh, light and strong multipath",
    [UHFSetting(multipath=m, dims=3, refresh=r) for m in MULTIPATHS for r in REFRESHES],
    ("combined",),
    lambda s, w: PAPER[(s.multipath, s.dims, w)],
    plot_curves,
    f"Anchor {CLOSE_ANCHOR} m from the tag. The Gaussian cells are fig-5.5's combined curves (same cell ids, same "
    "seeded runs). The kernel refresh moves every resampled particle by h L eps (L L^T the set's covariance, h = "
    "Silverman's bandwidth, 0.37 for 2000 particles in 4 dimensions: jaxnav.core.resampling.kernel_refresh) instead "
    "of redrawing the whole set from one Gaussian, so the early multimodal posterior keeps its modes. " + _COMMON_NOTES,
)

UHF_PRIOR = _experiment(
    "uhf-prior",
    "Ours, not [A]'s: Alg. 6 combined in 3D, light multipath, with [A]'s prior (the room's box) against wider "
    "priors, Gaussian and kernel refresh",
    [UHFSetting(multipath="light", dims=3, refresh=r, prior_margin=m) for r in REFRESHES for m in PRIOR_MARGINS],
    ("combined",),
    lambda s, w: PAPER[(s.multipath, s.dims, w)],
    plot_curves,
    f"Anchor {CLOSE_ANCHOR} m from the tag. The filter's uniform prior (and the box its refresh is clipped to) is "
    "the 2 x 3 x 2 m room grown by 0, 0.5 or 1 m on every side (the floor kept at z = 0); the tag and the anchor "
    "are drawn in the room either way. The cells with [A]'s box are fig-5.5's and uhf-refresh's (same cell ids, "
    "same seeded scenes and keys, so the run that fig-5.5's combined weighting loses is among them; another "
    "compiled program rounds differently, so a run that hesitates between modes may end elsewhere). " + _COMMON_NOTES,
)

EXPERIMENTS = (FIG_5_3, FIG_5_3_CORRELATED, FIG_5_5, FIG_5_6, UHF_REFRESH, UHF_PRIOR)
"""The UHF experiments (listed by :mod:`jaxnav.experiments.catalog`)."""
