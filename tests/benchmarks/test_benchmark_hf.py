"""HF-RFID SLAM benchmark workloads S1, S2, W5 (benchmarks/workloads/{s1_hf_particles,s2_hf_map_size,w5_monte_carlo}.py).

Sanity only — no timing is asserted (a time is compared only with another
measured in the same run):

* each workload, run at its smallest size on a short trajectory, returns rows
  in the harness's row format (``workload, implementation, size,
  mode, median_s, compile_s`` plus ``method``; S1 also ``setting``) with
  positive, finite times;
* the S2 world is what its docstring states: with the HF reader model of
  [W] eq. 3.7 (strictly inside the square footprint) exactly the four
  corner readers detect, each exactly the tag the detections name, and
  integrating the odometry gives the true poses (so the filter is fed a
  consistent trajectory); the prefilled PF/PS-SLAM tables hold every tag as
  already mapped, near its true position; a negative control shows the
  geometry check can fail (a robot shifted by 1.5 reader half-widths is
  seen by other readers);
* the S2 ratio t(largest)/t(10) is computed per method and mode;
* the plot functions draw S1/S2/W5 rows.

Every jitted function takes seconds to compile, so each test
compiles one or two configurations only (FastSLAM, the quickest to compile,
for the S1 modes; PF-SLAM for S2; W5 on a small setting).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from benchmarks.harness import Context
from benchmarks.workloads import s1_hf_particles as s1
from benchmarks.workloads import s2_hf_map_size as s2
from benchmarks.workloads import w5_monte_carlo as w5

REQUIRED = ("workload", "implementation", "size", "mode", "median_s", "compile_s", "method")


def _ctx():
    return Context(quick=True, repeats=1, bandwidth=1e10, retries=0)


def _check_rows(rows, workload, size_keys, modes, methods):
    assert {(r["method"], r["mode"]) for r in rows} == {(m, mo) for m in methods for mo in modes}
    for r in rows:
        assert "skipped" not in r, r.get("skipped")
        for k in REQUIRED:
            assert k in r, k
        assert r["workload"] == workload and r["implementation"] == "jaxnav"
        assert set(r["size"]) == set(size_keys)
        assert math.isfinite(r["median_s"]) and r["median_s"] > 0
        assert math.isfinite(r["compile_s"]) and r["compile_s"] > 0
        assert r["min_s"] <= r["median_s"]


def test_s1_rows_smallest_size():
    """S1 at I = 100 on the fig4.1a carpet (42 tags): a per_call and an in_scan row with the settings' metadata."""
    size = {"robot_particles": 100, "tags": 42}
    assert s1.setting_for_tags(42) == "fig4.1a" and s1.setting_for_tags(806) == "fig3.6"
    rows = s1.run_rows(_ctx(), size, methods=("fastslam",), steps=30)
    _check_rows(rows, "S1", ("robot_particles", "tags"), ("per_call", "in_scan"), ("fastslam",))
    for r in rows:
        assert r["setting"] == "fig4.1a" and r["reader_side_m"] == 0.3 and r["density_tags_per_m2"] == 4.0
        assert 0 < r["detections_per_step"] <= r["slots"]
    scan = next(r for r in rows if r["mode"] == "in_scan")
    assert scan["steps"] == 30
    # S1's sizes: both settings, all particle counts; quick: the two smallest of each
    from benchmarks.workloads import REGISTRY

    sizes = REGISTRY["S1"].sizes_for(False)
    assert sorted({x["tags"] for x in sizes}) == [42, 806]
    assert sorted({x["robot_particles"] for x in sizes}) == list(s1.PARTICLES)
    assert sorted({x["robot_particles"] for x in REGISTRY["S1"].sizes_for(True)}) == [100, 250]


def _detected(w, t):
    """(reader, tag) pairs strictly inside a reader footprint at true pose t ([W] eq. 3.7 'inside'), θ = 0."""
    sensor = s2.sensor()
    pos, off, hw = np.asarray(w.positions), np.asarray(sensor.offsets), float(sensor.half_width)
    pose = np.asarray(w.true_poses[t])
    assert pose[2] == 0.0
    e = pos[None] - pose[None, None, :2] - off[:, None]
    readers, tags = np.nonzero(np.all(np.abs(e) < hw, axis=-1))
    return sorted(zip(readers.tolist(), tags.tolist()))


@pytest.mark.parametrize("n", [10, 100, 1000])
def test_s2_world_has_exactly_the_stated_detections(n):
    w = s2.make_world(n, t=40)
    nx, ny = s2.lattice_shape(n)
    assert nx * ny == n and ny >= 2 and ny <= math.isqrt(n)
    det = w.detections
    assert det.ids.shape == (40, 4) and bool(det.mask.all())
    for t in range(40):
        named = sorted(zip(np.asarray(det.readers[t]).tolist(), np.asarray(det.ids[t]).tolist()))
        assert _detected(w, t) == named
    assert len(np.unique(np.asarray(det.ids))) > 4  # the robot moves over the map
    # the odometry integrates to the true poses (omni model, noise-free)
    u = np.asarray(w.controls, np.float64)
    poses = np.asarray(w.start_pose, np.float64) + np.cumsum(u[:, :3] * u[:, 3:], axis=0)
    np.testing.assert_allclose(poses, np.asarray(w.true_poses), atol=1e-4)  # float32 positions ≤ 72 m


