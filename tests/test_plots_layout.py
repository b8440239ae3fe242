"""The plots read at a glance: legends inside the figure and off the data, quick variants named, titles
that match the data, errors drawn ≥ 0, one colour per method, every drawn line explained.

Each plot function saves through a ``_draw_*`` function that returns the figure; these tests draw the
figures (Agg) from the committed experiment results and from small synthetic inputs.
"""

from __future__ import annotations

import importlib
import json
from pathlib import Path

import numpy as np
import pytest

matplotlib = pytest.importorskip("matplotlib")
matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402
from matplotlib.container import ErrorbarContainer  # noqa: E402
from matplotlib.transforms import Bbox  # noqa: E402

from jaxnav.experiments import registry  # noqa: E402

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results" / "experiments"
NAMES = registry.names()


def _committed(name: str) -> dict:
    """The committed full result of ``name`` (every registered experiment has one: ``tests/test_docs.py``)."""
    return json.loads((RESULTS / f"{name}.json").read_text())


def _draw(name: str, result: dict):
    """The figure ``registry.get(name).plot`` saves."""
    plot = registry.get(name).plot
    module = importlib.import_module(plot.__module__)
    return getattr(module, "_draw_" + plot.__name__.removeprefix("plot_"))(result)


def _quick(result: dict) -> dict:
    return {**result, "quick": True, "runs": 4}


def _rendered(fig):
    fig.canvas.draw()  # runs the layout engine: extents are final
    return fig.canvas.get_renderer()


def _legends(fig) -> list:
    return list(fig.legends) + [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None]


def _suptitle(fig) -> str:
    return fig._suptitle.get_text() if fig._suptitle is not None else ""


def _titles(fig) -> str:
    return " ".join([_suptitle(fig), *(ax.get_title() for ax in fig.axes)])


def _assert_legends_inside(fig) -> None:
    renderer = _rendered(fig)
    figure = fig.bbox
    legends = _legends(fig)
    assert legends, "no legend"
    for legend in legends:
        box = legend.get_window_extent(renderer)
        assert (
            box.x0 >= figure.x0 - 1 and box.y0 >= figure.y0 - 1 and box.x1 <= figure.x1 + 1 and box.y1 <= figure.y1 + 1
        ), f"legend {[t.get_text() for t in legend.get_texts()]} at {box} leaves the figure {figure}"
    for text in [fig._suptitle, *(ax.title for ax in fig.axes)]:
        if text is not None and text.get_text():
            box = text.get_window_extent(renderer)
            assert box.x0 >= figure.x0 - 1 and box.x1 <= figure.x1 + 1, f"title {text.get_text()!r} is cut off"


def _data_boxes(ax, renderer) -> list[Bbox]:
    """Display boxes of the bars, error bars and markers of ``ax``."""
    boxes = [p.get_window_extent(renderer) for p in ax.patches if p.get_height() > 0] if ax.patches else []
    for c in ax.containers:
        if isinstance(c, ErrorbarContainer):
            for coll in c.lines[2]:
                for seg in coll.get_segments():
                    xy = ax.transData.transform(np.asarray(seg, float))
                    boxes.append(Bbox.from_extents(*(xy.min(0) - 2), *(xy.max(0) + 2)))
    for line in ax.lines:
        if line.get_linestyle() == "None":  # markers only
            pts = ax.transData.transform(np.column_stack([line.get_xdata(), line.get_ydata()]).astype(float))
            boxes += [Bbox.from_extents(x - 3, y - 3, x + 3, y + 3) for x, y in pts]
    return [b for b in boxes if np.isfinite(b.extents).all()]  # NaN: a value no run could score


def _assert_legends_off_the_data(fig) -> None:
    renderer = _rendered(fig)
    for legend in _legends(fig):
        box = legend.get_window_extent(renderer)
        for ax in fig.axes:
            for data in _data_boxes(ax, renderer):
                assert not box.overlaps(data), f"legend {[t.get_text() for t in legend.get_texts()]} covers data"


def _lowest_drawn_error(fig) -> float:
    """The lowest y (data units) of any error bar or shaded interval."""
    low = np.inf
    for ax in fig.axes:
        for c in ax.containers:
            if isinstance(c, ErrorbarContainer):
                for coll in c.lines[2]:
                    for seg in coll.get_segments():
                        low = min(low, float(np.nanmin(np.asarray(seg)[:, 1])))
        for coll in ax.collections:
            if isinstance(coll, PolyCollection):  # fill_between's shading
                for path in coll.get_paths():
                    low = min(low, float(np.nanmin(path.vertices[:, 1])))
    return low


