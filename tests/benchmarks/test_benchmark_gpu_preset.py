"""The GPU preset of the benchmark runner (``python -m benchmarks.run --preset gpu``, benchmarks/presets.py).

* its plan (workloads and sizes) is the one the docs give, in benchmarks/README.md and in the guide
  docs/guides/scaling-out.md, and each size has the keys of its registered workload;
* ``--scale-down`` divides every size by the preset's factor (at least the workload's minimum,
  sizes that fall together kept once);
* a tiny scaled run (a fake workload in place of the real ones) writes the device's kind, platform,
  memory and measured bandwidth, the scaling and the plan to the JSON, measures only the preset's
  implementations and takes its floors from the device's bandwidth;
* the run budget keeps a size from starting once the budget is spent.
"""

from __future__ import annotations

import functools
import json
import pathlib
import re

import jax
import pytest

from benchmarks import harness, run
from benchmarks.presets import GPU, Preset
from benchmarks.workloads import REGISTRY, Workload, discover

ROOT = pathlib.Path(__file__).resolve().parents[2]
DOCS = (ROOT / "benchmarks" / "README.md", ROOT / "docs" / "guides" / "scaling-out.md")
_SUPERSCRIPT = str.maketrans("⁰¹²³⁴⁵⁶⁷⁸⁹", "0123456789")


def _number(text: str) -> int:
    """``"10⁶"`` → 10**6, ``"1,000"`` → 1000."""
    text = text.strip().replace(",", "")
    if text.startswith("10") and text[2:] and not text[2:].isascii():  # "⁶".isdigit() holds: not a test
        return 10 ** int(text[2:].translate(_SUPERSCRIPT))
    return int(text)


def _documented(path: pathlib.Path) -> dict[str, tuple[list[int], list[int]]]:
    """The preset's table of a doc, ``| W1 | particles N | 10⁶, 10⁷, 10⁸ | 10³, 10⁴, 10⁵ |``: workload →
    (sizes, sizes with ``--scale-down``) of the axis the preset scales."""
    out = {}
    lines = path.read_text().splitlines()
    start = lines.index("| workload | size axis | sizes | with `--scale-down` |")
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        m = re.fullmatch(r"\| (\w+) \| [^|]+ \| ([^|]+) \| ([^|]+) \|", line.strip())
        out[m[1]] = tuple([_number(v) for v in m[k].split(", ")] for k in (2, 3))
    return out


def _axis(plan: dict, name: str) -> list[int]:
    return [size[GPU.scaled[name]] for size in plan[name]]


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_the_plan_is_the_one_the_docs_give(doc):
    documented = _documented(doc)
    full, small = GPU.plan(), GPU.plan(scale_down=True)
    assert list(documented) == list(full) == ["W1", "W2", "W2b", "W5", "S2"]
    for name in full:
        assert documented[name] == (_axis(full, name), _axis(small, name)), name
    discover()
    for name, sizes in full.items():  # every size names the keys its workload reads
        assert all(set(size) == set(REGISTRY[name].sizes[0]) for size in sizes), name
    assert GPU.budget_s == 480.0  # 8 minutes, what the docs promise on one H200
    assert not GPU.implementations & {"numpy", "filterpy", "particles"}  # host-CPU peers are left out


def test_scale_down_divides_every_size_by_the_factor():
    full, small = GPU.plan(), GPU.plan(scale_down=True)
    assert GPU.scale_factor == 1000
    for name, sizes in full.items():
        key = GPU.scaled[name]
        expected: list[dict] = []
        for size in sizes:
            divided = dict(size, **{key: max(GPU.minimum[name], round(size[key] / GPU.scale_factor))})
            if divided not in expected:
                expected.append(divided)
        assert small[name] == expected, name
    assert _axis(small, "W1") == [10**3, 10**4, 10**5]
    assert small["S2"] == [{"robot_particles": 500, "tags": 10}, {"robot_particles": 500, "tags": 100}]


def _tiny_workload(calls: list) -> Workload:
    def run_size(ctx, size):
        calls.append(size["n"])
        rows = []
        for impl in ("jaxnav", "numpy"):  # the preset measures jaxnav only
            rows += harness.guarded(
                ctx,
                "ZZ",
                impl,
                size,
                "per_call",
                lambda impl=impl: harness.make_row(
                    "ZZ", impl, size, "per_call", median_s=1e-6 * size["n"], floor_s=ctx.floor(8 * size["n"])
                ),
            )
        return rows

    return Workload("ZZ", "a fake workload", [{"n": 1}], run_size, "n")


