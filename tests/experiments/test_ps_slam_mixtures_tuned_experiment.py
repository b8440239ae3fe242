"""The quick variant of ``ps-slam-mixtures-tuned`` end to end: its files, the JSON's layout, the mixture
readings' rows and the tuned jitter and lag (:mod:`jaxnav.experiments.hf_slam.readings`).

One module fixture runs it with R = 2 runs (one setting, Table 4.2's random trajectory, shortened; a
2 × 2 tuning grid on 2 training runs), nearly all of its time compiling the cell's five filters and the
grid's two lags.
"""

import json

import jax
import numpy as np
import pytest

from jaxnav.experiments import registry
from jaxnav.experiments.hf_slam import readings as rd

RUNS = 2
NAME = "ps-slam-mixtures-tuned"


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("mixtures")
    result = registry.run(NAME, RUNS, jax.random.PRNGKey(0), str(out), quick=True, chunk_size=RUNS, progress=False)
    return result, out


def test_files_and_json_layout(quick):
    result, out = quick
    for ext in (".json", ".md", ".png", ".runs.json"):
        assert (out / f"{NAME}.quick{ext}").stat().st_size > 0
    stored = json.loads((out / f"{NAME}.quick.json").read_text())
    assert stored["experiment"] == NAME and stored["quick"] is True and stored["runs"] == RUNS
    (s,) = stored["settings"]
    assert s["setting_label"] == "table-4.2" and s["runs"] == RUNS
    assert [r["row"] for r in s["rows"]] == ["PF-SLAM", "default", "smoothed particles", "tag particles", "tuned"]
    readings = {r["row"]: r["readings"] for r in s["rows"]}
    assert readings["smoothed particles"] == {"robot_target": "smoothed_particles"}
    assert readings["tag particles"] == {"robot_target": "particles"}
    assert readings["default"] == readings["tuned"] == {}
    for r in s["rows"]:
        for col in ("dr_mm", "dt_mm"):
            assert np.isfinite(r[col]["mean"]) and r[col]["ci95"][0] <= r[col]["mean"] <= r[col]["ci95"][1]
        assert ("dr_mm_minus_pf" in r) == (r["row"] != "PF-SLAM")
    md = (out / f"{NAME}.quick.md").read_text()
    assert "PS − PF" in md and "tag particles" in md and "tuned: jitter" in md


def test_cells_draw_fresh_seeds():
    """Its worlds are not those of ps-slam-readings: the cell ids, from which the run keys come, differ."""
    ids = {c.id for c in registry.get(NAME).cells(False)}
    assert ids.isdisjoint(c.id for c in registry.get("ps-slam-readings").cells(False))
    assert len(ids) == len(rd.SETTINGS)


def test_the_mixtures_weight_the_robot_differently_from_the_default(quick):
    """Same worlds and filter keys: a mixture row that gave the default's errors run for run would be the
    default filter under another name."""
    _, out = quick
    (cell,) = json.loads((out / f"{NAME}.quick.runs.json").read_text())["cells"].values()
    default = np.asarray(cell["default/dr_mm"], float)
    for row in ("smoothed particles", "tag particles"):
        assert not np.allclose(np.asarray(cell[f"{row}/dr_mm"], float), default), row


def test_tuned_jitter_and_lag_come_from_the_training_grid(quick):
    """The tuned row's jitter and lag are the grid point of the lowest mean robot error on the training
    worlds (computed again here: the choice is cached per process)."""
    result, _ = quick
    (cell,) = registry.get(NAME).cells(True)
    jitter, lag = rd.tuned_smoother(cell.id, cell.setting, True)
    tuned = result["settings"][0]["tuned"]
    assert tuned["lag"] == lag and tuned["jitter_mm"] == pytest.approx(1000 * jitter, rel=1e-6)
    half = cell.setting.reader_side / 2
    assert lag in rd._QUICK_LAGS and any(abs(jitter - f * half) < 1e-9 for f in rd._QUICK_JITTERS)


def test_tuning_grid_picks_the_lowest_mean_error():
    """The grid's argmin is the choice; a grid point where a run diverged is never chosen."""
    (cell,) = registry.get(NAME).cells(True)
    key = jax.random.fold_in(jax.random.PRNGKey(rd.TUNING_SEED), 7)
    grid = rd.tuning_grid(key, cell.setting, rd._QUICK_JITTERS, rd._QUICK_LAGS[:1], 2)
    assert grid.shape == (1, len(rd._QUICK_JITTERS)) and np.isfinite(grid).all() and (grid > 0).all()