# ---------------------------------------------------------------------------
# the experiments, from their committed results


@pytest.mark.parametrize("name", NAMES)
def test_experiment_plot_reads_at_a_glance(name):
    """Legends inside the figure (and, on bar charts, off the bars), intervals drawn ≥ 0, no "quick" in a
    full result's title; the quick variant of the same result says "quick variant"."""
    result = _committed(name)
    fig = _draw(name, result)
    try:
        _assert_legends_inside(fig)
        if registry.get(name).plot.__name__ == "plot_table":  # bar charts: nothing under a legend
            _assert_legends_off_the_data(fig)
        assert _lowest_drawn_error(fig) >= 0.0
        assert "quick" not in _titles(fig).lower()
    finally:
        plt.close(fig)
    quick = _draw(name, _quick(result))
    try:
        assert "quick variant" in _suptitle(quick)
    finally:
        plt.close(quick)


def test_a_quick_result_keeps_its_legends_in_the_figure():
    """The quick title's second line takes room: the legends still fit."""
    for name in ("table-3.1", "fig-3.7", "ir-speeds", "fig-5.5"):
        fig = _draw(name, _quick(_committed(name)))
        try:
            _assert_legends_inside(fig)
        finally:
            plt.close(fig)


def test_a_negative_stored_interval_is_drawn_from_zero():
    """A stored interval (mean ± t·s/√R) of widely spread runs can reach below 0 mm: it is drawn from 0."""
    import copy

    result = copy.deepcopy(_committed("ir-rotation"))
    row = result["rows"][0]
    row["dr_mm"]["ci95"] = [-0.5 * row["dr_mm"]["mean"], 2.5 * row["dr_mm"]["mean"]]  # as few spread runs give
    fig = _draw("ir-rotation", result)
    try:
        low = _lowest_drawn_error(fig)
        assert low == pytest.approx(0.0, abs=1e-9)
    finally:
        plt.close(fig)


def test_ir_speeds_title_names_the_speeds_of_the_data():
    result = _committed("ir-speeds")
    speeds = [r["speed_mm_s"] for r in result["rows"]]
    fig = _draw("ir-speeds", result)
    try:
        assert all(f"{v:g}" in _suptitle(fig) for v in speeds)
        assert fig.axes[0].get_xlabel() == "robot speed"
    finally:
        plt.close(fig)
    quick = _quick({**result, "rows": [r for r in result["rows"] if r["speed_mm_s"] in (200.0, 300.0)]})
    fig = _draw("ir-speeds", quick)
    try:
        title = _suptitle(fig)
        assert "200, 300 mm/s" in title and "100" not in title and "2 laps" in title
    finally:
        plt.close(fig)


def test_table_legend_leaves_the_first_error_bar_alone():
    """table-3.1's legend sat on its first bar's error bar."""
    fig = _draw("table-3.1", _committed("table-3.1"))
    try:
        renderer = _rendered(fig)
        first = []
        for ax in fig.axes:
            (bars,) = [c for c in ax.containers if isinstance(c, ErrorbarContainer)]
            seg = np.asarray(bars.lines[2][0].get_segments()[0], float)  # the first row's whisker
            xy = ax.transData.transform(seg)
            first.append(Bbox.from_extents(*(xy.min(0) - 2), *(xy.max(0) + 2)))
        assert len(first) == 2
        for legend in _legends(fig):
            assert not any(legend.get_window_extent(renderer).overlaps(b) for b in first)
    finally:
        plt.close(fig)


def test_uhf_curves_explain_the_dashed_lines():
    fig = _draw("fig-5.5", _committed("fig-5.5"))
    try:
        for ax in fig.axes:
            dashed = [ln for ln in ax.lines if ln.get_linestyle() == "--"]
            assert dashed and all(ln.get_label().startswith("[A]") for ln in dashed)
            texts = [t.get_text() for t in ax.get_legend().get_texts()]
            assert all(ln.get_label() in texts for ln in dashed)
    finally:
        plt.close(fig)


# ---------------------------------------------------------------------------
# the command-line plots, from small synthetic inputs


