"""The registry of [W]'s tables and figures: cells, summaries, rendering and the JSON layout (no filtering here)."""

from __future__ import annotations

import json
import subprocess
import sys

import jax
import numpy as np
import pytest

from jaxnav.experiments import registry
from jaxnav.experiments.hf_slam import ERROR_COLUMNS

NAMES = ("table-3.1", "table-3.2", "table-4.1", "table-4.2", "fig-3.5", "fig-3.7", "fig-4.4", "kidnapping")


def test_every_result_of_the_thesis_is_registered():
    for name in NAMES:
        assert registry.get(name).name == name
    with pytest.raises(ValueError, match="table-3.1"):
        registry.get("table-9.9")


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("quick", [False, True])
def test_cells_have_unique_ids_and_valid_settings(name, quick):
    cells = registry.get(name).cells(quick)
    assert cells and len({c.id for c in cells}) == len(cells)
    for c in cells:
        assert callable(c.fn)
        if quick:
            assert c.setting.robot_particles <= 200


@pytest.mark.parametrize(
    "quick, given, expected",
    [
        (False, None, "LIGHT_COMPILE"),
        (True, None, "FAST_COMPILE"),
        (False, {"xla_backend_optimization_level": 2}, "given"),
    ],
)
def test_compiler_options_default_to_the_experiments_own(quick, given, expected, monkeypatch):
    """A full HF-RFID SLAM sweep compiles with LIGHT_COMPILE, a quick one with FAST_COMPILE,
    and options passed by the caller win. A quick sweep evaluates its runs in a ``lax.map``, a full
    one as the experiment says."""
    from jaxnav.experiments import sweep as sw

    seen = {}

    def fake_sweep(cells, runs, key, path, chunk_size, progress, **kwargs):
        seen.update(kwargs)
        return _fake_errors(registry.get("table-3.1").cells(quick), runs, np.random.default_rng(0))

    monkeypatch.setattr(sw, "sweep", fake_sweep)
    registry.run("table-3.1", 3, jax.random.PRNGKey(0), quick=quick, compiler_options=given)
    want = given if expected == "given" else getattr(sw, expected)
    assert seen["compiler_options"] == want
    assert registry.get("table-3.1").batching == "vmap"  # so a full sweep's batching differs from a quick one's
    assert seen["batching"] == ("map" if quick else "vmap")
    assert registry.get("fig-4.4").compiler_options == sw.LIGHT_COMPILE
    assert registry.get("fig-5.3").compiler_options is None  # the UHF experiments keep XLA's defaults


def _fake_errors(cells, runs, rng):
    return {c.id: {col: rng.uniform(10, 50, runs) for col in ERROR_COLUMNS} for c in cells}


def test_table_summary_holds_mean_interval_and_thesis_value(tmp_path):
    exp = registry.get("table-3.1")
    cells = exp.cells(False)
    raw = _fake_errors(cells, 8, np.random.default_rng(0))
    result = {"experiment": exp.name, "title": exp.title, "runs": 8, "quick": False, **exp.summarize(raw, cells, False)}
    rows = result["rows"]
    assert [(r["setting"]["density"], r["method"]) for r in rows] == [
        (16.0, "fastslam"),
        (16.0, "pf_slam"),
        (100.0, "fastslam"),
        (100.0, "pf_slam"),
    ]
    first = rows[0]
    assert first["setting"] == {
        "density": 16.0,
        "reader_mm": 60.0,
        "trajectory": "rectangle",
        "fastslam_gaussian": "footprint",  # a FastSLAM row names its Gaussian
    }
    values = raw[cells[0].id]["dr_mm"]
    assert first["dr_mm"]["mean"] == pytest.approx(values.mean())
    lo, hi = first["dr_mm"]["ci95"]
    assert lo < values.mean() < hi
    assert first["dr_mm"]["paper"] == 36.6 and rows[3]["dt_mm"]["paper"] == 35.2
    json.dumps(result)  # JSON-ready
    text = exp.render(result)
    assert "36.6" in text and "PF-SLAM" in text
    assert "| 16 tags/m², 60 mm, rectangle, σ = s/√12 | FastSLAM |" in exp.markdown(result)
    assert "| 16 tags/m², 60 mm, rectangle | PF-SLAM |" in exp.markdown(result)
    exp.plot(result, str(tmp_path / "t.png"))
    assert (tmp_path / "t.png").stat().st_size > 10_000


