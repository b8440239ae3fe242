"""PS-SLAM under each reading of [W] Alg. 2 against PF-SLAM: the ablations ``ps-slam-readings`` and
``ps-slam-mixtures-tuned``.

[W] §4.4 reports PS-SLAM ahead of PF-SLAM on the robot error with large readers (Table 4.1: 53.8 against
82.1 mm; Table 4.2: 29.1 against 66.7 mm). Alg. 2 leaves choices open (:mod:`jaxnav.slam.ps_slam`,
"Readings"); this experiment runs PF-SLAM once and PS-SLAM under each reading on the same seeded
worlds, so that every difference PS − PF is paired by seed.

Settings (4 tags/m²): Table 4.1's first rectangle with 300 mm readers (also Fig. 4.4's 300 mm point),
Table 4.2's random trajectory with 300 mm readers, and Fig. 4.4's 500 mm point (the same rectangle).
Each run lays one world and runs every method on it with the same filter key; its cell ids differ
from the tables', so its seeds are fresh.

``ps-slam-readings``, rows per setting: PF-SLAM; PS-SLAM as jaxnav runs it (``default``); one row per
non-default value of each reading (:data:`READINGS`) but the two mixtures.

``ps-slam-mixtures-tuned``, on the same settings and on fresh seeds of its own: PF-SLAM, ``default``,
the two values of ``robot_target`` that weight the robot against a mixture over a tag's ``J`` smoothed
or current particles (:data:`MIXTURE_READINGS`; they cost ``K·I·J`` likelihoods per step, about twelve
times a row of the others), and ``tuned``: the default reading with the jitter ``s`` and the lag ``L``
that gave the lowest mean robot error over :data:`TUNING_RUNS` training runs (a grid of
:data:`TUNING_JITTERS` × :data:`TUNING_LAGS`, ``vmap``-ed over runs and jitters). The training worlds
come from their own key (:data:`TUNING_SEED`), never from the test runs'. The grid is evaluated when
the cell is first traced, once per process.

Per row: the robot error ``dr`` and the tag error ``dt`` (mm, :func:`~jaxnav.experiments.hf_slam.simulation.score`),
mean with 95 % interval, and for PS-SLAM rows the paired difference PS − PF with its interval
(negative: PS-SLAM better). A run in which any method diverged (robot error not finite) is left
out of every row of its setting and counted.
"""

from __future__ import annotations

import concurrent.futures
import functools
import textwrap
import zlib
from dataclasses import replace

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core.filter import check_key
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
    "MIXTURE_READINGS",
    "TUNING_JITTERS",
    "TUNING_LAGS",
    "TUNING_RUNS",
    "TUNING_SEED",
    "SETTINGS",
    "tuning_grid",
    "tuned_smoother",
    "PS_SLAM_READINGS",
    "PS_SLAM_MIXTURES_TUNED",
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
"""``(row label, PSSLAMConfig fields)``: PS-SLAM's readings run by ``ps-slam-readings``, the defaults first."""

MIXTURE_READINGS = (
    ("default", ()),
    ("smoothed particles", (("robot_target", "smoothed_particles"),)),
    ("tag particles", (("robot_target", "particles"),)),
)
"""``(row label, PSSLAMConfig fields)``: the readings of ``ps-slam-mixtures-tuned`` (the default, then the
two mixtures of ``robot_target``)."""

TUNING_JITTERS = (1 / 20, 1 / 10, 1 / 5, 1 / 2.5)
"""The tag jitters of the tuning grid, as fractions of the footprint half-width σ."""
TUNING_LAGS = (5, 10, 20, 30)
"""The lags ``L`` of the tuning grid."""
TUNING_RUNS = 20
"""Training runs per grid point; the quick variant takes 2."""
TUNING_SEED = 20_260_406
"""The seed of the training worlds (folded with the setting's cell id); the test runs' keys come from
the experiment's key and cell ids (:func:`jaxnav.experiments.sweep.run_key`)."""

_QUICK_JITTERS = (1 / 10, 1 / 5)
_QUICK_LAGS = (5, 10)
_QUICK_TUNING_RUNS = 2

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


def _methods(setting: hf.HFSetting, readings: tuple = READINGS) -> list[tuple[str, str, hf.HFSetting]]:
    """``(row, method, setting)`` of PF-SLAM and of PS-SLAM under each of ``readings``."""
    out = [("PF-SLAM", "pf_slam", setting)]
    out += [(label, "ps_slam", replace(setting, smoother_readings=fields)) for label, fields in readings]
    return out


