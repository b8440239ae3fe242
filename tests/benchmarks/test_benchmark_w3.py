"""W3 fastslam-step benchmark (benchmarks/workloads/w3_fastslam.py): every implementation is the same filter.

Given the same particles (poses, log-weights, per-particle maps), the same
control and observations, and the same resampling uniform, the NumPy peer
(:class:`benchmarks.peers.numpy_fastslam.NumpyFastSLAM`) and
``jaxnav.slam.fastslam.step`` must return the same poses, landmark means and
covariances, log-weights, log-likelihood increment and ESS. The motion noise
is switched off (sd 0) so that the motion is deterministic and the two
implementations' random streams do not matter; the resampling uniform of
jaxnav is recomputed from its key (the split chain of ``fastslam.kernel`` and
``resampling.conditional_resample``). The small case has M = 40 particles,
N = 12 landmarks, different maps in every particle (means and SPD
covariances drawn per particle), non-uniform prior log-weights and K = 5
slots with one landmark observed twice (applied in turn by both). The
in-place resampling copy of the maps
(:func:`jaxnav.core.resampling.copy_ancestors_in_place`, what
``fastslam.step`` uses for W3's large maps) must equal the gather for sorted
ancestors. No timing is asserted.

Tolerances:

* float64: the same arithmetic in a different association order (closed-form
  2 × 2 inverse in NumPy, Cholesky solves in jaxnav), so agreement is at
  rounding level; 1e-9 (relative to means ~10 m, covariances ~1e-2 m²,
  log-weights ~10) is ≈ 1e5 ulp, the bound ``tests/benchmarks/test_benchmark_w4.py``
  uses for the same kind of comparison.
* float32 (what the benchmark times): agreement to a few ulp of the
  largest magnitudes involved, with a margin of ~10: log-weights 2e-4
  (≈ 100 ulp of |log w| ≤ 20; the 5 Mahalanobis terms are built from
  residuals ``z − ẑ`` that are differences of ~5 m quantities and so carry
  a few ulp(5 m) of absolute error each), means 1e-5 m (≈ 10 ulp at 10 m),
  covariances 1e-5 relative to the largest entry (≈ 100 ulp), poses 1e-6 m
  (≈ 2 ulp at 8 m; fastmath's float32 ``sincos``/``atan2`` are within a few
  ulp of NumPy's). Measured on this case: 1.9e-5, 9.5e-7 m, 7e-8, 1.2e-7 m.

A negative control shows the comparison can fail: the peer with the range
noise sd scaled by 1.1 disagrees with jaxnav far beyond these tolerances,
and the in-place copy applied to unsorted ancestors (outside its contract)
differs from the gather.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from benchmarks.peers.numpy_fastslam import NumpyFastSLAM
from benchmarks.workloads import w3_fastslam as w3
from jaxnav.core import resampling
from jaxnav.models.landmarks import RangeBearingNoise, RangeBearingObs
from jaxnav.models.motion import VelocityNoise
from jaxnav.slam import fastslam as fs

M, N = 40, 12
IDS = np.array([3, 7, 3, 0, 11], np.int32)  # landmark 3 twice: sequential updates
CONTROL = (0.5, 0.1, 0.1)
SENSOR_SD = (0.1, 0.05)


def _case(dtype, seed=0):
    """Per-particle maps, non-uniform log-weights and observations (NumPy arrays)."""
    rng = np.random.default_rng(seed)
    poses = np.column_stack(
        [5.0 + 0.1 * rng.standard_normal(M), 5.0 + 0.1 * rng.standard_normal(M), 0.3 + 0.05 * rng.standard_normal(M)]
    )
    lw = rng.normal(0.0, 1.0, M)
    lw -= np.log(np.sum(np.exp(lw - lw.max()))) + lw.max()
    truth = rng.uniform(0.0, 10.0, (N, 2))
    means = truth[None] + 0.05 * rng.standard_normal((M, N, 2))
    a = 0.05 * rng.standard_normal((M, N, 2, 2))
    covs = a @ np.swapaxes(a, -1, -2) + 1e-3 * np.eye(2)
    true_pose = np.array([5.05, 5.0, 0.31])
    d = truth[IDS] - true_pose[:2]
    z = np.column_stack([np.hypot(d[:, 0], d[:, 1]), np.arctan2(d[:, 1], d[:, 0]) - true_pose[2]])
    z += rng.standard_normal(z.shape) * np.asarray(SENSOR_SD)
    z[:, 1] = (z[:, 1] + np.pi) % (2 * np.pi) - np.pi
    return tuple(x.astype(dtype) for x in (poses, lw, means, covs, z))


def _jaxnav_step(dtype, ess_threshold, key, sensor_sd=SENSOR_SD):
    poses, lw, means, covs, z = _case(dtype)
    config = fs.FastSLAMConfig(
        num_particles=M, num_landmarks=N, version=1, resampling="systematic", ess_threshold=ess_threshold
    )
    params = fs.FastSLAMParams(
        VelocityNoise(jnp.zeros(6, dtype), jnp.zeros(3, dtype)), RangeBearingNoise(jnp.asarray(sensor_sd, dtype))
    )
    state = fs.FastSLAMState(
        jnp.asarray(poses), jnp.asarray(lw), jnp.asarray(means), jnp.asarray(covs), jnp.ones(N, bool)
    )
    obs = RangeBearingObs(jnp.asarray(IDS), jnp.asarray(z), jnp.ones(len(IDS), bool))
    new, info = fs.step(key, state, config, params, jnp.asarray(CONTROL, dtype), obs)
    return jax.tree_util.tree_map(np.asarray, (new, info))


def _peer(dtype, sensor_sd=SENSOR_SD):
    poses, lw, means, covs, z = _case(dtype)
    pf = NumpyFastSLAM(poses, lw, means, covs, (0.0, 0.0, 0.0), sensor_sd, seed=0, dtype=dtype)
    pf.move(CONTROL)
    ll = pf.update(IDS, z)
    w, log_norm, ess = pf.normalise(ll)
    return pf, w, log_norm, ess


def _jaxnav_uniform(key, dtype):
    """The systematic-resampling uniform jaxnav draws inside ``fastslam.step(key, ...)``."""
    _, k_resample = jax.random.split(key)  # fastslam.kernel
    k_res, _ = jax.random.split(k_resample)  # resampling.conditional_resample
    return int(jax.random.bits(k_res, (), jnp.uint32)) / 2.0**32  # the systematic uniform u = U/2³² (resampling)


def _assert_same(pf, new, tol_lw, tol_mean, tol_cov_rel, tol_pose):
    np.testing.assert_allclose(pf.poses, new.poses, rtol=0, atol=tol_pose)
    np.testing.assert_allclose(pf.means, new.means, rtol=0, atol=tol_mean)
    np.testing.assert_allclose(pf.covs, new.covs, rtol=0, atol=tol_cov_rel * np.abs(new.covs).max())
    np.testing.assert_allclose(pf.lw, new.log_weights, rtol=0, atol=tol_lw)


def test_update_and_weights_match_float64(getkey):
    """No resampling (threshold far below any ESS): EKF updates, log-weights, log-likelihood, ESS agree."""
    with jax.enable_x64(True):
        new, info = _jaxnav_step(np.float64, 1e-3, getkey())
    assert not bool(info.resampled)
    pf, _, log_norm, ess = _peer(np.float64)
    _, _, means0, covs0, _ = _case(np.float64)
    assert np.abs(pf.means - means0).max() > 1e-3  # the observed landmarks did move
    _assert_same(pf, new, 1e-9, 1e-9, 1e-9, 1e-12)
    np.testing.assert_allclose(log_norm, info.log_likelihood, rtol=0, atol=1e-9)
    np.testing.assert_allclose(ess, info.ess, rtol=1e-9)
    # unobserved landmarks untouched by both
    untouched = np.setdiff1d(np.arange(N), IDS)
    np.testing.assert_array_equal(new.means[:, untouched], means0[:, untouched])


def test_resampling_matches_float64(getkey):
    """Resampling every step with jaxnav's uniform: the same ancestors, maps copied alike."""
    key = getkey()
    with jax.enable_x64(True):
        new, info = _jaxnav_step(np.float64, 1.0, key)
        u = _jaxnav_uniform(key, jnp.float64)
    assert bool(info.resampled)
    pf, w, _, _ = _peer(np.float64)
    idx = pf.indices(w, u)
    assert len(np.unique(idx)) < M  # a real resampling, some particles copied, some dropped
    pf.resample(idx)
    _assert_same(pf, new, 1e-12, 1e-9, 1e-9, 1e-12)
    np.testing.assert_allclose(new.log_weights, -math.log(M), rtol=1e-12)


