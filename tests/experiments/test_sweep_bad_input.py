"""Damaged, foreign or stale sweep checkpoints are refused, and diverged runs reach every table.

A checkpoint (jaxnav.experiments.sweep) is refused with one ``ValueError`` line that names the
file and says to pass ``--fresh``, and the file is left as it was; never a raw ``KeyError``,
``TypeError`` or ``JSONDecodeError``, never mixed into the means. A run that diverged (a
non-finite value in a quantity every run has) is counted in the JSON and named in the tables.
"""

from __future__ import annotations

import json
import subprocess
import sys
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.experiments import registry
from jaxnav.experiments import sweep as sw
from jaxnav.experiments.hf_slam import ERROR_COLUMNS

RUNS, CHUNK = 4, 2
KEY = jax.random.PRNGKey(11)


class Run(NamedTuple):
    value: jax.Array  # float
    count: jax.Array  # int32
    curve: jax.Array  # [3] floats


def _fn(key):
    return Run(jax.random.normal(key), jnp.int32(2), jax.random.uniform(key, (3,)))


CELLS = [("first", _fn), ("second", _fn)]


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    """A complete checkpoint of RUNS runs in chunks of CHUNK, as text."""
    path = tmp_path_factory.mktemp("good") / "runs.json"
    sw.sweep(CELLS, RUNS, KEY, str(path), chunk_size=CHUNK, progress=False)
    return path.read_text()


def _edit(change):
    """A mutation of the parsed checkpoint, written back as standard JSON."""

    def mutate(text):
        data = json.loads(text)
        change(data)
        return json.dumps(data)

    return mutate


def _set(*where, value):
    def change(data):
        node = data
        for k in where[:-1]:
            node = node[k]
        node[where[-1]] = value

    return _edit(change)


def _drop(*where):
    def change(data):
        node = data
        for k in where[:-1]:
            node = node[k]
        del node[where[-1]]

    return _edit(change)


def _first_value(literal):
    """The checkpoint's text with the first run of ``first``'s ``value`` replaced by ``literal`` verbatim."""

    def mutate(text):
        data = json.loads(text)
        data["cells"]["first"]["value"][0] = "@@"
        return json.dumps(data).replace('"@@"', literal)

    return mutate


def _uneven(data):
    data["cells"]["first"]["value"].pop()


def _rename(data):
    data["cells"]["first"]["values"] = data["cells"]["first"].pop("value")


