"""W4 kf-batch benchmark (benchmarks/workloads/w4_kf_batch.py): every implementation is the same filter.

On a small batch (B = 3 sequences of T = 40 steps, seed 1) each
implementation timed by the benchmark — jaxnav's ``kalman_predict`` +
``kalman_update`` under ``vmap``/``scan``, the batched NumPy peer, filterpy's ``KalmanFilter`` and dynamax's
``lgssm_filter`` (when installed) — must return the same filtered means and
per-sequence log-likelihoods. filterpy (float64, Joseph form, its own
``log_likelihood``) is the reference. No timing is asserted.

Tolerances:

* float64, jaxnav / NumPy: the same algorithm in a different
  association order, so agreement is at rounding level; 1e-9 (relative to
  the size of the means, ~10 m, and of the log-likelihoods, ~10) is
  ≈ 1e5 ulp, the bound ``tests/core/test_kalman.py`` uses for the same model.
* float64, dynamax: its ``psd_solve`` adds ``diagonal_boost = 1e-9`` to
  ``S`` before solving, a relative perturbation ≤ 1e-9 / λmin(S) = 1e-9 /
  0.04 = 2.5e-8 of the gain per step (λmin(S) ≥ λmin(R) = 0.2² m²); the
  bounds 1e-6 m (means) and 1e-5 (log-likelihood, a sum over 40 steps)
  leave a factor ≥ 10 over that.
* float32: 1e-4 relative, as in ``tests/core/test_kalman.py`` for the
  float32 Kalman filters on this model.

The benchmark times jaxnav, dynamax and NumPy in both float32 and float64;
:func:`test_rows_float32_and_float64` runs the workload once at B = 1 and
checks that every row is there once per dtype, that the float64 rows have the
float64 floor, and that ``jax_enable_x64`` is left as it was.

A negative control shows the comparison can fail: the NumPy filter with
R scaled by 1.1 disagrees with the reference far beyond these tolerances.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from benchmarks.peers.numpy_kf import numpy_kf_batch
from benchmarks.workloads import w4_kf_batch as w4

B, T, SEED = 3, 40, 1


@pytest.fixture(scope="module")
def inputs():
    return w4.make_inputs(B, T, seed=SEED)


@pytest.fixture(scope="module")
def reference(inputs):
    pytest.importorskip("filterpy.kalman")
    from benchmarks.peers.numpy_kf import filterpy_kf

    means, ll = filterpy_kf(inputs.m0, inputs.p0, inputs.zs, *w4.model())
    assert means.shape == (B, T, 4) and ll.shape == (B,)
    return means, ll


def _jax_filters():
    out = [("jaxnav", w4.jaxnav_filter())]
    fn, _ = w4.dynamax_filter()
    if fn is not None:
        out.append(("dynamax", fn))
    return out


def test_inputs_are_seeded_and_shaped():
    a = w4.make_inputs(4, 10, seed=3)
    b = w4.make_inputs(4, 10, seed=3)
    c = w4.make_inputs(4, 10, seed=4)
    assert a.m0.shape == (4, 4) and a.p0.shape == (4, 4, 4) and a.zs.shape == (4, 10, 2) and a.xs.shape == (4, 10, 4)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    assert not np.allclose(a.zs, c.zs)
    # per-sequence initial covariances differ (no shared Riccati recursion across the batch)
    assert len({float(p[0, 0]) for p in a.p0}) == 4
    assert w4.floor_bytes(1000) == 1000 * 4 * (6 * w4.T + 21)


def test_float64_all_implementations_agree(inputs, reference):
    ref_m, ref_ll = reference
    m, ll = numpy_kf_batch(inputs.m0, inputs.p0, inputs.zs, *w4.model(), dtype=np.float64)
    np.testing.assert_allclose(m, ref_m, rtol=0, atol=1e-9 * np.abs(ref_m).max())
    np.testing.assert_allclose(ll, ref_ll, rtol=1e-9, atol=1e-9)
    with jax.enable_x64(True):
        args = w4.jax_args(inputs, jnp.float64)
        for name, fn in _jax_filters():
            m, ll = (np.asarray(x) for x in fn(*args))
            assert m.dtype == np.float64, name
            if name == "dynamax":
                np.testing.assert_allclose(m, ref_m, rtol=0, atol=1e-6, err_msg=name)
                np.testing.assert_allclose(ll, ref_ll, rtol=0, atol=1e-5, err_msg=name)
            else:
                np.testing.assert_allclose(m, ref_m, rtol=0, atol=1e-9 * np.abs(ref_m).max(), err_msg=name)
                np.testing.assert_allclose(ll, ref_ll, rtol=1e-9, atol=1e-9, err_msg=name)


def test_float32_as_benchmarked_agrees(inputs, reference):
    ref_m, ref_ll = reference
    scale_m = np.abs(ref_m).max()
    m, ll = numpy_kf_batch(inputs.m0, inputs.p0, inputs.zs, *w4.model())
    assert m.dtype == np.float32
    np.testing.assert_allclose(m, ref_m, rtol=0, atol=1e-4 * scale_m)
    np.testing.assert_allclose(ll, ref_ll, rtol=1e-4, atol=1e-4)
    args = w4.jax_args(inputs)
    for name, fn in _jax_filters():
        if name == "dynamax":
            continue  # its float64 agreement above is the check; skip a second compile
        m, ll = (np.asarray(x) for x in fn(*args))
        assert m.dtype == np.float32, name
        np.testing.assert_allclose(m, ref_m, rtol=0, atol=1e-4 * scale_m, err_msg=name)
        np.testing.assert_allclose(ll, ref_ll, rtol=1e-4, atol=1e-4, err_msg=name)


def test_negative_control_wrong_noise_is_detected(inputs, reference):
    ref_m, ref_ll = reference
    a, q, c, r = w4.model()
    m, ll = numpy_kf_batch(inputs.m0, inputs.p0, inputs.zs, a, q, c, 1.1 * r, dtype=np.float64)
    assert np.max(np.abs(ll - ref_ll)) > 1e3 * 1e-5
    assert np.max(np.abs(m - ref_m)) > 1e3 * 1e-6


def test_rows_float32_and_float64():
    from benchmarks.harness import Context

    ctx = Context(quick=True, repeats=1, bandwidth=1e10, retries=0)
    x64_before = bool(jax.config.jax_enable_x64)
    rows = w4.run(ctx, {"B": 1, "T": w4.T})
    assert bool(jax.config.jax_enable_x64) == x64_before
    keys = [(r["implementation"], r["dtype"]) for r in rows]
    expected = {("jaxnav", d) for d in w4.DTYPES} | {("numpy", d) for d in w4.DTYPES}
    expected |= {("dynamax", d) for d in w4.DTYPES} | {("filterpy", "float64")}
    assert sorted(keys) == sorted(expected)
    for r in rows:
        if r.get("median_s") is None:  # an optional peer that is not installed
            assert r["implementation"] in ("dynamax", "filterpy") and "skipped" in r, r
            continue
        nbytes = np.dtype(r["dtype"]).itemsize
        assert r["floor_s"] == pytest.approx(w4.floor_bytes(1, nbytes=nbytes) / 1e10)
    jaxnav = {r["dtype"]: r for r in rows if r["implementation"] == "jaxnav"}
    assert jaxnav["float32"]["median_s"] > 0 and jaxnav["float64"]["median_s"] > 0
    assert jaxnav["float64"]["compile_s"] > 0 and jaxnav["float32"]["compile_s"] > 0
