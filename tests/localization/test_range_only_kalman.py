"""EKF and UKF localization, and FastSLAM, with a biased range to each beacon (observation model RANGE_ONLY)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.core import kalman
from jaxnav.localization import ekf, ukf
from jaxnav.models import landmarks as lm
from jaxnav.models import motion
from jaxnav.models import range_only as ro
from jaxnav.sim import landmark_world as lw
from jaxnav.sim import range_world as rw
from jaxnav.sim import trajectories as tr
from jaxnav.slam import fastslam

ROOM = lw.square_room_landmarks(10.0, 8)
MOTION = motion.VelocityNoise(jnp.asarray([0.01, 0.005, 0.005, 0.01, 0.0, 0.0]), jnp.asarray([0.01, 0.01, 0.005]))
START = jnp.asarray([5.0, 2.0, 0.0])
CONTROLS = tr.loop_controls(200, speed=0.5, turn_rate=0.15, dt=0.25)
NOISE = ro.range_noise(0.1, bias=0.3)
RUN = rw.simulate(jax.random.PRNGKey(2), ROOM, START, CONTROLS, MOTION, NOISE, max_range=6.0)
INITIAL_COV = jnp.diag(jnp.asarray([0.05, 0.05, 0.02]) ** 2)


def _error(module, config, noise, observations=RUN.observations):
    params = ekf.KalmanParams(MOTION, noise, ROOM)
    state = module.init(None, config, params, START, INITIAL_COV)
    _, trace = module.run(None, state, config, params, RUN.controls, observations)
    return np.linalg.norm(np.asarray(trace.estimate)[:, :2] - np.asarray(RUN.true_poses)[:, :2], axis=1).mean(), trace


@pytest.mark.parametrize("module, config_type", [(ekf, ekf.EKFConfig), (ukf, ukf.UKFConfig)])
def test_kalman_filters_localize_by_biased_ranges_and_the_bias_is_subtracted_exactly(module, config_type):
    """Eight beacons of a 10 m room within 6 m, σ = 0.1 m, a bias of 0.3 m. Measured (seed 2): mean
    error 0.04 m (EKF and UKF) with the bias known, 0.2 m and more with it ignored. Bounds: under 0.1 m
    known, and the bias-blind filter at least twice as far off. The model's bias is ``z − b`` before the
    update: the same trace as ranges debiased by hand, bit for bit."""
    config = config_type(observation_model="range_only")
    known, trace = _error(module, config, NOISE)
    blind, _ = _error(module, config, NOISE._replace(bias=jnp.float32(0.0)))
    assert known < 0.1 and blind > 2 * known, (known, blind)
    debiased = RUN.observations._replace(z=RUN.observations.z - NOISE.bias)
    _, by_hand = _error(module, config, NOISE._replace(bias=jnp.float32(0.0)), debiased)
    np.testing.assert_array_equal(np.asarray(trace.estimate), np.asarray(by_hand.estimate))
    assert int(np.asarray(trace.accepted).sum()) == int(np.asarray(RUN.observations.mask).sum())


def test_the_gate_of_a_range_has_one_degree_of_freedom_and_the_bias_a_gradient():
    """χ²₁ at 0.999 is 10.83 (χ²₂: 13.82); the log-likelihood of a run is differentiable in the bias,
    with its maximum near the true 0.3 m (the derivative positive below it, negative above)."""
    assert ekf.EKFConfig(observation_model="range_only", gate_probability=0.999).gate == pytest.approx(10.828, abs=1e-3)
    assert ekf.EKFConfig(gate_probability=0.999).gate == pytest.approx(kalman.chi2_gate(0.999, 2))
    config = ekf.EKFConfig(observation_model="range_only")

    def log_likelihood(bias):
        params = ekf.KalmanParams(MOTION, NOISE._replace(bias=bias), ROOM)
        state = ekf.KalmanState(START, INITIAL_COV)
        first_minute = jax.tree_util.tree_map(lambda a: a[:60], RUN.observations)
        _, trace = ekf.run(None, state, config, params, RUN.controls[:60], first_minute)
        return jnp.sum(trace.log_likelihood)

    below, above = jax.grad(log_likelihood)(jnp.float32(0.2)), jax.grad(log_likelihood)(jnp.float32(0.4))
    assert np.isfinite(below) and np.isfinite(above) and below > 0 > above, (below, above)


def test_range_observations_and_parameters_are_checked_by_name():
    config = ekf.EKFConfig(observation_model="range_only")
    with pytest.raises(ValueError, match=r"params\.sensor must be RangeNoise"):
        ekf.init(None, config, ekf.KalmanParams(MOTION, lm.RangeBearingNoise(jnp.ones(2)), ROOM), START, INITIAL_COV)
    params = ekf.KalmanParams(MOTION, NOISE, ROOM)
    state = ekf.init(None, config, params, START, INITIAL_COV)
    two_numbers = ro.RangeObs(jnp.zeros(2, jnp.int32), jnp.ones((2, 2)), jnp.ones(2, bool))
    with pytest.raises(ValueError, match=r"observations\.z"):
        ekf.step(None, state, config, params, CONTROLS[0], two_numbers)
    with pytest.raises(ValueError, match="observation_model"):
        ekf.EKFConfig(observation_model="sonar")
    # inside a caller's jit a negative σ is flagged and the state kept
    bad = ekf.KalmanParams(MOTION, NOISE._replace(sd=jnp.float32(-0.1)), ROOM)
    obs = jax.tree_util.tree_map(lambda a: a[0], RUN.observations)
    new, info = jax.jit(ekf.kernel, static_argnums=2)(None, state, config, bad, CONTROLS[0], obs)
    assert bool(info.invalid_inputs) and np.array_equal(np.asarray(new.mean), np.asarray(state.mean))


def test_fastslam_starts_a_beacon_ahead_at_its_range_with_the_rings_spread():
    """FastSLAM with RANGE_ONLY (the biased range, anchors unknown): a beacon seen once becomes the
    Gaussian straight ahead of the particle at the unbiased range ``ρ = z − b``, covariance
    ``(ρ²/2 + σ²) I`` — one Gaussian cannot hold the ring, which is PF-SLAM's argument."""
    config = fastslam.FastSLAMConfig(
        num_particles=4, num_landmarks=8, motion_model="velocity", observation_model="range_only"
    )
    still = motion.VelocityNoise(jnp.zeros(6), jnp.zeros(3))
    params = fastslam.FastSLAMParams(still, NOISE)
    state = fastslam.init(jax.random.PRNGKey(0), config, params, START)
    obs = ro.RangeObs(jnp.asarray([3, 0]), jnp.asarray([[2.3], [0.0]]), jnp.asarray([True, False]))
    final, _ = fastslam.step(jax.random.PRNGKey(1), state, config, params, jnp.asarray([0.0, 0.0, 0.1]), obs)
    means = np.asarray(final.means)[:, 3]
    np.testing.assert_allclose(means, np.tile([7.0, 2.0], (4, 1)), atol=1e-5)
    covs = np.asarray(final.covs)[..., 3, :, :] if final.covs.ndim == 4 else np.asarray(final.covs)[3]
    np.testing.assert_allclose(covs.reshape(-1, 2, 2)[0], np.eye(2) * (0.5 * 2.0**2 + 0.01), rtol=1e-5)
    assert bool(np.asarray(final.seen)[..., 3].all()) and not bool(np.asarray(final.seen)[..., 0].any())