BAD = {
    # unreadable
    "truncated": (lambda t: t[: len(t) // 2], "not valid JSON"),
    "cut-after-one-character": (lambda t: t[:1], "not valid JSON"),
    "empty-file": (lambda t: "", "empty"),
    "blank-file": (lambda t: " \n", "empty"),
    "not-utf8": (lambda t: "\udcff", "not UTF-8"),
    "nested-too-deeply": (lambda t: "[" * 200_000 + "]" * 200_000, "too deeply"),
    # another structure
    "an-array": (lambda t: "[1, 2]", "an array, not an object"),
    "a-number": (lambda t: "42", "a number, not an object"),
    "no-cells": (_drop("cells"), "lacks the key cells"),
    "stray-key": (_set("extra", value=1), "unknown key 'extra'"),
    "meta-not-an-object": (_set("meta", value=[1]), "meta is an array"),
    "cells-an-array": (_set("cells", value=[]), "cells are an array"),
    "unknown-cell": (_set("cells", "third", value={}), "cell 'third'"),
    "cell-an-array": (_set("cells", "first", value=[1.0, 2.0]), "an array, not an object of fields"),
    "field-a-number": (_set("cells", "first", "value", value=3.5), "a number, not an array of runs"),
    "key-twice": (lambda t: t.replace('"chunk_size": 2', '"chunk_size": 2, "chunk_size": 2'), "twice"),
    # another sweep
    "other-seed": (_set("meta", "seed", value=[0, 1]), "other settings (seed"),
    "other-cells": (_set("meta", "cells", value=["first"]), "other settings (cells"),
    "other-version": (_set("meta", "jaxnav", value="0.0.1"), "other settings (jaxnav '0.0.1' in the file"),
    "other-meta": (_set("meta", "experiment", value="table-3.1"), "other settings (experiment"),
    # chunk size
    "chunk-size-zero": (_set("chunk_size", value=0), "chunk_size is 0"),
    "chunk-size-string": (_set("chunk_size", value="2"), "chunk_size is '2'"),
    "chunk-size-true": (_set("chunk_size", value=True), "chunk_size is True"),
    "chunk-size-fraction": (_set("chunk_size", value=2.5), "chunk_size is 2.5"),
    # the runs
    "uneven-lengths": (_edit(_uneven), "different numbers of runs"),
    "string-in-numbers": (_set("cells", "first", "value", 1, value="0.5"), "'0.5', a string"),
    "object-in-numbers": (_set("cells", "first", "value", 1, value={"v": 1}), "an object, where a number"),
    "true-among-numbers": (_set("cells", "first", "value", 1, value=True), "mixes true/false"),
    "nan-literal": (_first_value("NaN"), "literal NaN"),
    "infinity-literal": (_first_value("Infinity"), "literal Infinity"),
    "minus-infinity-literal": (_first_value("-Infinity"), "literal -Infinity"),
    "overflowing-number": (_first_value("1e999"), "out of the float range"),
    "huge-integer": (_set("cells", "first", "count", 0, value=10**30), "out of range"),
    "ragged-curve": (_set("cells", "first", "curve", 1, value=[0.5, 0.5]), "uneven shapes"),
    "scalar-for-curve": (_set("cells", "first", "curve", 1, value=0.5), "uneven shapes"),
    "list-for-scalar": (_set("cells", "first", "value", value=[[1.0]] * RUNS), "shape (1,)"),
    "null-in-integers": (_set("cells", "first", "count", 2, value=None), "not integers"),
    "fraction-in-integers": (_set("cells", "first", "count", 2, value=2.5), "not integers"),
    "renamed-field": (_edit(_rename), "written by other code"),
    "missing-field": (_drop("cells", "second", "curve"), "written by other code"),
}


@pytest.mark.parametrize("case", list(BAD), ids=list(BAD))
def test_a_bad_checkpoint_is_refused_naming_the_file_and_fresh(good, tmp_path, case):
    mutate, reason = BAD[case]
    path = tmp_path / "runs.json"
    path.write_text(mutate(good), encoding="utf-8", errors="surrogateescape")
    before = path.read_bytes()
    with pytest.raises(ValueError) as err:
        sw.sweep(CELLS, RUNS, KEY, str(path), chunk_size=CHUNK, progress=False)
    message = str(err.value)
    assert message.startswith(f"{path}: ") and "--fresh" in message and "\n" not in message, message
    assert reason in message, message
    assert path.read_bytes() == before  # refused, not overwritten


def test_a_checkpoint_without_its_chunk_size_is_only_read(good, tmp_path):
    """A checkpoint that does not record its chunk size (nor a checksum: written by an older jaxnav) is read
    when complete, refused when runs are missing."""
    data = json.loads(good)
    del data["chunk_size"], data["sha256"]
    path = tmp_path / "runs.json"
    path.write_text(json.dumps(data))
    with pytest.warns(sw.UnverifiedCheckpointWarning):
        out = sw.sweep(CELLS, RUNS, KEY, str(path), chunk_size=CHUNK, progress=False)
    assert out["second"]["value"].tolist() == data["cells"]["second"]["value"]
    with pytest.raises(ValueError) as err:
        sw.sweep(CELLS, RUNS + 2, KEY, str(path), chunk_size=CHUNK, progress=False)
    message = str(err.value)
    assert message.startswith(f"{path}: ") and "does not record its chunk size" in message and "--fresh" in message


def test_another_chunk_size_is_refused_naming_both_sizes(good, tmp_path):
    """Runs still to compute (R = 6 of a 4-run checkpoint) in chunks of 3 would round differently from the
    checkpoint's chunks of 2."""
    path = tmp_path / "runs.json"
    path.write_text(good)
    with pytest.raises(ValueError) as err:
        sw.sweep(CELLS, 6, KEY, str(path), chunk_size=3, progress=False)
    message = str(err.value)
    assert message.startswith(f"{path}: ") and "chunks of 2" in message and "chunks of 3" in message
    assert "--chunk 2" in message and "--fresh" in message and "\n" not in message


def test_fresh_replaces_a_bad_checkpoint(good, tmp_path):
    path = tmp_path / "runs.json"
    path.write_text(good[:40])
    out = sw.sweep(CELLS, RUNS, KEY, str(path), chunk_size=CHUNK, progress=False, fresh=True)
    assert json.loads(path.read_text()) == json.loads(good)
    assert out["first"]["curve"].shape == (RUNS, 3) and out["first"]["count"].tolist() == [2] * RUNS


def test_null_marks_a_run_that_has_no_finite_value(good, tmp_path):
    """null is the checkpoint's non-finite value: read as NaN, whatever the field's shape."""
    data = json.loads(good)
    data["cells"]["first"]["value"][1] = None
    data["cells"]["first"]["curve"][2][0] = None
    data["sha256"] = sw._checksum(data)  # as if the runs had returned NaN
    path = tmp_path / "runs.json"
    path.write_text(json.dumps(data))
    out = sw.sweep(CELLS, RUNS, KEY, str(path), chunk_size=CHUNK, progress=False)
    assert np.isnan(out["first"]["value"]).tolist() == [False, True, False, False]
    assert np.isnan(out["first"]["curve"]).sum() == 1 and np.isnan(out["first"]["curve"][2, 0])


def test_the_command_line_prints_the_refusal_on_one_line(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    checkpoint = out / "table-3.1.quick.runs.json"
    checkpoint.write_text('{"meta": {"cells": ["16|fastslam|0"')
    run = subprocess.run(
        [sys.executable, "-m", "jaxnav.cli", "experiments", "run", "table-3.1", "--quick", "--runs", "2"]
        + ["--out", str(out), "--no-progress"],
        capture_output=True,
        text=True,
    )
    assert run.returncode == 2, run.stderr
    lines = [line for line in run.stderr.splitlines() if str(checkpoint) in line]
    assert len(lines) == 1 and "--fresh" in lines[0] and "Traceback" not in run.stderr, run.stderr


# ---------------------------------------------------------------------------
# diverged runs are counted in the JSON and named in the tables


def _fake(cells, runs, seed=0):
    rng = np.random.default_rng(seed)
    return {c.id: {col: rng.uniform(10, 50, runs) for col in ERROR_COLUMNS} for c in cells}


def _result(exp, raw, cells, runs, quick):
    return {
        "experiment": exp.name,
        "title": exp.title,
        "runs": runs,
        "quick": quick,
        **exp.summarize(raw, cells, quick),
    }


def test_a_table_counts_its_diverged_runs():
    """Two of eight PF-SLAM runs diverged (robot errors NaN, +inf): they are left out of every column, even
    where their value is finite, counted in the row's JSON and named under the text and Markdown tables; a
    run that merely mapped nothing stays an unscored run."""
    exp = registry.get("table-3.1")
    cells = exp.cells(False)
    raw = _fake(cells, 8)
    pf = raw[cells[1].id]
    pf["dr_mm"][2], pf["x_mm"][5], pf["dt_mm"][2] = np.nan, np.inf, np.nan
    for col in ("tx_mm", "ty_mm", "dt_mm"):
        pf[col][0] = np.nan  # nothing mapped, not diverged
    result = _result(exp, raw, cells, 8, False)
    row = result["rows"][1]
    assert row["diverged_runs"] == 2 and row["runs"] == 8
    assert all(r["diverged_runs"] == 0 for i, r in enumerate(result["rows"]) if i != 1)
    kept = np.ones(8, bool)
    kept[[2, 5]] = False
    assert row["dr_mm"]["mean"] == pytest.approx(np.mean(pf["dr_mm"][kept]))
    assert row["y_mm"]["mean"] == pytest.approx(np.mean(pf["y_mm"][kept]))  # run 5's finite y is left out too
    assert row["dt_mm"]["unscored_runs"] == 1 and "unscored_runs" not in row["dr_mm"]
    line = "16 tags/m², 60 mm, rectangle, PF-SLAM: 2 of 8 runs diverged"
    assert line in exp.render(result) and line in exp.markdown(result)
    assert json.loads(json.dumps(result))["rows"][1]["diverged_runs"] == 2


def test_curves_count_their_diverged_runs_per_point():
    exp = registry.get("fig-3.7")
    cells = exp.cells(True)
    raw = _fake(cells, 5, seed=1)
    raw[cells[0].id]["theta_rad"][3] = np.nan  # PF-SLAM at the first particle count
    result = _result(exp, raw, cells, 5, True)
    pf_dr = result["curves"][0]
    assert pf_dr["diverged_runs"] == [1, 0] and pf_dr["runs"] == [5, 5]
    assert pf_dr["mean"][0] == pytest.approx(np.mean(np.delete(raw[cells[0].id]["dr_mm"], 3)))
    assert all(c["diverged_runs"] == [0, 0] for c in result["curves"][2:])
    assert "(1 of 5 runs diverged)" in exp.render(result) and "(1 of 5 runs diverged)" in exp.markdown(result)


def test_the_kidnapping_leaves_its_diverged_runs_out_of_every_number():
    exp = registry.get("kidnapping")
    cells = exp.cells(True)
    rng = np.random.default_rng(2)
    steps, k = 600, 300
    raw = {c.id: {"error_mm": rng.uniform(20, 40, (4, steps)), "kidnap_step": np.full(4, k)} for c in cells}
    raw[cells[0].id]["error_mm"][1, 10] = np.inf
    result = _result(exp, raw, cells, 4, True)
    curve = result["curves"][0]
    assert set(curve["diverged_runs"]) == {1} and set(result["curves"][1]["diverged_runs"]) == {0}
    kept = np.delete(raw[cells[0].id]["error_mm"], 1, axis=0)
    assert curve["before_mm"] == pytest.approx(kept[:, k - 50 : k].mean())
    assert np.isfinite(curve["after_mm"]) and all(np.isfinite(curve["mean"]))
    assert "1 of 4 runs diverged (non-finite results): left out of every point" in exp.render(result)


def test_fig_3_5_counts_a_run_whose_sums_diverged():
    exp = registry.get("fig-3.5")
    cells = exp.cells(True)
    bins = 12
    rng = np.random.default_rng(3)
    raw = {"pf_slam": {"sums": rng.uniform(10, 50, (3, bins)), "counts": np.ones((3, bins), np.int64)}}
    raw["pf_slam"]["sums"][0, 4] = np.nan
    (curve,) = _result(exp, raw, cells, 3, True)["curves"]
    assert curve["diverged_runs"] == [1] * bins and curve["samples"] == [2] * bins


def _shaped_fake(cell, runs, rng):
    shapes = jax.eval_shape(lambda k: cell.fn(k, *cell.args), jax.random.PRNGKey(0))
    shapes = shapes._asdict() if hasattr(shapes, "_asdict") else dict(shapes)
    return {k: rng.uniform(0.01, 1.0, (runs, *v.shape)) for k, v in shapes.items()}


def test_an_ir_table_counts_its_diverged_runs():
    from jaxnav.experiments.ir.positioning import IRErrors  # every field one scalar per run

    exp = registry.get("table-5.2")
    cells = exp.cells(True)
    rng = np.random.default_rng(4)
    raw = {c.id: {f: rng.uniform(0.01, 1.0, 6) for f in IRErrors._fields} for c in cells}
    for col in ("x_mm", "dr_mm", "x_mm_max", "dr_mm_max"):
        raw[cells[0].id][col][1] = np.nan
    result = _result(exp, raw, cells, 6, True)
    row = result["rows"][0]
    assert row["diverged_runs"] == 1 and [r["diverged_runs"] for r in result["rows"][1:]] == [0, 0]
    kept = np.delete(raw[cells[0].id]["y_mm"], 1)
    assert row["y_mm"]["mean"] == pytest.approx(kept.mean()) and "unscored_runs" not in row["dr_mm"]
    assert row["dr_mm"]["median"] == pytest.approx(np.median(np.delete(raw[cells[0].id]["dr_mm"], 1)))
    line = "proposed: 1 of 6 runs diverged"
    assert line in exp.render(result) and line in exp.markdown(result)


def test_a_uhf_figure_counts_its_diverged_runs():
    exp = registry.get("fig-5.6")
    cells = exp.cells(True)
    rng = np.random.default_rng(5)
    raw = {c.id: _shaped_fake(c, 5, rng) for c in cells}
    raw[cells[1].id]["err_phase"][3, 7] = np.nan
    result = _result(exp, raw, cells, 5, True)
    light, strong = result["diagnostics"]
    assert strong["diverged_runs"] == {"rssi": 0, "phase": 1, "combined": 0} and strong["runs"] == 5
    assert set(light["diverged_runs"].values()) == {0}
    phase = next(r for r in result["rows"] if r["setting"]["multipath"] == "strong" and r["method"] == "phase")
    assert np.all(np.isfinite(phase["rmse_m"]["mean"])) and np.isfinite(phase["final_rmse_m"]["mean"])
    line = "strong, 2D, anchor 0.05 m (0.29 λ), phase: 1 of 5 runs diverged"
    assert line in exp.render(result) and line in exp.markdown(result)


def test_a_checkpoint_null_reaches_the_written_table(tmp_path):
    """End to end without computing: a complete table-3.1 checkpoint whose run 1 of a PF-SLAM cell diverged
    (null robot errors) is read, and the JSON and Markdown that registry.run writes count it."""
    exp = registry.get("table-3.1")
    cells = exp.cells(True)
    from jaxnav import __version__

    meta = {
        "cells": [c.id for c in cells],
        "seed": np.asarray(jax.random.key_data(KEY)).tolist(),
        "jaxnav": __version__,
        "experiment": "table-3.1",
        "quick": True,
    }
    runs = {c.id: {col: [20.0, 30.0] for col in ERROR_COLUMNS} for c in cells}
    for col in ("x_mm", "dr_mm"):
        runs["16|pf_slam|0"][col][1] = None
    (tmp_path / "table-3.1.quick.runs.json").write_text(json.dumps({"meta": meta, "chunk_size": 2, "cells": runs}))
    result = registry.run("table-3.1", 2, KEY, str(tmp_path), quick=True, progress=False)
    written = json.loads((tmp_path / "table-3.1.quick.json").read_text())
    pf16 = next(r for r in written["rows"] if r["row"] == "16" and r["method"] == "pf_slam")
    assert pf16["diverged_runs"] == 1 and pf16["dr_mm"]["mean"] == 20.0 and pf16["y_mm"]["mean"] == 20.0
    assert "PF-SLAM: 1 of 2 runs diverged" in (tmp_path / "table-3.1.quick.md").read_text()
    assert "PF-SLAM: 1 of 2 runs diverged" in exp.render(result)


def test_a_committed_full_size_checkpoint_still_reads(tmp_path):
    """The committed full-size checkpoint of table-3.1 passes the checks and gives the committed result
    again, with its diverged-run counts (none)."""
    import pathlib
    import shutil

    full = pathlib.Path(__file__).resolve().parents[2] / "benchmarks" / "results" / "experiments"
    if not (full / "table-3.1.runs.json").exists():
        pytest.skip(f"no full-size checkpoint in {full}")
    shutil.copy(full / "table-3.1.runs.json", tmp_path)
    committed = json.loads((full / "table-3.1.json").read_text())
    result = registry.run("table-3.1", committed["runs"], jax.random.PRNGKey(0), str(tmp_path), progress=False)
    for new, old in zip(result["rows"], committed["rows"]):
        assert new["diverged_runs"] == 0 and new["runs"] == committed["runs"]
        for col in ERROR_COLUMNS:
            assert new[col]["mean"] == old[col]["mean"] and new[col]["ci95"] == old[col]["ci95"]