def tuning_grid(
    key: jax.Array, setting: hf.HFSetting, jitters: tuple[float, ...], lags: tuple[int, ...], runs: int
) -> np.ndarray:
    """``[len(lags), len(jitters)]`` PS-SLAM's mean robot error ``dr`` (mm) over ``runs`` worlds drawn from
    ``key``, at each lag and tag jitter (``jitters`` in fractions of the footprint half-width σ).

    One compilation per lag (``L`` sizes the state); the runs and the jitters are ``vmap``-ed.
    A run that diverged counts as an infinite error, so a grid point where one did is never chosen.
    """
    check_key(key)
    keys = jax.random.split(key, runs)
    half = setting.reader_side / 2
    out = np.zeros((len(lags), len(jitters)))
    for i, lag in enumerate(lags):
        s = replace(setting, lag=int(lag))

        def one(k, sd, s=s):
            k_world, k_filter = jax.random.split(k)
            world = hf.make_world(k_world, s)
            return hf.score(world, hf.filter_world(k_filter, "ps_slam", s, world, tag_jitter_sd=sd)[0]).dr_mm

        sds = jnp.asarray([half * f for f in jitters], jnp.float32)
        dr = np.asarray(jax.jit(jax.vmap(jax.vmap(one, (None, 0)), (0, None)))(keys, sds), np.float64)  # [R, J]
        out[i] = np.where(np.isfinite(dr).all(axis=0), dr.mean(axis=0), np.inf)
    return out


@functools.lru_cache(maxsize=16)
def tuned_smoother(cell_id: str, setting: hf.HFSetting, quick: bool) -> tuple[float, int]:
    """``(jitter in m, lag)`` of the lowest mean robot error on the training worlds of ``cell_id`` (:func:`tuning_grid`).

    Computed once per process; it may be called while a cell's function is traced: JAX's trace state
    is per thread, so in a thread of its own the grid is computed then (concrete numbers) instead of
    being staged into that trace."""
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        return pool.submit(_tune, cell_id, setting, quick).result()


def _tune(cell_id: str, setting: hf.HFSetting, quick: bool) -> tuple[float, int]:
    jitters, lags, runs = (
        (_QUICK_JITTERS, _QUICK_LAGS, _QUICK_TUNING_RUNS) if quick else (TUNING_JITTERS, TUNING_LAGS, TUNING_RUNS)
    )
    key = jax.random.fold_in(jax.random.PRNGKey(TUNING_SEED), zlib.crc32(cell_id.encode()) & 0x7FFFFFFF)
    grid = tuning_grid(key, setting, jitters, lags, runs)
    i, j = np.unravel_index(int(np.argmin(grid)), grid.shape)
    return float(jitters[j] * setting.reader_side / 2), int(lags[i])


def _cell_fn(setting: hf.HFSetting, readings: tuple = READINGS, tuning: tuple[str, bool] | None = None):
    """``key -> {"ROW/dr_mm", "ROW/dt_mm"}``: every row's errors on one world, with one filter key; with
    ``tuning = (cell_id, quick)`` also the ``tuned`` row and its ``"tuned/jitter_mm"``, ``"tuned/lag"``."""

    def fn(key):
        k_world, k_filter = jax.random.split(key)
        world = hf.make_world(k_world, setting)
        rows = _methods(setting, readings)
        if tuning is not None:
            jitter, lag = tuned_smoother(tuning[0], setting, tuning[1])
            rows.append(("tuned", "ps_slam", replace(setting, smoother_jitter=jitter, lag=lag)))
        out = {}
        for row, method, s in rows:
            errors = hf.score(world, hf.run_method(k_filter, method, s, world))
            for col in _COLS:
                out[f"{row}/{col}"] = getattr(errors, col)
        if tuning is not None:
            out["tuned/jitter_mm"] = jnp.float32(1000 * jitter)
            out["tuned/lag"] = jnp.int32(lag)
        return out

    return fn


def _chosen(quick: bool) -> list[tuple[str, hf.HFSetting]]:
    chosen = SETTINGS[1:2] if quick else SETTINGS  # the quick variant: the random trajectory only
    return [(label, quick_setting(s) if quick else s) for label, s in chosen]


def _cells(quick: bool) -> list[Cell]:
    return [Cell(f"readings|{label}", label, "ps_slam", s, _cell_fn(s)) for label, s in _chosen(quick)]


