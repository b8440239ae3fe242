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


def test_markdown_tables_leave_out_the_columns_no_row_fills():
    """S2 has no peer and no floor: its table shows the sizes and jaxnav's times only, a column per method
    (PF-SLAM's and PS-SLAM's rows of one size are not one cell); W2, with a numpy peer and a floor, keeps
    the ratio columns, and jaxnav's time over the floor where no peer ran."""
    from benchmarks.markdown import tables

    def row(workload, impl, n, median_s, **extra):
        return dict(workload=workload, implementation=impl, size={"N": n}, mode="per_call", median_s=median_s, **extra)

    payload = {
        "rows": [
            row("S2", "jaxnav", 10, 2e-3, method="pf_slam"),
            row("S2", "jaxnav", 10, 5e-3, method="ps_slam"),
            row("S2", "jaxnav", 100, 3e-3, method="pf_slam"),
            row("S2", "jaxnav", 100, 6e-3, method="ps_slam"),
            row("W2", "jaxnav", 1000, 2e-3, floor_s=1e-5),
            row("W2", "numpy", 1000, 4e-3, floor_s=1e-5),
            row("W2", "jaxnav", 10000, 8e-3, floor_s=1e-4),
        ]
    }
    lines = tables(payload).splitlines()
    s2 = lines[lines.index("| size | jaxnav (per_call, pf_slam) | jaxnav (per_call, ps_slam) |") :]
    assert s2[1] == "|---|---|---|"
    assert s2[2:4] == ["| N=10 | 2.00 ms | 5.00 ms |", "| N=100 | 3.00 ms | 6.00 ms |"]
    w2_head = next(line for line in lines if line.startswith("| size | jaxnav (per_call) | numpy"))
    assert w2_head.endswith("| floor | jaxnav best / fastest peer | jaxnav best / floor |")
    w2 = lines[lines.index(w2_head) + 2 : lines.index(w2_head) + 4]
    assert w2[0].split(" | ")[-2:] == ["0.50", "200 |"]  # 2 ms / 4 ms, 2 ms / 10 µs
    assert w2[1].split(" | ")[-3:] == ["100.0 µs", "", "80 |"]  # no peer at N=1e4: its floor ratio still shown
