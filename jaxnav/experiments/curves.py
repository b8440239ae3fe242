"""Curve experiments: results that are curves of a quantity against a setting, for any study.

A curve is ``{"method", "quantity", "x", "mean", "ci95", "runs", "diverged_runs"[, "unscored_runs"]}``:
per point the mean over the point's seeded runs with its 95 % interval
(:func:`jaxnav.experiments.stats.summarize`); a run with nothing to score at a point is NaN there,
left out of the point's mean and counted in ``unscored_runs``; a run that diverged is left out and
counted in ``diverged_runs``. A curve result is ``{"x_label", "x_log", "curves", "notes"}`` beside the
registry's ``experiment``, ``title``, ``runs`` and ``quick``.

:func:`summarize_points` makes a curve's points from per-run values; :func:`render`, :func:`markdown`
and :func:`plot` show a curve result (terminal, Markdown, PNG with one panel per quantity);
:func:`curve_experiment` makes an :class:`~jaxnav.experiments.experiment.Experiment` of them. A study
names its methods (``labels``) and says how a point no run could score reads (``nan_text``).
"""

from __future__ import annotations

import textwrap
from collections.abc import Callable, Mapping, Sequence
from functools import partial
from typing import Any

import numpy as np

from jaxnav.experiments import report, stats
from jaxnav.experiments.experiment import Experiment

__all__ = ["summarize_points", "points", "diverged_text", "render", "markdown", "draw", "plot", "curve_experiment"]


def summarize_points(x: Sequence[float], per_run: Sequence[np.ndarray], diverged: Sequence[np.ndarray]) -> dict:
    """``{"x", "mean", "ci95", "runs", "diverged_runs"}`` of one curve from per-point arrays of per-run values
    (NaN = no value) and per-point masks of the runs that diverged (left out, counted), with
    ``"unscored_runs"`` per point when a point has runs without a value."""
    means, cis, unscored, runs, gone = [], [], [], [], []
    for values, mask in zip(per_run, diverged, strict=True):
        s = stats.summarize(values, diverged=mask)
        means.append(s.mean)
        cis.append([s.lo, s.hi])
        unscored.append(s.unscored)
        runs.append(s.runs)
        gone.append(s.diverged)
    out = {"x": list(map(float, x)), "mean": means, "ci95": cis, "runs": runs, "diverged_runs": gone}
    if any(unscored):
        out["unscored_runs"] = unscored
    return out


def points(c: dict) -> list[dict]:
    """The curve's points as ``{"mean", "ci95"[, "unscored_runs"]}`` summaries (for :mod:`jaxnav.experiments.report`)."""
    n = len(c["mean"])
    unscored = c.get("unscored_runs", [0] * n)
    gone, runs = c.get("diverged_runs", [0] * n), c.get("runs", [None] * n)
    return [
        {"mean": m, "ci95": ci, "unscored_runs": k, "diverged_runs": d, "runs": r}
        for m, ci, k, d, r in zip(c["mean"], c["ci95"], unscored, gone, runs)
    ]


def diverged_text(c: dict) -> str:
    """``"2 of 8 runs diverged …"`` for a curve whose points all pool the same runs,
    ``"runs diverged at some points …"`` otherwise; ``""`` when no run diverged."""
    gone, runs = c.get("diverged_runs", []), c.get("runs", [])
    if not any(gone):
        return ""
    if len(set(gone)) == 1 and len(set(runs)) == 1:
        return f"{report.diverged_note(gone[0], runs[0])} (non-finite results): left out of every point"
    return "runs diverged at some points (non-finite results): left out of those points, counted there"