def test_s2_geometry_check_can_fail():
    """Negative control: the robot shifted by 45 mm in x (1.5 half-widths) sees other tags with other readers."""
    w = s2.make_world(100, t=5)
    shifted = s2.S2World(w.positions, w.start_pose, w.controls, w.detections, w.true_poses.at[:, 0].add(0.045))
    named = sorted(zip(np.asarray(w.detections.readers[0]).tolist(), np.asarray(w.detections.ids[0]).tolist()))
    assert _detected(shifted, 0) != named


@pytest.mark.parametrize("method", ["pf_slam", "ps_slam"])
def test_s2_prefilled_table(method):
    w = s2.make_world(100, t=5)
    module, config, params = s1.filter_setup(method, 50, 100, s2.sensor(), s2.motion(), lag=4, tag_particles=20)
    state = s2.prefilled_state(method, module, config, params, w)
    tags = state.tags
    assert tags.particles.shape == (100, 20, 2) and state.poses.shape == (50, 3)
    assert bool(jnp.all(tags.counts > 0))
    np.testing.assert_allclose(np.asarray(tags.estimates), np.asarray(w.positions), atol=5 * s2.TAG_SD / math.sqrt(20))
    np.testing.assert_allclose(np.asarray(jax.scipy.special.logsumexp(tags.log_weights, axis=1)), 0.0, atol=1e-5)
    if method == "ps_slam":
        assert tags.history.shape == (100, 4, 20, 2)
        np.testing.assert_array_equal(np.asarray(tags.history[:, -1]), np.asarray(tags.particles))


def test_s2_rows_smallest_size_and_ratio():
    size = {"robot_particles": 500, "tags": 10}
    s2._MEDIANS.clear()
    rows = s2.run_rows(_ctx(), size, methods=("pf_slam",), modes=("per_call", "in_scan"), steps=20)
    _check_rows(rows, "S2", ("robot_particles", "tags"), ("per_call", "in_scan"), ("pf_slam",))
    assert all(r["ratio_to_10_tags"] == 1.0 and r["detections_per_step"] == 4 for r in rows)
    scan = next(r for r in rows if r["mode"] == "in_scan")
    assert "jitted_donated" in scan["note"] and scan["steps"] == 20 and scan["state_bytes"] > 0
    # the public call checks the fresh state as well: timed apart, once per call
    assert scan["public_call_s"] > 0
    fake = [
        dict(workload="S2", method="pf_slam", mode="per_call", size={"tags": n}, median_s=v)
        for n, v in ((10, 2e-3), (1000, 2.2e-3), (100_000, 2.4e-3))
    ]
    notes = s2.ratio_notes(fake)
    assert notes == ["S2 pf_slam per_call: t(100000)/t(10) = 1.20 (target ≤ 1.5)"]


def test_s2_state_size_and_copy_helpers():
    state = {"a": jnp.zeros((10, 3), jnp.float32), "b": jnp.zeros((4,), jnp.int32)}
    assert s2._nbytes(state) == 10 * 3 * 4 + 4 * 4
    assert s2._copy_time(state) > 0


def test_w5_rows_one_run_small_setting():
    """W5 at R = 1 on a small setting (one lap, 50 robot and 20 tag particles): a row in the interface format."""
    from jaxnav.experiments.hf_slam import HFSetting

    small = HFSetting(density=4.0, laps=1, robot_particles=50, tag_particles=20)
    rows = w5.run_rows(_ctx(), {"runs": 1}, s=small)
    assert len(rows) == 1
    r = rows[0]
    assert "skipped" not in r, r.get("skipped")
    for k in REQUIRED:
        assert k in r
    assert r["workload"] == "W5" and r["size"] == {"runs": 1} and r["method"] == "pf_slam"
    assert r["median_s"] > 0 and r["compile_s"] > 0 and r["call_s"] == pytest.approx(r["median_s"])
    assert r["finite_runs"] == 1 and math.isfinite(r["mean_dr_mm"]) and r["mean_dr_mm"] >= 0


def test_plots_draw_the_hf_workloads(tmp_path):
    pytest.importorskip("matplotlib")
    from benchmarks.plot import plot_all

    rows = []
    for setting, tags in (("fig3.6", 806), ("fig4.1a", 42)):
        for i in (100, 250):
            for method in s1.METHODS:
                for mode in ("per_call", "in_scan"):
                    rows.append(
                        dict(
                            workload="S1",
                            implementation="jaxnav",
                            size={"robot_particles": i, "tags": tags},
                            mode=mode,
                            median_s=1e-5 * i,
                            method=method,
                            setting=setting,
                            density_tags_per_m2=4.0,
                            reader_side_m=0.3,
                        )
                    )
    for n in (10, 1000):
        for method in s1.METHODS:
            rows.append(
                dict(
                    workload="S2",
                    implementation="jaxnav",
                    size={"robot_particles": 500, "tags": n},
                    mode="per_call",
                    median_s=1e-3 * (1 + n / 1000),
                    method=method,
                )
            )
    for r in (1, 10):
        rows.append(
            dict(
                workload="W5",
                implementation="jaxnav",
                size={"runs": r},
                mode="per_call",
                median_s=1.0 / r,
                compile_s=20.0,
                method="pf_slam",
            )
        )
    from benchmarks.workloads import discover

    out = plot_all({"machine": {}, "rows": rows}, str(tmp_path / "hf.json"), discover())
    assert sorted(p.rsplit("_", 1)[1] for p in out) == ["S1.png", "S2.png", "W5.png"]
    assert all((tmp_path / p.rsplit("/", 1)[1]).stat().st_size > 1000 for p in out)
