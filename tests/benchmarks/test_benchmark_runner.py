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