def test_table_4_1_pools_the_five_rectangles():
    exp = registry.get("table-4.1")
    cells = exp.cells(False)
    assert len(cells) == 15 and len({c.setting.rectangle for c in cells}) == 5
    raw = _fake_errors(cells, 4, np.random.default_rng(1))
    rows = exp.summarize(raw, cells, False)["rows"]
    pooled = np.concatenate([raw[c.id]["dt_mm"] for c in cells if c.method == "ps_slam"])
    assert rows[0]["method"] == "ps_slam" and rows[0]["cells"] == 5
    assert rows[0]["dt_mm"]["mean"] == pytest.approx(pooled.mean())


def test_figure_summary_gives_curves(tmp_path):
    exp = registry.get("fig-3.7")
    cells = exp.cells(True)
    raw = _fake_errors(cells, 5, np.random.default_rng(2))
    result = {"experiment": exp.name, "title": exp.title, "runs": 5, **exp.summarize(raw, cells, True)}
    curves = result["curves"]
    assert {c["method"] for c in curves} == {"pf_slam", "fastslam"}
    assert all(len(c["x"]) == len(c["mean"]) == len(c["ci95"]) == 2 for c in curves)
    assert "robot particles" in exp.render(result)
    exp.plot(result, str(tmp_path / "f.png"))
    assert (tmp_path / "f.png").stat().st_size > 10_000


def test_cli_lists_the_experiments_and_refuses_unknown_names():
    out = subprocess.run([sys.executable, "-m", "jaxnav.cli", "experiments", "list"], capture_output=True, text=True)
    assert out.returncode == 0 and all(name in out.stdout for name in NAMES)
    bad = subprocess.run(
        [sys.executable, "-m", "jaxnav.cli", "experiments", "run", "table-9.9", "--runs", "1"],
        capture_output=True,
        text=True,
    )
    assert bad.returncode == 2 and "unknown experiment" in bad.stderr


# ---------------------------------------------------------------------------
# the explicit catalog


def test_catalog_lists_every_experiment_once_under_a_unique_name():
    from jaxnav.experiments import catalog

    listed = [exp for study in catalog.STUDIES for exp in study.EXPERIMENTS]
    names = [exp.name for exp in listed]
    assert len(names) == len(set(names)) == len(catalog.experiments())
    assert list(catalog.experiments()) == names
    assert all(registry.get(n) is e for n, e in zip(names, listed))
    assert registry.names() == tuple(sorted(names))
    assert set(NAMES) <= set(names)
    assert {"table-5.2", "table-5.3", "ir-failure", "fig-5.3", "fig-5.5", "fig-5.6", "uhf-refresh"} <= set(names)
    with pytest.raises(TypeError):
        catalog.experiments()["new"] = listed[0]  # read-only: nothing registers itself