def test_hf_slam_run_plot_keeps_its_legends_in_the_figure(monkeypatch):
    """The map's legend (three columns under it) was cut off the bottom of the image."""
    from types import SimpleNamespace

    from jaxnav.experiments.hf_slam import simulation as hf

    rng = np.random.default_rng(0)
    t = np.arange(400)
    side = np.clip(t % 200, 0, 100) / 100.0  # a drive out and back, kidnapped half-way
    truth = np.column_stack([0.5 + side, 0.5 + 0.5 * (t >= 200), np.zeros_like(side)])
    tags = np.stack(np.meshgrid(np.arange(0, 2, 0.25), np.arange(0, 1.5, 0.25)), -1).reshape(-1, 2)
    kidnapped = t == 200
    run = SimpleNamespace(true_poses=truth, kidnapped=kidnapped)
    # the simulator's arrays the plot reads, without running it
    monkeypatch.setattr(hf, "dead_reckoning", lambda r: truth + 0.05)
    monkeypatch.setattr(hf.tc, "tag_positions", lambda carpet: tags)
    method_run = hf.MethodRun(
        truth + rng.normal(0, 0.02, truth.shape),
        tags + rng.normal(0, 0.03, tags.shape),
        rng.random(tags.shape[0]) < 0.5,
        np.zeros(truth.shape[0], bool),
    )
    setting = hf.HFSetting(trajectory="kidnapping", laps=1)
    fig = hf._draw_run(setting, "pf_slam", SimpleNamespace(run=run, carpet=None), method_run)
    try:
        _assert_legends_inside(fig)
        texts = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
        assert "kidnapped here (B)" in texts and "start" in texts and "PF-SLAM map" in texts
        shift_legend = [t.get_text() for t in fig.axes[2].get_legend().get_texts()]
        assert shift_legend[0].startswith("as mapped (mean") and "common shift" in shift_legend[1]
    finally:
        plt.close(fig)


def _mrclam_inputs():
    from jaxnav import metrics
    from jaxnav.experiments.mrclam import evaluation as ev
    from jaxnav.io import mrclam as data

    rng = np.random.default_rng(1)
    t = np.linspace(0, 2 * np.pi, 200)
    truth = np.column_stack([2 * np.cos(t), 2 * np.sin(t), t + np.pi / 2]).astype(np.float32)
    landmarks = rng.uniform(-4, 4, (15, 2)).astype(np.float32)
    fields = dict.fromkeys(data.MRCLAMSequence._fields, 0)
    seq = data.MRCLAMSequence(**{**fields, "true_poses": truth, "landmarks": landmarks, "dt": 0.1, "robot": 1})
    results = []
    for name in ("dead_reckoning", "ekf", "ekf_slam", "fastslam2"):
        est = truth + rng.normal(0, 0.1, truth.shape).astype(np.float32)
        slam = name in ("ekf_slam", "fastslam2")
        mapped = landmarks + rng.normal(0, 0.2, landmarks.shape) if slam else None
        seen = rng.random(15) < 0.8 if slam else None
        traj = metrics.trajectory_rmse(est, truth)
        results.append(ev.AlgorithmResult(name, est, mapped, seen, 1.0, traj, 0.1, None))
    return ev, seq, results


def test_mrclam_maps_share_their_path_colour_and_the_legend_is_off_the_map():
    ev, seq, results = _mrclam_inputs()
    fig = ev._draw_robot(seq, results)
    try:
        ax_map = fig.axes[0]
        lines = {ln.get_label(): ln for ln in ax_map.lines}
        for r in results:
            path = lines[ev.display_name(r.name)]
            maps = [ln for label, ln in lines.items() if label.startswith(f"{ev.display_name(r.name)} map")]
            if r.landmarks is None:
                assert not maps
                continue
            (marks,) = maps
            assert matplotlib.colors.same_color(marks.get_color(), path.get_color()), r.name
            assert matplotlib.colors.same_color(marks.get_markeredgecolor(), path.get_color()), r.name
        # the same colour for an algorithm in both panels
        errs = {ln.get_label(): ln for ln in fig.axes[1].lines}
        for r in results:
            assert matplotlib.colors.same_color(
                errs[ev.display_name(r.name)].get_color(), lines[ev.display_name(r.name)].get_color()
            )
        assert "landmarks (surveyed)" in lines  # the stars are named
        _assert_legends_inside(fig)
        renderer = _rendered(fig)
        for legend in _legends(fig):
            for ax in fig.axes:
                assert not legend.get_window_extent(renderer).overlaps(ax.get_window_extent(renderer))
    finally:
        plt.close(fig)