def test_fastslam_ring_spreads_a_new_beacon_around_its_ring_one_point_per_particle():
    """RANGE_ONLY_RING: particle ``n`` puts a new beacon on the ring of radius ``ρ = z − b`` at the angle
    ``2πu_n``; the particles' angles cover the circle evenly (every eighth of it holds 50 of 400
    particles, one either way for a point on a boundary), the covariance is ``σ²`` across the ring and ``σ² + (2πρ/N)²``
    along it, and two beacons first seen together get unrelated angles (their pairs fill each of 16
    cells of the torus, 25 ± 12 of 400)."""
    n = 400
    config = fastslam.FastSLAMConfig(
        num_particles=n, num_landmarks=8, motion_model="velocity", observation_model="range_only_ring"
    )
    still = motion.VelocityNoise(jnp.zeros(6), jnp.zeros(3))
    params = fastslam.FastSLAMParams(still, NOISE)
    state = fastslam.init(jax.random.PRNGKey(0), config, params, START)
    obs = ro.RangeObs(jnp.asarray([3, 5]), jnp.asarray([[2.3], [1.3]]), jnp.asarray([True, True]))
    final, _ = fastslam.step(jax.random.PRNGKey(1), state, config, params, jnp.asarray([0.0, 0.0, 0.1]), obs)
    offsets = np.asarray(final.means)[:, [3, 5]] - np.asarray(START)[:2]  # [N, 2 beacons, 2]
    np.testing.assert_allclose(np.linalg.norm(offsets, axis=-1), np.tile([2.0, 1.0], (n, 1)), atol=1e-5)
    angles = np.mod(np.arctan2(offsets[..., 1], offsets[..., 0]), 2 * np.pi)
    for b in range(2):
        counts = np.bincount((angles[:, b] / (np.pi / 4)).astype(int), minlength=8)
        assert counts.min() >= 49 and counts.max() <= 51, counts
    cells = np.bincount((angles[:, 0] / (np.pi / 2)).astype(int) * 4 + (angles[:, 1] / (np.pi / 2)).astype(int))
    assert len(cells) == 16 and cells.min() >= 13 and cells.max() <= 37, cells
    cov = np.asarray(final.covs)[0, 3]
    radial = offsets[0, 0] / 2.0
    along = np.array([-radial[1], radial[0]])
    assert radial @ cov @ radial == pytest.approx(0.01, rel=1e-4)
    assert along @ cov @ along == pytest.approx(0.01 + (2 * np.pi * 2.0 / n) ** 2, rel=1e-4)


@pytest.mark.parametrize("num_particles", [1, 7, 1000, 100_000])
def test_spread_quantiles_are_one_per_stratum_and_pair_landmarks_at_random(num_particles):
    """A Latin hypercube: each landmark's quantiles are exactly ``(k + ½)/N``, k = 0 … N − 1, in an order
    that differs between landmarks (for N ≥ 1000 two landmarks' orders agree at no more than a few
    particles, as two random permutations would: 1 expected); the same inside ``jit``."""
    from jaxnav.models.observation import spread_quantiles

    expected = (np.arange(num_particles) + 0.5) / num_particles
    orders = []
    for j in (0, 1, 7, 999):
        u = np.asarray(spread_quantiles(num_particles, jnp.asarray(j)))
        np.testing.assert_allclose(np.sort(u), expected, rtol=1e-6)
        orders.append(np.argsort(u))
    if num_particles >= 1000:
        for a in range(4):
            for b in range(a):
                assert np.sum(orders[a] == orders[b]) <= 8, (a, b)
    inside = jax.jit(lambda j: spread_quantiles(num_particles, j))
    np.testing.assert_array_equal(inside(jnp.asarray(7)), spread_quantiles(num_particles, jnp.asarray(7)))
