"""The benchmark runner (benchmarks/run.py) keeps what a run measured when the run dies."""

from __future__ import annotations

import json

import pytest

from benchmarks import harness, run
from benchmarks.workloads import Workload


def _fake_workload(sizes_done: list) -> Workload:
    def run_size(ctx, size):
        if size["n"] == 3:
            raise KeyboardInterrupt  # a run killed mid-way: not caught like a workload's own error
        sizes_done.append(size["n"])
        return [harness.make_row("ZZ", "jaxnav", size, "per_call", median_s=0.001 * size["n"])]

    return Workload("ZZ", "a fake workload", [{"n": 1}, {"n": 2}, {"n": 3}], run_size, "n")


def test_each_size_is_written_as_it_finishes_and_a_full_run_is_marked_complete(tmp_path, monkeypatch):
    done: list = []
    monkeypatch.setattr(run, "discover", lambda: {"ZZ": _fake_workload(done)})
    monkeypatch.setattr(
        harness, "measure_bandwidth", lambda: {"bandwidth_bytes_per_s": 1e10, "bandwidth_GB_per_s": 10.0}
    )
    out = tmp_path / "res.json"
    with pytest.raises(KeyboardInterrupt):
        run.main(["--only", "ZZ", "--out", str(out), "--no-plot", "--retries", "0"])
    partial = json.loads(out.read_text())
    assert done == [1, 2]
    assert partial["complete"] is False
    assert [r["size"]["n"] for r in partial["rows"]] == [1, 2]
    assert not (tmp_path / "res.json.tmp").exists()

    monkeypatch.setattr(
        run, "discover", lambda: {"ZZ": Workload("ZZ", "t", [{"n": 1}, {"n": 2}], _fake_workload([]).run, "n")}
    )
    assert run.main(["--only", "ZZ", "--out", str(out), "--no-plot", "--retries", "0"]) == 0
    full = json.loads(out.read_text())
    assert full["complete"] is True and [r["size"]["n"] for r in full["rows"]] == [1, 2]


def test_terminal_table_tells_methods_and_precisions_apart():
    from benchmarks.harness import format_table

    def row(workload, impl, **extra):
        return dict(workload=workload, implementation=impl, size={"B": 1}, mode="in_scan", median_s=1e-3, **extra)

    kf = [row("W4", "jaxnav", dtype="float32"), row("W4", "jaxnav", dtype="float64")]
    slam = [
        row("S2", "jaxnav", method="pf_slam", dtype="float32"),
        row("S2", "jaxnav", method="ps_slam", dtype="float32"),
    ]
    lines = format_table(kf + slam).splitlines()
    assert "variant" in lines[0]
    for label in ("float32", "float64", "pf_slam", "ps_slam"):
        assert sum(label in line for line in lines[2:]) >= 1
    # one precision in a workload: the dtype is not shown
    assert not any("float32" in line for line in lines if line.startswith("S2"))
    # nothing to tell apart: no variant column
    assert "variant" not in format_table([row("W2", "jaxnav", dtype="float32")]).splitlines()[0]


def test_before_after_table_pairs_rows_and_divides(tmp_path):
    import json

    from benchmarks.before_after import table

    def result(path, median):
        rows = [
            dict(
                workload="W4", implementation="jaxnav", size={"B": 1}, mode="in_scan", dtype="float32", median_s=median
            ),
            dict(workload="W4", implementation="dynamax", size={"B": 1}, mode="in_scan", dtype="float64", median_s=1.0),
        ]
        path.write_text(json.dumps({"machine": {"cpu": "cpu", "cores": 2}, "rows": rows}))
        return str(path)

    text = table(result(tmp_path / "b.json", 2e-3), result(tmp_path / "a.json", 1e-3), implementation="jaxnav")
    (line,) = [l for l in text.splitlines() if l.startswith("| W4")]
    assert line == "| W4 | B=1 |  | jaxnav | in_scan | float32 | 2.00 ms | 1.00 ms | 0.50 |"


def test_plain_forms_rows_trace_without_the_fast_paths_and_restore_them():
    """The ``jaxnav-plain`` rows' switch: on inside the block (jax.random's loop back in the program), off after,
    even when the block raises."""
    import jax
    import jax.numpy as jnp

    from jaxnav.core import fastmath, rng

    def draw(key):
        return rng.uniform(key, (100,), jnp.float32)

    def has_loop() -> bool:
        return "stablehlo.while" in jax.jit(draw).lower(jax.random.key(0)).as_text()

    assert not fastmath.use_plain_forms() and not has_loop()
    with harness.plain_forms():
        assert fastmath.use_plain_forms() and has_loop()
    assert not fastmath.use_plain_forms() and not has_loop()
    with pytest.raises(RuntimeError), harness.plain_forms():
        raise RuntimeError("a failed row")
    assert not fastmath.use_plain_forms() and not has_loop()
