"""The registry of [W]'s tables and figures: cells, summaries, rendering and the JSON layout (no filtering here)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from jaxnav.experiments import registry
from jaxnav.experiments.registry import ERROR_COLUMNS

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
        assert callable(c.run_fn())
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
    and options passed by the caller win."""
    from jaxnav.experiments import sweep as sw

    seen = {}

    def fake_sweep(cells, runs, key, path, chunk_size, progress, **kwargs):
        seen.update(kwargs)
        return _fake_errors(registry.get("table-3.1").cells(quick), runs, np.random.default_rng(0))

    monkeypatch.setattr(sw, "sweep", fake_sweep)
    registry.run("table-3.1", 3, None, quick=quick, compiler_options=given)
    want = given if expected == "given" else getattr(sw, expected)
    assert seen["compiler_options"] == want
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
    assert first["setting"] == {"density": 16.0, "reader_mm": 60.0, "trajectory": "rectangle"}
    values = raw[cells[0].id]["dr_mm"]
    assert first["dr_mm"]["mean"] == pytest.approx(values.mean())
    lo, hi = first["dr_mm"]["ci95"]
    assert lo < values.mean() < hi
    assert first["dr_mm"]["paper"] == 36.6 and rows[3]["dt_mm"]["paper"] == 35.2
    json.dumps(result)  # JSON-ready
    text = exp.render(result)
    assert "36.6" in text and "PF-SLAM" in text
    assert "| 16 tags/m², 60 mm, rectangle | FastSLAM |" in exp.markdown(result)
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
