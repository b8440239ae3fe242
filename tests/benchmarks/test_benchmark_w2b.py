"""W2b mcl-batch benchmark (benchmarks/workloads/w2b_mcl_batch.py): the batched filters are R separate filters.

* The NumPy batch peer's resampling (one ``searchsorted`` over the
  row-shifted cumulative sums of all rows) gives, row by row, exactly the
  ancestors of :class:`benchmarks.peers.numpy_mcl.NumpyMCL`'s per-row
  systematic resampling with the same uniform, including the edge cases: a
  uniform of 0 and one just below 1, a row whose float32 sum stops short of 1
  (points past its last sum take the last particle), a row whose sum
  overshoots 1, and rows whose first particles have zero weight.
* Its motion (noise switched off) and its per-row weighting, normalisation
  and ESS equal NumpyMCL's run by run, to float32 rounding (poses 1e-6 m, a
  few ulp at 5 m, in case NumPy's SIMD ``cos``/``sin`` treat an array's tail
  differently; weights 1e-6 relative: the batch normalises with a per-row
  array, NumpyMCL with a scalar, a difference of an ulp or two).
* Rows stay independent: changing one run's observations (NumPy peer,
  jaxnav) changes only that run's particles, bit for bit.
* jaxnav's batched run (``batch.compiled_vmap`` of ``mcl.run.jitted``) equals R
  separate ``mcl.run`` calls with the same keys, data and initial states
  (float32; 1e-5 m allows for XLA compiling the vmapped program with another
  association order; measured: bit-identical).
* ``python -m benchmarks.run --only W2b`` writes rows in the harness's row
  format (sizes made small).

No timing is asserted. The batched jaxnav program is slow to compile, so
the tests share one configuration (R = 3, N = 32), compiled once per process.
"""

from __future__ import annotations

import dataclasses
import json
import math

import jax
import numpy as np
import pytest

from benchmarks.peers.numpy_mcl import NumpyMCL
from benchmarks.peers.numpy_mcl_batch import NumpyMCLBatch, normalise_rows
from benchmarks.workloads import w2_mcl as w2
from benchmarks.workloads import w2b_mcl_batch as w2b

R, N = 3, 32


class _FixedUniform:
    """Stand-in generator whose ``random()`` returns one given uniform (NumpyMCL's resampling draw)."""

    def __init__(self, u):
        self.u = u

    def random(self):
        return self.u


def _per_row_indices(w, u):
    """NumpyMCL's systematic resampling of each row of ``w`` with the uniform ``u[r]``."""
    r, n = w.shape
    pf = NumpyMCL(np.zeros((n, 3), np.float32), np.zeros((2, 2)), (0, 0, 0), (1, 1))
    out = []
    for i in range(r):
        pf.rng = _FixedUniform(u[i])
        out.append(pf.indices(w[i]))
    return np.stack(out)