def render(result: dict, labels: Mapping[str, str] = {}, nan_text: Mapping[str, str] = {}) -> str:
    """Terminal: per curve, its points as ``x = value: mean [lo, hi]`` (long curves thinned; the JSON has
    them all). ``labels`` names the methods, ``nan_text`` says per quantity how a point no run could score
    reads (default :data:`jaxnav.experiments.report.NA`)."""
    lines = [
        f"{result['experiment']}: {result['title']}  ({result['runs']} runs per point"
        f"{', quick variant' if result.get('quick') else ''}; mean [95 % interval])"
    ]
    for c in result["curves"]:
        lines.append(f"  {labels.get(c['method'], c['method'])}, {c['quantity']}:")
        nan = nan_text.get(c["quantity"], report.NA)
        every = max(1, len(c["x"]) // 12)
        for x, p in list(zip(c["x"], points(c)))[::every]:
            value = report.interval(p, 1, nan)
            pad = " " * max(0, 8 - len(value.split(" ", 1)[0]))  # the mean right-aligned in 8 characters
            lines.append(f"    {result['x_label']} = {x:g}: {pad}{value}")
        if "before_mm" in c:
            lines.append(
                f"    mean error over the 5 s before: {report.number(c['before_mm'], 1)} mm, "
                f"over 5–15 s after: {report.number(c['after_mm'], 1)} mm"
            )
        if note := diverged_text(c):
            lines.append(f"    {note}")
    if result.get("notes"):
        lines.append(result["notes"])
    return "\n".join(lines)


def markdown(result: dict, labels: Mapping[str, str] = {}, nan_text: Mapping[str, str] = {}) -> str:
    """Markdown: one line per curve, one column per point (the curves share their x)."""
    xs = result["curves"][0]["x"]
    title = f"**{result['experiment']}** — {result['title']} ({result['runs']} runs per point; mean [95 % interval])"
    rows = []
    for c in result["curves"]:
        nan = nan_text.get(c["quantity"], report.NA)
        cells = [report.interval(p, 1, nan) for p in points(c)]
        rows.append([labels.get(c["method"], c["method"]), c["quantity"], *cells])
    return report.markdown(["method", "quantity", *(f"{result['x_label']} = {x:g}" for x in xs)], rows, title)


def _default_title(result: dict) -> str:
    head = f"{result['experiment']}: {result['title']}"
    return f"{head}\nquick variant: not the full experiment" if result.get("quick") else head


def draw(
    result: dict,
    labels: Mapping[str, str] = {},
    title: Callable[[dict], str] = _default_title,
    wrap: Callable[[str, int], str] = textwrap.fill,
    marker: tuple[float, str] | None = None,
    log_y: bool = False,
):
    """The figure of :func:`plot`: one panel per quantity, each curve with its 95 % interval as a band;
    ``title(result)`` above (its lines wrapped by ``wrap(line, width)``), a vertical line at
    ``marker = (x, label)``, a logarithmic y axis with ``log_y``."""
    import matplotlib.pyplot as plt

    quantities = list(dict.fromkeys(c["quantity"] for c in result["curves"]))
    # a method keeps its colour in every panel, also where a panel lacks some method
    colors = {m: f"C{i % 10}" for i, m in enumerate(dict.fromkeys(c["method"] for c in result["curves"]))}
    fig, axes = plt.subplots(
        1, len(quantities), figsize=(6 * len(quantities), 4.6), squeeze=False, layout="constrained"
    )
    for ax, q in zip(axes[0], quantities):
        for c in (c for c in result["curves"] if c["quantity"] == q):
            x, m = np.array(c["x"]), np.array(c["mean"], float)
            ci = np.array(c["ci95"], float)
            (line,) = ax.plot(x, m, "o-", ms=3, color=colors[c["method"]], label=labels.get(c["method"], c["method"]))
            # errors are ≥ 0: a symmetric interval's lower end below 0 is drawn at 0
            low = np.maximum(ci[:, 0], np.nanmin(m) * 0.5 if log_y else 0.0)
            ax.fill_between(x, low, ci[:, 1], color=line.get_color(), alpha=0.2, lw=0)
        if marker is not None:
            ax.axvline(marker[0], color="0.3", ls="--", lw=1.0, label=marker[1])
        ax.set_xlabel(result["x_label"])
        ax.set_ylabel(q)
        if result.get("x_log"):
            ax.set_xscale("log")
            xs = sorted({v for c in result["curves"] if c["quantity"] == q for v in c["x"]})
            ax.set_xticks(xs, [f"{v:g}" for v in xs])  # the data's x, not powers of ten
            ax.minorticks_off()
        if log_y:
            ax.set_yscale("log")
        else:
            ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
    # the panels share their methods: one legend, under them (inside, they would hide curves)
    by_text: dict[str, Any] = {}
    for ax in axes[0]:
        for handle, text in zip(*ax.get_legend_handles_labels()):
            by_text.setdefault(text, handle)
    handles, texts = list(by_text.values()), list(by_text)
    handles.append(plt.Rectangle((0, 0), 1, 1, color="0.5", alpha=0.3, lw=0))
    texts.append("95 % CI of the mean")
    fig.legend(handles, texts, loc="outside lower center", ncol=len(texts), fontsize=8)
    lines = title(result).split("\n")
    lines[0] = f"{lines[0]} ({result['runs']} runs per point)"
    fig.suptitle("\n".join(wrap(t, 75 * len(quantities)) for t in lines), fontsize=10)
    return fig


def plot(result: dict, path: str, **options: Any) -> None:
    """:func:`draw` (``options`` are its keywords), saved as a PNG at ``path``."""
    import matplotlib.pyplot as plt

    fig = draw(result, **options)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def curve_experiment(
    name: str,
    title: str,
    x_label: str,
    cells: Callable[[bool], list],
    summarize: Callable[..., list[dict]],
    notes: str = "",
    x_log: bool = False,
    labels: Mapping[str, str] = {},
    nan_text: Mapping[str, str] = {},
    plot_options: Mapping[str, Any] = {},
    compiler_options: dict | None = None,
) -> Experiment:
    """An experiment whose result is curves: ``summarize(raw, cells, quick)`` gives its list of curves
    (:func:`summarize_points` makes their points); shown by :func:`render`, :func:`markdown` and
    :func:`plot` (with ``plot_options``)."""

    def summarize_all(raw, cell_list, quick):
        return {"x_label": x_label, "x_log": x_log, "curves": summarize(raw, cell_list, quick), "notes": notes}

    return Experiment(
        name,
        title,
        cells,
        summarize_all,
        partial(render, labels=labels, nan_text=nan_text),
        partial(markdown, labels=labels, nan_text=nan_text),
        partial(plot, labels=labels, **plot_options),
        notes,
        compiler_options=compiler_options,
    )