def test_uhf_real_plot_names_every_tag_line_and_the_search_box():
    from jaxnav.experiments.uhf import real

    rng = np.random.default_rng(2)
    results = []
    for g, truth in enumerate(np.array([[0.3, 0.9], [0.5, 0.9], [0.7, 0.9]])):
        for w in ("combined", "rssi", "phase"):
            est = truth + rng.normal(0, 0.05, (2, 50, 2))
            err = np.linalg.norm(est - truth, axis=-1)
            results.append(real.TagResult("exp", g, w, truth, est, err, err[:, -1], None))
    fig = real._draw_results(results)
    try:
        ax, bx = fig.axes
        curves = [ln for ln in bx.lines if len(ln.get_xdata()) > 1]
        assert len(curves) == 9
        assert all("tag" in ln.get_label() and not ln.get_label().startswith("_") for ln in curves)
        assert len({(ln.get_color(), ln.get_linestyle()) for ln in curves}) == 9  # told apart
        legend = [t.get_text() for t in bx.get_legend().get_texts()]
        assert sum(t.startswith("tag ") for t in legend) == 3  # the line styles explained
        box = [p for p in ax.patches if "search box" in p.get_label()]
        assert box and box[0].get_linestyle() == "--"
        _assert_legends_inside(fig)
    finally:
        plt.close(fig)


def _demo_result(steps: int = 40):
    from jaxnav.demo import DemoResult, cloud_steps

    rng = np.random.default_rng(3)
    a = np.linspace(0, 2 * np.pi, steps)
    truth = np.column_stack([5 + 2.4 * np.sin(a), 3.9 - 2.4 * np.cos(a), a])
    est = truth + rng.normal(0, 0.03, truth.shape)
    kept = np.asarray(cloud_steps(steps))
    clouds = np.stack([truth[max(t - 1, 0), :2] + rng.normal(0, 1.0 if t == 0 else 0.03, (300, 2)) for t in kept])
    landmarks = np.array([[0, 0], [5, 0], [10, 0], [10, 5], [10, 10], [5, 10], [0, 10], [0, 5]], float)
    err = np.linalg.norm(est[:, :2] - truth[:, :2], axis=1)
    return DemoResult(truth, est, err, landmarks, 0.25, kept, clouds)


def test_demo_plot_shows_clouds_names_the_start_and_keeps_the_legend_off_the_path():
    from jaxnav import demo

    result = _demo_result()
    fig = demo._draw_demo(result)
    try:
        ax = fig.axes[0]
        clouds = [ln for ln in ax.lines if ln.get_label().startswith("particles")]
        assert len(clouds) == len(result.cloud_steps) >= 3
        assert any(t.get_text() == "start" for t in ax.texts)
        _assert_legends_inside(fig)
        renderer = _rendered(fig)
        box = ax.get_legend().get_window_extent(renderer)
        path = ax.transData.transform(result.true_poses[:, :2])
        assert not any(box.contains(x, y) for x, y in path), "the legend covers the path"
    finally:
        plt.close(fig)


@pytest.mark.slow  # two compilations of the filter
def test_demo_keeps_the_particles_of_its_cloud_steps_without_changing_the_filter():
    """The clouds are the particles ``mcl.run`` holds at those steps; the estimates are ``mcl.run``'s."""
    import jax
    import jax.numpy as jnp

    from jaxnav import demo
    from jaxnav.localization import mcl
    from jaxnav.sim import landmark_world as world
    from jaxnav.sim import trajectories

    steps, n = 6, 64
    result = demo.run_demo(seed=1, num_steps=steps, num_particles=n)
    assert list(result.cloud_steps) == [0, 3, 6] and result.clouds.shape == (3, n, 2)
    # the same run, through the public filter
    config, params = demo.demo_setting(n)
    k_sim, k_init, k_run = jax.random.split(jax.random.PRNGKey(1), 3)
    controls = trajectories.loop_controls(steps, speed=0.5, turn_rate=0.21, dt=0.25)
    sim = world.simulate(k_sim, params.landmarks, jnp.asarray(demo.START), controls, params.motion, params.sensor)
    guess = jnp.asarray(demo.START) + jnp.asarray(demo.PRIOR_OFFSET)
    state = mcl.init(k_init, config, params, guess, jnp.asarray(demo.PRIOR_SD))
    np.testing.assert_array_equal(result.clouds[0], np.asarray(state.particles[:, :2]))
    final, trace = mcl.run(k_run, state, config, params, sim.controls, sim.observations)
    np.testing.assert_allclose(result.estimates, np.asarray(trace.estimate), atol=1e-6)
    np.testing.assert_allclose(result.clouds[-1], np.asarray(final.particles[:, :2]), atol=1e-6)
