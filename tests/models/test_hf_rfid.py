"""HF-RFID reader model ([W] eq. 3.7): likelihood values, frames, footprint sampling, validation."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from jaxnav.models import hf_rfid


def test_eq_3_7_by_hand():
    """log w = 0 inside (strict), log β − eᵀe/(2σ²) outside; σ = 30 mm, β = 0.1."""
    p = hf_rfid.reader_params(side=0.06, beta=0.1)
    lb = math.log(0.1)
    e = jnp.asarray([[0.0, 0.0], [0.029, -0.029], [-0.0299, 0.0], [0.05, 0.04], [0.0, -0.031], [0.1, 0.1]])
    got = hf_rfid.log_detection_likelihood(e, p.half_width, p.log_beta)
    s2 = 0.03**2
    want = [0.0, 0.0, 0.0, lb - (0.05**2 + 0.04**2) / (2 * s2), lb - 0.031**2 / (2 * s2), lb - 0.02 / (2 * s2)]
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)


def test_eq_3_7_boundary_is_strict():
    """|e_x| = σ exactly is outside ([W] eq. 3.7 uses <). σ = 0.25 and e are exact in float32."""
    hw, lb = jnp.asarray(0.25), jnp.asarray(math.log(0.5))
    e = jnp.asarray([[0.25, 0.0], [0.0, -0.25], [0.25, 0.25], [0.2499999, 0.0], [-0.125, 0.2499999]])
    got = np.asarray(hf_rfid.log_detection_likelihood(e, hw, lb))
    # on the boundary: log β − σ²/(2σ²) = log β − 1/2 (and − 1 at the corner)
    np.testing.assert_allclose(got[:3], [math.log(0.5) - 0.5, math.log(0.5) - 0.5, math.log(0.5) - 1.0], rtol=1e-6)
    np.testing.assert_array_equal(got[3:], [0.0, 0.0])
    # the outside branch is continuous with nothing: just outside the edge the weight jumps from 1 to β·e^{-1/2}
    assert got[0] < math.log(0.5) - 0.49


def test_tag_and_robot_likelihoods_are_eq_3_7_of_the_residual(getkey):
    p = hf_rfid.reader_params(side=0.3)
    pose = jnp.asarray([1.0, -0.5, 0.8])
    off = p.offsets[5]
    tags = jax.random.uniform(getkey(), (200, 2), minval=-0.5, maxval=0.5) + pose[:2]
    want = hf_rfid.log_detection_likelihood(hf_rfid.robot_frame(pose, tags) - off, p.half_width, p.log_beta)
    np.testing.assert_allclose(hf_rfid.tag_log_likelihood(tags, pose, off, p), want)
    poses = pose + jax.random.normal(getkey(), (100, 3)) * jnp.asarray([0.1, 0.1, 0.2])
    tag = hf_rfid.world_frame(pose, off + jnp.asarray([0.05, -0.03]))
    one = lambda q: hf_rfid.log_detection_likelihood(hf_rfid.robot_frame(q, tag) - off, p.half_width, p.log_beta)  # noqa: E731
    want = jax.vmap(one)(poses)
    np.testing.assert_allclose(hf_rfid.robot_log_likelihood(poses, tag, off, p), want, rtol=1e-6, atol=1e-6)
    # both inside and outside cases occur (the test is not vacuous)
    assert 0 < int(jnp.sum(want == 0)) < 100


def test_frames_by_hand_and_inverse(getkey):
    pose = jnp.asarray([1.0, 2.0, math.pi / 2])
    np.testing.assert_allclose(hf_rfid.robot_frame(pose, jnp.asarray([1.0, 3.0])), [1.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(hf_rfid.world_frame(pose, jnp.asarray([1.0, 0.0])), [1.0, 3.0], atol=1e-6)
    poses = jnp.concatenate(
        [
            jax.random.uniform(getkey(), (500, 2), minval=-5, maxval=5),
            jax.random.uniform(getkey(), (500, 1), minval=-math.pi, maxval=math.pi),
        ],
        axis=1,
    )
    pts = jax.random.uniform(getkey(), (500, 2), minval=-5, maxval=5)
    np.testing.assert_allclose(hf_rfid.world_frame(poses, hf_rfid.robot_frame(poses, pts)), pts, atol=1e-5)
    np.testing.assert_allclose(hf_rfid.robot_frame(poses, hf_rfid.world_frame(poses, pts)), pts, atol=1e-5)
    # a rotation: distances to the robot are preserved
    np.testing.assert_allclose(
        jnp.linalg.norm(hf_rfid.robot_frame(poses, pts), axis=-1),
        jnp.linalg.norm(pts - poses[:, :2], axis=-1),
        rtol=1e-5,
    )


def test_sample_in_footprint_is_uniform_over_the_rotated_square(getkey):
    """In float64 every sample is strictly inside (eq. 3.7 gives 0); in the reader frame each axis is U(−σ, σ)."""
    with jax.enable_x64(True):
        p = hf_rfid.reader_params(side=0.3)
        off = jnp.asarray(p.offsets[6], jnp.float64)
        hw = jnp.asarray(p.half_width, jnp.float64)
        pose = jnp.asarray([0.4, -1.2, 2.3], jnp.float64)
        n = 20000
        pts = hf_rfid.sample_in_footprint(getkey(), pose, off, hw, n)
        assert pts.shape == (n, 2) and pts.dtype == jnp.float64
        params64 = hf_rfid.HFReaderParams(jnp.asarray(p.offsets, jnp.float64), hw, jnp.asarray(p.log_beta, jnp.float64))
        ll = hf_rfid.tag_log_likelihood(pts, pose, off, params64)
        assert bool(jnp.all(ll == 0.0))
        e = np.asarray(hf_rfid.robot_frame(pose, pts) - off) / float(hw)
        # negative control: reader 0's overlapping but shifted footprint does not contain them all
        other = hf_rfid.tag_log_likelihood(pts, pose, params64.offsets[0], params64)
        assert 0.0 < float(jnp.mean(other == 0.0)) < 0.9
    for axis in range(2):
        # Kolmogorov–Smirnov against U(−1, 1): p > 0.001 fails with probability 0.001 under the null
        assert stats.kstest(e[:, axis], "uniform", args=(-1, 2)).pvalue > 1e-3
    # independence of the axes: correlation within 4/√n
    assert abs(np.corrcoef(e[:, 0], e[:, 1])[0, 1]) < 4 / math.sqrt(n)


def test_sample_in_footprint_float32_within_rounding(getkey):
    p = hf_rfid.reader_params(side=0.06)
    pose = jnp.asarray([3.0, 2.0, -0.4])
    pts = hf_rfid.sample_in_footprint(getkey(), pose, p.offsets[2], p.half_width, 5000)
    e = hf_rfid.robot_frame(pose, pts) - p.offsets[2]
    # float32 round trip through the world frame: within 1e-6 m of the closed square
    assert float(jnp.max(jnp.abs(e))) <= 0.03 + 1e-6
    assert float(jnp.mean(hf_rfid.tag_log_likelihood(pts, pose, p.offsets[2], p) == 0)) > 0.999


def test_footprint_cov_is_s_squared_over_12(getkey):
    for side in (0.06, 0.1, 0.3, 0.5):
        cov = hf_rfid.footprint_cov(hf_rfid.reader_params(side=side))
        np.testing.assert_allclose(cov, np.eye(2) * side**2 / 12, rtol=1e-6)
    # and it is the covariance of the uniform samples (standard error of a variance of U: √(4/45)·σ²/√n)
    p = hf_rfid.reader_params(side=0.3)
    pts = hf_rfid.sample_in_footprint(getkey(), jnp.zeros(3), jnp.zeros(2), p.half_width, 40000)
    emp = np.cov(np.asarray(pts).T)
    var = 0.3**2 / 12
    se = math.sqrt(4 / 45) * 0.15**2 / math.sqrt(40000)
    assert np.all(np.abs(np.diag(emp) - var) < 5 * se)
    assert abs(emp[0, 1]) < 5 * var / math.sqrt(40000)


def test_default_offsets_two_rows_of_four_at_60mm_centred():
    off = np.asarray(hf_rfid.default_reader_offsets())
    assert off.shape == (8, 2)
    np.testing.assert_allclose(off.mean(axis=0), [0.0, 0.0], atol=1e-7)
    np.testing.assert_allclose(sorted(set(np.round(off[:, 0], 6))), [-0.09, -0.03, 0.03, 0.09], atol=1e-7)
    np.testing.assert_allclose(sorted(set(np.round(off[:, 1], 6))), [-0.03, 0.03], atol=1e-7)
    # reader b = r·4 + c: row r along y, column c along x
    np.testing.assert_allclose(off[0], [-0.09, -0.03], atol=1e-7)
    np.testing.assert_allclose(off[3], [0.09, -0.03], atol=1e-7)
    np.testing.assert_allclose(off[4], [-0.09, 0.03], atol=1e-7)
    d = np.linalg.norm(off[:, None] - off[None], axis=-1) + np.eye(8)
    np.testing.assert_allclose(d.min(), 0.06, rtol=1e-5)
    p = hf_rfid.reader_params()
    assert p.num_readers == 8
    np.testing.assert_allclose(p.half_width, 0.03)
    np.testing.assert_allclose(p.log_beta, math.log(hf_rfid.DEFAULT_BETA), rtol=1e-6)


def test_reader_params_validation():
    with pytest.raises(ValueError, match="side"):
        hf_rfid.reader_params(side=0.0)
    with pytest.raises(ValueError, match="side"):
        hf_rfid.reader_params(side=-0.06)
    with pytest.raises(ValueError, match="beta"):
        hf_rfid.reader_params(beta=0.0)
    with pytest.raises(ValueError, match="beta"):
        hf_rfid.reader_params(beta=1.5)
    with pytest.raises(ValueError, match="offsets"):
        hf_rfid.reader_params(offsets=np.zeros((8, 3)))
    with pytest.raises(ValueError, match="offsets"):
        hf_rfid.reader_params(offsets=[[0.0, np.nan]])
    with pytest.raises(ValueError, match="rows must be a positive integer"):
        hf_rfid.default_reader_offsets(rows=0)
    with pytest.raises(ValueError, match="cols must be a positive integer"):
        hf_rfid.default_reader_offsets(cols=1.5)
    with pytest.raises(ValueError, match="pitch"):
        hf_rfid.default_reader_offsets(pitch=0.0)
    good = hf_rfid.reader_params()
    with pytest.raises(ValueError, match="half_width"):
        hf_rfid.validate_params(good._replace(half_width=jnp.asarray(0.0)))
    with pytest.raises(ValueError, match="log_beta"):
        hf_rfid.validate_params(good._replace(log_beta=jnp.asarray(0.5)))
    with pytest.raises(ValueError, match="HFReaderParams"):
        hf_rfid.validate_params((good.offsets, good.half_width, good.log_beta))
    hf_rfid.validate_params(good)  # and a valid one passes


def test_landmark_observations_give_the_detecting_readers_offsets():
    p = hf_rfid.reader_params()
    det = hf_rfid.TagDetections(
        jnp.asarray([[7, 9, -1], [3, 3, 12]], jnp.int32),
        jnp.asarray([[2, 5, -1], [0, 7, 1]], jnp.int32),
        jnp.asarray([[True, True, False], [True, True, True]]),
    )
    obs = hf_rfid.landmark_observations(det, p)
    assert obs.z.shape == (2, 3, 2)
    np.testing.assert_array_equal(obs.ids, det.ids)
    np.testing.assert_array_equal(obs.mask, det.mask)
    off = np.asarray(p.offsets)
    np.testing.assert_allclose(obs.z[0, :2], off[[2, 5]])
    np.testing.assert_allclose(obs.z[1], off[[0, 7, 1]])
    assert np.all(np.isfinite(np.asarray(obs.z)))  # the empty slot (reader −1) is clipped, not NaN


def test_validate_detections():
    det = hf_rfid.TagDetections(
        jnp.zeros(4, jnp.int32), jnp.asarray([0, 1, 9, -1], jnp.int32), jnp.asarray([True, True, True, False])
    )
    with pytest.raises(ValueError, match="readers"):
        hf_rfid.validate_detections(det, time_axis=False, num_readers=8)
    hf_rfid.validate_detections(
        det._replace(readers=jnp.asarray([0, 1, 7, -1], jnp.int32)), time_axis=False, num_readers=8
    )
    with pytest.raises(ValueError, match="same shape"):
        hf_rfid.validate_detections(det._replace(mask=jnp.ones(3, bool)), time_axis=False)
    with pytest.raises(ValueError, match="shape"):
        hf_rfid.validate_detections(det, time_axis=True)