def test_importing_the_registry_imports_no_study():
    """A fresh interpreter: the registry and the shared modules load without any study; the first
    look-up loads them through the catalog (and no study imports the registry or the catalog)."""
    code = (
        "import sys\n"
        "from jaxnav.experiments import registry, report, stats, sweep\n"
        "studies = ('hf_slam', 'ir', 'uhf', 'mrclam', 'catalog')\n"
        "loaded = lambda: sorted(m for m in sys.modules if m.split('.')[:3][-1] in studies and m.startswith('jaxnav.experiments.'))\n"
        "assert loaded() == [], loaded()\n"
        "registry.get('table-3.1')\n"
        "assert 'jaxnav.experiments.catalog' in sys.modules and 'jaxnav.experiments.hf_slam.tables' in sys.modules\n"
        "print('ok')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr


def test_no_study_imports_the_registry_or_the_catalog():
    import ast
    import pathlib

    root = pathlib.Path(registry.__file__).parent
    for path in root.rglob("*.py"):
        if path.name in ("registry.py", "catalog.py"):
            continue
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                mods = [node.module or ""] + [f"{node.module}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                mods = [a.name for a in node.names]
            else:
                continue
            for m in mods:
                assert m not in ("jaxnav.experiments.registry", "jaxnav.experiments.catalog"), (path, m)


# ---------------------------------------------------------------------------
# a score with nothing to score is NaN, never 0


def test_tag_errors_are_nan_when_no_tag_was_mapped():
    """HF-RFID SLAM: the robot errors of a perfect estimate are 0, but a run that mapped no tag has
    no tag error (NaN, not 0 mm); with one tag mapped 5 mm off in x the tag errors are 5, 0, 5 mm."""
    import jax
    import jax.numpy as jnp

    from jaxnav.experiments import hf_slam as hf
    from jaxnav.sim import tag_carpet as tc

    setting = hf.HFSetting(carpet=(1.5, 1.5), rectangle=(0.5, 0.5, 0.5, 0.5), laps=1)
    world = hf.make_world(jax.random.PRNGKey(0), setting)
    truth = world.run.true_poses
    tags = tc.tag_positions(world.carpet)
    nothing = hf.MethodRun(truth, tags, jnp.zeros(tags.shape[0], bool), jnp.zeros(truth.shape[0], bool))
    e = hf.score(world, nothing)
    assert float(e.dr_mm) == 0.0 and float(e.x_mm) == 0.0
    assert all(np.isnan(float(getattr(e, c))) for c in ("tx_mm", "ty_mm", "dt_mm"))
    one = nothing._replace(tags=tags.at[0, 0].add(0.005), seen=nothing.seen.at[0].set(True))
    e = hf.score(world, one)
    np.testing.assert_allclose([float(e.tx_mm), float(e.ty_mm), float(e.dt_mm)], [5.0, 0.0, 5.0], atol=1e-3)
    assert "n/a (nothing mapped)" in hf.format_errors([("none", hf.score(world, nothing))])


def test_table_reports_runs_that_mapped_nothing():
    """Two of eight runs of a row mapped no tag (NaN tag errors): the tag means are over the six
    others, the row counts the two, the JSON holds no 0 for them; a row where no run mapped a tag has
    NaN means, printed "n/a (nothing mapped)"."""
    exp = registry.get("table-3.1")
    cells = exp.cells(False)
    raw = _fake_errors(cells, 8, np.random.default_rng(3))
    for col in ("tx_mm", "ty_mm", "dt_mm"):
        raw[cells[0].id][col][:2] = np.nan
        raw[cells[1].id][col][:] = np.nan
    result = {"experiment": exp.name, "title": exp.title, "runs": 8, "quick": False, **exp.summarize(raw, cells, False)}
    some, none = result["rows"][0], result["rows"][1]
    assert some["dt_mm"]["mean"] == pytest.approx(np.mean(raw[cells[0].id]["dt_mm"][2:]))
    assert some["dt_mm"]["unscored_runs"] == 2 and "unscored_runs" not in some["dr_mm"]
    assert np.isnan(none["dt_mm"]["mean"]) and none["dt_mm"]["unscored_runs"] == 8
    text, md = exp.render(result), exp.markdown(result)
    assert "n/a (nothing mapped)" in text and "n/a (nothing mapped)" in md
    assert "; 2 runs n/a" in md and "(2 runs n/a)" in text
    assert "NaN" in json.dumps(result)


def test_ir_score_is_nan_without_a_scored_record():
    import jax.numpy as jnp

    from jaxnav.experiments.ir import positioning as ir

    poses = jnp.zeros((4, 3))
    mean, worst = ir.score(poses.at[:, 0].set(1.0), poses, jnp.full((4,), -1))
    assert np.all(np.isnan(np.asarray(mean))) and np.all(np.isnan(np.asarray(worst)))


def test_mrclam_map_error_is_nan_when_nothing_was_mapped():
    """A SLAM run that mapped no landmark prints "n/a (nothing mapped)", not 0 mm."""
    from jaxnav import metrics
    from jaxnav.experiments import mrclam as xp

    traj = metrics.TrajectoryError(np.float32(0.1), np.float32(0.01))
    nan_map = metrics.MapError(np.float32(np.nan), np.float32(np.nan), np.eye(2), np.zeros(2))
    res = xp.AlgorithmResult("ekf_slam", np.zeros((2, 3)), np.zeros((3, 2)), np.zeros(3, bool), 1.0, traj, 0.1, nan_map)
    line = xp.format_table([(1, res)]).splitlines()[-1]
    assert line.count("n/a (nothing mapped)") == 2 and "| 0 |" not in line