def test_update_and_weights_match_float32(getkey):
    """The float32 filters the benchmark times agree to float32 round-off (tolerances in the docstring)."""
    new, info = _jaxnav_step(np.float32, 1e-3, getkey())
    pf, _, log_norm, _ = _peer(np.float32)
    assert pf.means.dtype == np.float32 and pf.lw.dtype == np.float32
    _assert_same(pf, new, 2e-4, 1e-5, 1e-5, 1e-6)
    np.testing.assert_allclose(log_norm, info.log_likelihood, rtol=0, atol=2e-4)


def test_negative_control_wrong_sensor_noise(getkey):
    """The peer with σ_r × 1.1 differs from jaxnav far beyond the float32 tolerance: the comparison can fail."""
    new, _ = _jaxnav_step(np.float32, 1e-3, getkey())
    pf, _, _, _ = _peer(np.float32, sensor_sd=(SENSOR_SD[0] * 1.1, SENSOR_SD[1]))
    assert np.abs(pf.lw - new.log_weights).max() > 100 * 2e-4
    assert np.abs(pf.means - new.means).max() > 100 * 1e-5


def _gather_cases(m):
    rng = np.random.default_rng(3)
    w = rng.exponential(size=m) ** 3
    cdf = np.cumsum(w / w.sum())
    systematic = np.minimum(np.searchsorted(cdf, (0.37 + np.arange(m)) / m, side="right"), m - 1)
    return {
        "identity": np.arange(m),
        "all first": np.zeros(m, int),
        "all last": np.full(m, m - 1),
        "one in the middle": np.full(m, m // 2),
        "systematic": systematic,
        "shift right": np.minimum(np.arange(m) + 3, m - 1),
        "shift left": np.maximum(np.arange(m) - 3, 0),
    }


@pytest.mark.parametrize("case", list(_gather_cases(50)))
def test_inplace_ancestor_copy_equals_gather(case):
    """For sorted ancestors the in-place copy returns exactly ``x[a]`` (both arrays, any row shape)."""
    m = 50
    idx = _gather_cases(m)[case].astype(np.int32)
    assert np.all(np.diff(idx) >= 0)
    rng = np.random.default_rng(4)
    a = rng.standard_normal((m, 7, 2)).astype(np.float32)
    b = rng.standard_normal((m, 7, 2, 2)).astype(np.float32)
    out = jax.jit(resampling.copy_ancestors_in_place)((jnp.asarray(a), jnp.asarray(b)), jnp.asarray(idx))
    np.testing.assert_array_equal(np.asarray(out[0]), a[idx])
    np.testing.assert_array_equal(np.asarray(out[1]), b[idx])


def test_inplace_ancestor_copy_needs_sorted_ancestors():
    """Negative control: a swap (unsorted, outside the contract) is not reproduced, so the test above can fail."""
    a = jnp.arange(6.0).reshape(3, 2)
    idx = jnp.asarray([1, 0, 2], jnp.int32)
    (out,) = resampling.copy_ancestors_in_place((a,), idx)
    assert not np.array_equal(np.asarray(out), np.asarray(a)[np.asarray(idx)])


def test_workload_data_and_floor():
    """The K = 5 observations are the nearest landmarks, within the map; the floor formula of the docstring."""
    data = w3.make_data(10)
    assert data.ids.shape == (w3.T, w3.K) and data.z.shape == (w3.T, w3.K, 2) and data.mask.all()
    assert data.ids.min() >= 0 and data.ids.max() < 10
    for t in range(w3.T):
        d = np.hypot(*(data.landmarks - data.true_poses[t, :2]).T)
        assert set(data.ids[t]) == set(np.argsort(d)[: w3.K])
        np.testing.assert_allclose(data.z[t, :, 0], d[data.ids[t]], atol=0.6)  # range noise sd 0.1 m, 6 sd
    assert np.all(np.linalg.eigvalsh(data.prior_covs.astype(np.float64)) > 0)
    assert w3.floor_bytes(4000, 1000) == 4000 * (300 + 48 * 1000)