def _mixture_cells(quick: bool) -> list[Cell]:
    out = []
    for label, s in _chosen(quick):
        cell_id = f"mixtures-tuned|{label}"  # fresh seeds: not the ids of ps-slam-readings' cells
        out.append(Cell(cell_id, label, "ps_slam", s, _cell_fn(s, MIXTURE_READINGS, (cell_id, quick))))
    return out


def _row_labels(readings: tuple = READINGS, tuned: bool = False) -> list[str]:
    return ["PF-SLAM"] + [label for label, _ in readings] + (["tuned"] if tuned else [])


def _summary(raw: dict, cells: list[Cell], quick: bool, readings: tuple = READINGS, notes: str | None = None) -> dict:
    tuned = "tuned" in {k.partition("/")[0] for c in cells for k in raw[c.id]}
    out = []
    for c in cells:
        values = raw[c.id]
        labels = _row_labels(readings, tuned)
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
        fields = dict(readings)
        for row in rows:
            row["readings"] = dict(fields.get(row["row"], ()))
        entry = {
            "setting_label": c.row,
            "setting": setting_label(c.setting),
            "runs": int(diverged.size),
            "diverged_runs": int(diverged.sum()),
            "rows": rows,
        }
        if tuned:
            entry["tuned"] = {
                "jitter_mm": float(np.asarray(values["tuned/jitter_mm"])[0]),
                "lag": int(np.asarray(values["tuned/lag"])[0]),
            }
        out.append(entry)
    return {"settings": out, "notes": NOTES if notes is None else notes}


def _mixture_summary(raw: dict, cells: list[Cell], quick: bool) -> dict:
    return _summary(raw, cells, quick, MIXTURE_READINGS, MIXTURE_NOTES)


NOTES = (
    "PS − PF: the paired difference per seed (negative: PS-SLAM better). 'default' is PS-SLAM as jaxnav runs it "
    "(tag jitter σ/10, L = 20). Thesis: Table 4.1 PS 53.8 / PF 82.1 mm, Table 4.2 PS 29.1 / PF 66.7 mm."
)
MIXTURE_NOTES = (
    "PS − PF: the paired difference per seed (negative: PS-SLAM better). 'default' is PS-SLAM as jaxnav runs it "
    "(tag jitter σ/10, L = 20, the robot weighted against the smoothed mean); 'smoothed particles' and 'tag "
    "particles' weight the robot against the mixture over the tag's smoothed or current particles; 'tuned' is the "
    "default reading with the jitter and lag of the lowest mean robot error on separate training runs. "
    "Thesis: Table 4.1 PS 53.8 / PF 82.1 mm, Table 4.2 PS 29.1 / PF 66.7 mm."
)


def _cell(v: dict, digits: int = 1) -> str:
    return report.interval(v, digits, report.NA, note=False)


def _row_cells(r: dict) -> list[str]:
    """One row of the tables: the reading, then ``dr``, ``dr`` PS − PF, ``dt``, ``dt`` PS − PF."""
    return [r["row"]] + [_cell(r[k]) if k in r else "" for k in ("dr_mm", "dr_mm_minus_pf", "dt_mm", "dt_mm_minus_pf")]


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
        cells = [_row_cells(r) for r in s["rows"]]
        title = [f"{s['setting_label']} — {_setting_text(s)}"]
        lines.append(report.text(columns, cells, title, _footer(s)))
    return "\n\n".join(lines + [textwrap.fill(result.get("notes", ""), 110)])


def _setting_text(s: dict) -> str:
    st = s["setting"]
    text = f"{st['density']:g} tags/m², {st['reader_mm']:g} mm readers, {st['trajectory']}"
    if "tuned" in s:
        text += f"; tuned: jitter {s['tuned']['jitter_mm']:.3g} mm, L = {s['tuned']['lag']}"
    return text


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
        rows = [_row_cells(r) for r in s["rows"]]
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

CELLS_BY_NAME["ps-slam-mixtures-tuned"] = _mixture_cells
PS_SLAM_MIXTURES_TUNED = Experiment(
    "ps-slam-mixtures-tuned",
    "PS-SLAM weighted against its tag particles, and with a tuned jitter and lag, vs PF-SLAM, 300 and 500 mm readers",
    _mixture_cells,
    _mixture_summary,
    render,
    markdown,
    plot_readings,
    MIXTURE_NOTES,
    compiler_options=sw.LIGHT_COMPILE,
)

EXPERIMENTS = (PS_SLAM_READINGS, PS_SLAM_MIXTURES_TUNED)
"""The ablations, listed by :mod:`jaxnav.experiments.catalog`."""
