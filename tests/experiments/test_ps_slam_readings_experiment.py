"""The quick variant of ``ps-slam-readings`` end to end: its files, the JSON's layout and the paired
differences (:mod:`jaxnav.experiments.hf_slam.readings`).

One module fixture runs it with R = 2 runs (one setting, Table 4.2's random trajectory, shortened),
nearly all of its time compiling the seven filters of the cell.
"""

import json

import jax
import numpy as np
import pytest

from jaxnav.experiments import registry
from jaxnav.experiments.hf_slam import readings as rd

RUNS = 2
NAME = "ps-slam-readings"


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("readings")
    result = registry.run(NAME, RUNS, jax.random.PRNGKey(0), str(out), quick=True, chunk_size=RUNS, progress=False)
    return result, out


def test_files_and_json_layout(quick):
    result, out = quick
    for ext in (".json", ".md", ".png", ".runs.json"):
        assert (out / f"{NAME}.quick{ext}").stat().st_size > 0
    stored = json.loads((out / f"{NAME}.quick.json").read_text())
    assert stored["experiment"] == NAME and stored["quick"] is True and stored["runs"] == RUNS
    assert [s["setting_label"] for s in stored["settings"]] == ["table-4.2"]
    for s in stored["settings"]:
        assert set(s["setting"]) == {"density", "reader_mm", "trajectory"} and s["runs"] == RUNS
        labels = [r["row"] for r in s["rows"]]
        assert labels == ["PF-SLAM"] + [label for label, _ in rd.READINGS]
        for r in s["rows"]:
            for col in ("dr_mm", "dt_mm"):
                v = r[col]
                assert np.isfinite(v["mean"]) and v["ci95"][0] <= v["mean"] <= v["ci95"][1]
            assert ("dr_mm_minus_pf" in r) == (r["row"] != "PF-SLAM")
        assert s["rows"][1]["readings"] == {} and s["rows"][3]["readings"] == {"resampled_state": "smoothed"}
    md = (out / f"{NAME}.quick.md").read_text()
    assert "PS − PF" in md and "feedback" in md


def test_differences_are_paired_by_seed(quick):
    """Each PS − PF is the mean of per-seed differences: it equals the difference of the means, and its
    interval comes from the differences (the runs are stored per seed in the checkpoint)."""
    result, out = quick
    runs = json.loads((out / f"{NAME}.quick.runs.json").read_text())["cells"]
    (cell,) = runs.values()
    pf = np.asarray(cell["PF-SLAM/dr_mm"], float)
    for r in result["settings"][0]["rows"][1:]:
        ps = np.asarray(cell[f"{r['row']}/dr_mm"], float)
        d = r["dr_mm_minus_pf"]
        np.testing.assert_allclose(d["mean"], np.mean(ps - pf), rtol=1e-9)
        half = 12.706 * np.std(ps - pf, ddof=1) / np.sqrt(RUNS)  # Student t, 1 degree of freedom
        np.testing.assert_allclose(d["ci95"][1] - d["mean"], half, rtol=1e-3)