@pytest.fixture
def tiny_preset(monkeypatch):
    """The ``gpu`` preset replaced by one fake workload; bandwidths measured quickly (a small device array)."""
    calls: list = []
    tiny = Preset(
        name="gpu",
        sizes={"ZZ": [{"n": 1000}, {"n": 3000}, {"n": 10_000}]},
        scaled={"ZZ": "n"},
        minimum={"ZZ": 2},
        implementations=frozenset({"jaxnav"}),
        budget_s=480.0,
        scale_factor=1000,
    )
    monkeypatch.setitem(run.PRESETS, "gpu", tiny)
    monkeypatch.setattr(run, "discover", lambda: {"ZZ": _tiny_workload(calls)})
    monkeypatch.setattr(
        harness, "measure_bandwidth", lambda: {"bandwidth_bytes_per_s": 1e10, "bandwidth_GB_per_s": 10.0}
    )
    monkeypatch.setattr(
        harness, "measure_device_bandwidth", functools.partial(harness.measure_device_bandwidth, 4 * 2**20, 3)
    )
    return calls


def test_a_tiny_scaled_run_writes_the_device_and_the_scaling(tmp_path, tiny_preset):
    from benchmarks.markdown import tables
    from benchmarks.plot import machine_line

    out = tmp_path / "gpu.json"
    assert run.main(["--preset", "gpu", "--scale-down", "--out", str(out), "--no-plot", "--retries", "0"]) == 0
    payload = json.loads(out.read_text())
    device = payload["machine"]["device"]
    assert device["kind"] == jax.devices()[0].device_kind and device["platform"] == jax.devices()[0].platform
    assert device["bandwidth_GB_per_s"] > 0 and device["reduce_GB_per_s"] > 0
    assert device["method"].startswith("measured: jitted x + 1")
    assert "memory_bytes" in device  # None where the backend reports none (XLA:CPU)
    opts = payload["options"]
    assert (opts["preset"], opts["scale_down"], opts["scale_factor"], opts["budget_s"]) == ("gpu", True, 1000, 480.0)
    assert opts["plan"] == {"ZZ": [{"n": 2}, {"n": 3}, {"n": 10}]}  # 1000 / 1000 raised to the minimum, 2
    assert payload["complete"] and tiny_preset == [2, 3, 10]
    rows = payload["rows"]
    assert [(r["implementation"], r["size"]["n"]) for r in rows] == [("jaxnav", 2), ("jaxnav", 3), ("jaxnav", 10)]
    for r in rows:  # floors from the device's measured bandwidth, not the host's stub
        assert r["floor_s"] == pytest.approx(8 * r["size"]["n"] / device["bandwidth_bytes_per_s"])
    line = machine_line(payload)
    assert device["kind"] in line and "measured bandwidth" in line and line.endswith("sizes ÷ 1000")
    assert f"Device: {line}" in tables(payload)

    assert run.main(["--preset", "gpu", "--out", str(out), "--no-plot", "--retries", "0"]) == 0
    payload = json.loads(out.read_text())
    assert payload["options"]["scale_factor"] == 1 and payload["options"]["scale_down"] is False
    assert [r["size"]["n"] for r in payload["rows"]] == [1000, 3000, 10_000]


def test_the_run_budget_stops_sizes_from_starting(tmp_path, tiny_preset):
    assert run.budget_reason(None, 1e9, 1e9) is None
    assert run.budget_reason(480.0, 100.0, 300.0) is None
    assert "previous size took 400 s" in run.budget_reason(480.0, 100.0, 400.0)
    assert "480 s spent" in run.budget_reason(480.0, 480.0, 0.0)
    out = tmp_path / "gpu.json"
    assert run.main(["--preset", "gpu", "--budget", "0", "--out", str(out), "--no-plot", "--retries", "0"]) == 0
    payload = json.loads(out.read_text())
    assert tiny_preset == [] and payload["options"]["budget_s"] == 0.0
    assert [r["skipped"].startswith("run budget") for r in payload["rows"]] == [True] * 3
    assert any("run budget" in n for n in payload["notes"])


def test_the_preset_options_that_do_not_go_together(capsys):
    assert run.main(["--scale-down", "--no-plot"]) == 2
    assert run.main(["--preset", "gpu", "--quick", "--no-plot"]) == 2
    assert "--scale-down needs --preset" in capsys.readouterr().err