def _weights(rng, r, n):
    """``[R, N]`` float32 probabilities with edge cases in the first rows, normalised in float32."""
    w = rng.gamma(0.3, size=(r, n)).astype(np.float32)
    w[0, :5] = 0.0  # leading zero weights
    w[1] = 0.0
    w[1, n // 2] = 1.0  # one particle takes everything
    w[2, -3:] = 0.0  # trailing zeros: the last points fall past the last non-zero sum
    w /= w.sum(axis=1, keepdims=True)
    w[3] *= np.float32(1.0 - 3e-7)  # a sum that stops short of 1
    w[4] *= np.float32(1.0 + 3e-7)  # a sum that overshoots 1
    return w


def test_batch_resampling_equals_numpy_mcl_per_row():
    rng = np.random.default_rng(0)
    r, n = 40, 257
    pf = NumpyMCLBatch(np.zeros((r, n, 3), np.float32), np.zeros((2, 2)), (0, 0, 0), (1, 1))
    for trial in range(20):
        w = _weights(rng, r, n)
        u = rng.random(r)
        u[:2] = (0.0, np.nextafter(1.0, 0.0))
        if trial % 2:
            u = np.sort(u)[::-1].copy()  # order of the uniforms across rows must not matter
        got = pf.indices(w, u)
        assert np.all(np.diff(pf.cdf64.ravel()) >= 0)  # the row-shifted sums, concatenated, are sorted
        assert got.shape == (r, n) and got.min() >= 0 and got.max() <= n - 1
        np.testing.assert_array_equal(got, _per_row_indices(w, u))
        flat = pf.resample_flat(w, u)
        np.testing.assert_array_equal(flat, got + n * np.arange(r)[:, None])
    # negative control: another row's uniform gives other ancestors
    u2 = u.copy()
    u2[5] = (u2[5] + 0.5) % 1.0
    assert not np.array_equal(pf.indices(w, u2)[5], _per_row_indices(w, u)[5])


def test_batch_gather_moves_each_row_within_itself():
    rng = np.random.default_rng(1)
    r, n = 6, 50
    x0 = rng.standard_normal((r, n, 3)).astype(np.float32)
    pf = NumpyMCLBatch(x0, np.zeros((2, 2)), (0, 0, 0), (1, 1))
    w = _weights(rng, r, n)
    u = rng.random(r)
    idx = pf.indices(w, u)
    pf.resample(pf.resample_flat(w, u))
    np.testing.assert_array_equal(pf.particles, np.take_along_axis(x0, idx[:, :, None], axis=1))
    np.testing.assert_array_equal(pf.lw, np.full((r, n), -math.log(n), np.float32))


def _peer_data(r=R, n=N):
    x0, lm, controls, zs = w2b.peer_inputs(r, n)
    assert x0.shape == (r, n, 3) and controls.shape == (r, w2b.T, 3) and zs.shape == (r, w2b.T, lm.shape[0], 2)
    return x0, lm, controls, zs


def test_batch_motion_and_weights_equal_numpy_mcl_per_run():
    x0, lm, controls, zs = _peer_data()
    batch = NumpyMCLBatch(x0, lm, (0, 0, 0), w2.SENSOR_SD)  # no motion noise: deterministic moves
    singles = [NumpyMCL(x0[i], lm, (0, 0, 0), w2.SENSOR_SD) for i in range(R)]
    for t in range(3):
        batch.move(controls[:, t])
        w, log_norm, ess = batch.weigh(zs[:, t])
        for i, pf in enumerate(singles):
            pf.move(controls[i, t])
            np.testing.assert_allclose(batch.p[:, i], np.stack([pf.x, pf.y, pf.th]), rtol=0, atol=1e-6)
            wi, log_norm_i, ess_i = pf.weigh(zs[i, t])
            np.testing.assert_allclose(w[i], wi, rtol=1e-6, atol=1e-12)
            np.testing.assert_allclose(log_norm[i], log_norm_i, rtol=1e-6)
            np.testing.assert_allclose(ess[i], ess_i, rtol=1e-6)
            assert 1.0 <= ess[i] <= N
        batch.lw.fill(-math.log(N))
        for pf in singles:
            pf.lw.fill(-math.log(N))
    # the row normaliser alone: probabilities sum to 1 per row, ESS of uniform weights is N
    lw = np.zeros((2, 8), np.float32)
    lw[1, 0] = -np.inf
    p, ln, e = normalise_rows(lw)
    np.testing.assert_allclose(p.sum(axis=1), 1.0, rtol=1e-6)
    np.testing.assert_allclose(e, [8.0, 7.0], rtol=1e-6)
    np.testing.assert_allclose(ln, [math.log(8), math.log(7)], rtol=1e-6)


def test_numpy_rows_stay_independent():
    x0, lm, controls, zs = _peer_data()
    j = 1
    zs2 = zs.copy()
    zs2[j, :, :, 0] += 0.3  # run j's ranges change
    runs = []
    for z in (zs, zs2):
        pf = NumpyMCLBatch(x0, lm, w2.POSE_SD, w2.SENSOR_SD, seed=3)
        for t in range(10):
            pf.step(controls[:, t], z[:, t])
        runs.append(pf.particles)
    a, b = runs
    for i in range(R):
        if i == j:
            assert not np.array_equal(a[i], b[i])
        else:
            np.testing.assert_array_equal(a[i], b[i])


def test_jaxnav_batched_run_equals_separate_runs_and_rows_stay_independent():
    from jaxnav.core import batch
    from jaxnav.localization import mcl

    run_all, compile_s = w2b.jaxnav_batched(R, N)
    assert compile_s is None
    final, trace = jax.block_until_ready(run_all())
    assert final.particles.shape == (R, N, 3) and trace.estimate.shape == (R, w2b.T, 3)

    _, _, _, sims = w2b.runs_world(R)
    states = w2b.initial_states(R, N)
    keys = w2b.fold_in_keys(2, R)
    config, params = w2._config_params(N)
    for i in range(R):
        row = lambda tree, i=i: jax.tree_util.tree_map(lambda a: a[i], tree)
        f_i, tr_i = mcl.run(keys[i], row(states), config, params, sims.controls[i], row(sims.observations))
        np.testing.assert_allclose(np.asarray(final.particles[i]), np.asarray(f_i.particles), rtol=0, atol=1e-5)
        np.testing.assert_allclose(np.asarray(final.log_weights[i]), np.asarray(f_i.log_weights), atol=1e-5)
        np.testing.assert_allclose(np.asarray(trace.estimate[i]), np.asarray(tr_i.estimate), rtol=0, atol=1e-5)
        np.testing.assert_allclose(
            np.asarray(trace.log_likelihood[i]), np.asarray(tr_i.log_likelihood), rtol=1e-5, atol=1e-5
        )
    # the runs differ from each other (own data and keys)
    assert not np.allclose(np.asarray(final.particles[0]), np.asarray(final.particles[1]))

    # changing run j's observations changes only run j (same compiled program)
    j = 2
    obs = sims.observations
    obs2 = obs._replace(z=obs.z.at[j, :, :, 0].add(0.3))
    args = (keys, states, sims.controls, obs2)
    exe = batch.compiled_vmap(w2b.run_one(N), *args, shared=(params,))
    final2, _ = exe(*args, params)
    for i in range(R):
        same = np.array_equal(np.asarray(final.particles[i]), np.asarray(final2.particles[i]))
        assert same == (i != j), i


def test_floor_and_sizes():
    from benchmarks.workloads import REGISTRY

    assert w2b.floor_bytes(100, 1000) == 100 * w2.floor_bytes(1000) == 60 * 100 * 1000
    wl = REGISTRY["W2b"]
    assert wl.sizes_for(False) == [{"R": 10, "N": 1000}, {"R": 100, "N": 1000}]
    assert wl.sizes_for(True) == wl.sizes_for(False)


@pytest.mark.slow
def test_runner_writes_w2b_rows(tmp_path, monkeypatch):
    """``python -m benchmarks.run --only W2b --quick`` with the sizes made small: one row per implementation."""
    from benchmarks import harness, run
    from benchmarks.workloads import REGISTRY

    small = dataclasses.replace(REGISTRY["W2b"], sizes=[{"R": R, "N": N}])
    registry = dict(run.discover())
    registry["W2b"] = small
    monkeypatch.setattr(run, "discover", lambda: registry)
    monkeypatch.setattr(
        harness, "measure_bandwidth", lambda: {"bandwidth_bytes_per_s": 1e10, "bandwidth_GB_per_s": 10.0}
    )
    out = tmp_path / "w2b.json"
    args = ["--only", "W2b", "--quick", "--no-plot", "--retries", "0", "--repeats", "1", "--out", str(out)]
    assert run.main(args) == 0
    payload = json.loads(out.read_text())
    assert payload["complete"] is True and "W2b" in payload["workloads"]
    rows = payload["rows"]
    impls = {(r["implementation"], r["mode"]) for r in rows}
    assert {
        ("jaxnav", "in_scan"),
        ("jaxnav-plain", "in_scan"),
        ("numpy", "per_call"),
        ("particles", "per_call"),
    } == impls
    floor = w2b.floor_bytes(R, N) / 1e10
    for r in rows:
        for k in ("workload", "implementation", "size", "mode", "median_s"):
            assert k in r, k
        assert r["workload"] == "W2b" and r["size"] == {"R": R, "N": N}
        if r["implementation"] == "particles" and r.get("skipped"):
            assert "not importable" in r["skipped"]
            continue
        assert "skipped" not in r, r.get("skipped")
        assert math.isfinite(r["median_s"]) and r["median_s"] > 0
        assert r["floor_s"] == pytest.approx(floor)
        assert r["ratio_to_floor"] == pytest.approx(r["median_s"] / floor)
        assert "ratio_to_fastest_peer" in r
    jaxnav_row = next(r for r in rows if r["implementation"] == "jaxnav")
    assert jaxnav_row["compile_s"] >= 0 and jaxnav_row["steps"] == w2b.T
