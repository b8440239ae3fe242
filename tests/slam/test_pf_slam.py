"""PF-SLAM and PS-SLAM steps ([W] Algs. 1 and 2) on tiny hand-built cases.

Every expected number below is computed here in NumPy from [W] eq. 3.7 and
the algorithm's lines, independently of jaxnav's implementation.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.core import weights
from jaxnav.models import hf_rfid
from jaxnav.models.motion import OmniNoise
from jaxnav.slam import pf_slam, ps_slam

BETA = 0.1
SENSOR = hf_rfid.reader_params(0.06, beta=BETA)
OFFSETS = np.asarray(SENSOR.offsets, np.float64)
SIGMA = 0.03
STILL = jnp.asarray([0.0, 0.0, 0.0, 0.1], jnp.float32)  # (vx, vy, ω, dt): no motion
NO_NOISE = OmniNoise(jnp.zeros(3, jnp.float32))


def _eq37(e: np.ndarray) -> np.ndarray:
    """[W] eq. 3.7 (log form), written out independently."""
    e = np.atleast_2d(e)
    inside = (np.abs(e[:, 0]) < SIGMA) & (np.abs(e[:, 1]) < SIGMA)
    return np.where(inside, 0.0, math.log(BETA) - (e * e).sum(1) / (2 * SIGMA**2))


def _to_robot(pose, pts):
    c, s = math.cos(pose[2]), math.sin(pose[2])
    d = np.atleast_2d(pts) - pose[:2]
    return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], 1)


def _det(pairs, k=4):
    ids = np.zeros(k, np.int32)
    readers = np.zeros(k, np.int32)
    mask = np.zeros(k, bool)
    for i, (n, b) in enumerate(pairs):
        ids[i], readers[i], mask[i] = n, b, True
    return hf_rfid.TagDetections(jnp.asarray(ids), jnp.asarray(readers), jnp.asarray(mask))


def _pf(i=4, j=4, max_tags=8, **kw):
    return pf_slam.PFSLAMConfig(num_particles=i, num_tag_particles=j, max_tags=max_tags, **kw)


# The tests share two PF-SLAM configurations (and so two compiled steps): the hand-computed cases'
# I = J = 4, and I = J = 200 for the cases whose claim needs many robot or tag particles.
WIDE = dict(i=200, j=200)


def _state_with_tag(config, poses, tag_id, tag_particles):
    state = pf_slam.init(jax.random.PRNGKey(0), config, pf_slam.PFSLAMParams(NO_NOISE, SENSOR), poses[0])
    tags = state.tags
    tp = jnp.asarray(tag_particles, jnp.float32)
    tags = tags._replace(
        particles=tags.particles.at[tag_id].set(tp),
        estimates=tags.estimates.at[tag_id].set(tp.mean(0)),
        counts=tags.counts.at[tag_id].set(1),
    )
    return state._replace(poses=jnp.asarray(poses, jnp.float32), tags=tags)


def test_pf_slam_redetection_matches_hand_computed_algorithm_1():
    """J = I = 4, one re-detection by reader 5: tag weights, tag resampling, tag estimate,
    robot weights, ESS, estimate and log-likelihood equal the hand computation of [W] Alg. 1."""
    config = _pf()
    params = pf_slam.PFSLAMParams(NO_NOISE, SENSOR)
    # Robot particles: two inside the plausible region, two off by 5 cm and 6 cm in x (outside the footprint, not on its edge).
    poses = np.array([[1.0, 1.0, 0.0], [1.004, 0.998, 0.0], [1.05, 1.0, 0.0], [0.94, 1.0, 0.0]])
    reader = 5  # offset (-0.03, 0.03)
    # Tag particles: two inside reader 5's footprint seen from the estimate, two far outside.
    tag = np.array([[0.975, 1.03], [0.985, 1.02], [1.2, 1.3], [0.7, 0.6]])
    state = _state_with_tag(config, poses, 3, tag)

    new_state, info = pf_slam.step(jax.random.PRNGKey(7), state, config, params, STILL, _det([(3, reader)]))

    pose_est = poses.mean(0)  # uniform weights, θ = 0
    ll_tag = _eq37(_to_robot(pose_est, tag) - OFFSETS[reader])
    assert ll_tag[0] == 0 and ll_tag[1] == 0 and ll_tag[2] < -40 and ll_tag[3] < -40
    # Weights (0.5, 0.5, ~0, ~0): systematic resampling keeps exactly two copies of each survivor.
    particles = np.asarray(new_state.tags.particles[3])
    for survivor in tag[:2]:
        assert np.sum(np.all(np.isclose(particles, survivor, atol=1e-6), axis=1)) == 2
    tag_est = tag[:2].mean(0)
    np.testing.assert_allclose(new_state.tags.estimates[3], tag_est, atol=1e-6)
    np.testing.assert_allclose(np.exp(new_state.tags.log_weights[3]), np.full(4, 0.25), rtol=1e-5)
    assert int(new_state.tags.counts[3]) == 2

    ll_robot = _eq37(np.stack([_to_robot(p, tag_est)[0] for p in poses]) - OFFSETS[reader])
    w = np.exp(ll_robot - ll_robot.max())
    w /= w.sum()
    np.testing.assert_allclose(info.ess, 1.0 / np.sum(w**2), rtol=1e-4)
    np.testing.assert_allclose(info.estimate[:2], (w[:, None] * poses[:, :2]).sum(0), atol=1e-5)
    np.testing.assert_allclose(info.log_likelihood, np.log(np.mean(np.exp(ll_robot))), rtol=1e-4, atol=1e-5)
    assert int(info.num_updated) == 1 and int(info.num_new) == 0 and not bool(info.lost)
    # The resampled robot set consists of the original particles, in systematic proportions.
    counts = [int(np.sum(np.all(np.isclose(new_state.poses, p, atol=1e-6), axis=1))) for p in poses]
    assert sum(counts) == 4
    for c, wi in zip(counts, w):
        assert math.floor(4 * wi) <= c <= math.ceil(4 * wi)


def test_new_tag_is_spread_over_the_detecting_footprint_and_does_not_weight_the_robot():
    config = _pf(**WIDE)
    params = pf_slam.PFSLAMParams(NO_NOISE, SENSOR)
    pose = np.array([2.0, -1.0, 0.7])
    state = pf_slam.init(jax.random.PRNGKey(1), config, params, pose)
    new_state, info = pf_slam.step(jax.random.PRNGKey(2), state, config, params, STILL, _det([(6, 2)]))
    e = _to_robot(pose, np.asarray(new_state.tags.particles[6])) - OFFSETS[2]
    assert np.all(np.abs(e) <= SIGMA + 1e-6)
    assert np.std(e[:, 0]) > 0.4 * SIGMA  # spread over the footprint (uniform sd = σ/√3 ≈ 0.58σ)
    assert int(new_state.tags.counts[6]) == 1 and int(info.num_new) == 1
    np.testing.assert_allclose(float(info.ess), config.num_particles, rtol=1e-5)
    assert int(np.sum(np.asarray(new_state.tags.counts) > 0)) == 1  # nothing else written


def test_a_degenerate_step_reports_ess_zero_like_weights_ess():
    """No robot particle with positive weight: the step resets to uniform, flags it, and reports ESS 0
    (``weights.step_ess``), the value ``weights.ess`` gives the same log-weights."""
    config = _pf()
    params = pf_slam.PFSLAMParams(NO_NOISE, SENSOR)
    state = pf_slam.init(jax.random.PRNGKey(1), config, params, np.array([2.0, -1.0, 0.7]))
    state = state._replace(log_weights=jnp.full_like(state.log_weights, -jnp.inf))
    ess_of_inputs = float(weights.ess(state.log_weights))  # before the step, which donates the state
    new_state, info = pf_slam.step(jax.random.PRNGKey(2), state, config, params, STILL, _det([(6, 2)]))
    assert bool(info.degenerate) and float(info.ess) == 0.0 == ess_of_inputs
    np.testing.assert_allclose(np.asarray(new_state.log_weights), -np.log(config.num_particles), rtol=1e-6)


def test_two_readers_detecting_one_tag_update_it_once_with_both_detections():
    """300 mm footprints overlap: readers 0 and 3 (18 cm apart) both see a new tag. The tag is
    written once, counted once, and its particles end in the intersection of the two footprints."""
    sensor = hf_rfid.reader_params(0.3, beta=1e-3)
    config = _pf(**WIDE)
    params = pf_slam.PFSLAMParams(NO_NOISE, sensor)
    pose = np.zeros(3)
    state = pf_slam.init(jax.random.PRNGKey(3), config, params, pose)
    new_state, info = pf_slam.step(jax.random.PRNGKey(4), state, config, params, STILL, _det([(1, 0), (1, 3)]))
    off = np.asarray(sensor.offsets)
    p = np.asarray(new_state.tags.particles[1])
    in_0 = np.all(np.abs(p - off[0]) < 0.15, axis=1)
    in_3 = np.all(np.abs(p - off[3]) < 0.15, axis=1)
    assert in_0.all() and in_3.mean() > 0.9  # initialised in reader 0's footprint, weighted by reader 3's
    assert int(new_state.tags.counts[1]) == 1 and int(info.num_new) == 1
    np.testing.assert_array_equal(np.asarray(info.slot_ids), [1, 1, -1, -1])
    # Negative control: detected by reader 0 alone, only the overlap (40 % of the footprint) is in reader 3's.
    single, _ = pf_slam.step(
        jax.random.PRNGKey(4),
        pf_slam.init(jax.random.PRNGKey(3), config, params, pose),
        config,
        params,
        STILL,
        _det([(1, 0)]),
    )
    q = np.asarray(single.tags.particles[1])
    assert 0.25 < np.all(np.abs(q - off[3]) < 0.15, axis=1).mean() < 0.6


def test_ids_beyond_the_table_are_dropped_and_counted():
    config = _pf()
    params = pf_slam.PFSLAMParams(NO_NOISE, SENSOR)
    state = pf_slam.init(jax.random.PRNGKey(0), config, params, np.zeros(3))
    before = jax.tree_util.tree_map(np.asarray, state.tags)
    first_beyond = config.max_tags  # the first ID past the table, then one far past it and a negative one
    new_state, info = pf_slam.step(
        jax.random.PRNGKey(1), state, config, params, STILL, _det([(first_beyond, 0), (99, 1), (-1, 2)])
    )
    assert int(info.num_ignored) == 3 and int(info.num_new) == 0
    for a, b in zip(jax.tree_util.tree_leaves(new_state.tags), jax.tree_util.tree_leaves(before)):
        np.testing.assert_array_equal(np.asarray(a), b)


def _ps(j=4, lag=3, **kw):
    return ps_slam.PSSLAMConfig(num_particles=4, num_tag_particles=j, max_tags=8, lag=lag, **kw)


def test_ps_slam_ring_holds_lineages_and_smoothed_estimate_is_the_ring_mean():
    """J = 4, L = 3: after four detections the ring has wrapped; every particle's ring rows form
    one lineage (consecutive states differ by the jitter, not by a jump to another particle),
    the current particle is the newest ring entry, and the estimate is the mean over the last L."""
    config = _ps()
    jitter = 1e-3
    params = ps_slam.PSSLAMParams(NO_NOISE, SENSOR, jnp.asarray(jitter, jnp.float32))
    pose = np.array([0.5, 0.5, 0.0])
    state = ps_slam.init(jax.random.PRNGKey(0), config, params, pose)
    for t in range(4):
        state, info = ps_slam.step(jax.random.PRNGKey(10 + t), state, config, params, STILL, _det([(2, 1)]))
    tags = jax.tree_util.tree_map(np.asarray, state.tags)
    assert tags.counts[2] == 4
    hist = tags.history[2]  # [L, J, 2]; slot 4 mod 3 = 1 is next, so the order is slots 1, 2, 0
    ordered = hist[[1, 2, 0]]
    np.testing.assert_allclose(ordered[-1], tags.particles[2], atol=1e-7)
    steps = np.linalg.norm(np.diff(ordered, axis=0), axis=-1)
    assert steps.max() < 6 * jitter * math.sqrt(2)
    np.testing.assert_allclose(tags.estimates[2], ordered.mean(axis=(0, 1)), atol=1e-6)
    np.testing.assert_allclose(info.slot_estimates[0], tags.estimates[2], atol=1e-7)


def test_ps_slam_first_detection_matches_pf_slam_and_resampling_moves_histories():
    """A new tag: the ring holds the initial particles once and the estimate is their mean. Then a
    re-detection that rules out half the particles: the surviving lineages' histories move with them."""
    config = _ps()  # L = 3: the two detections fill two ring slots, as with any L ≥ 2
    params = ps_slam.PSSLAMParams(NO_NOISE, SENSOR, jnp.asarray(0.0, jnp.float32))
    pose = np.array([0.0, 0.0, 0.0])
    state = ps_slam.init(jax.random.PRNGKey(0), config, params, pose)
    state, _ = ps_slam.step(jax.random.PRNGKey(1), state, config, params, STILL, _det([(0, 0)]))
    first = np.asarray(state.tags.particles[0])
    np.testing.assert_allclose(state.tags.history[0, 0], first, atol=1e-7)
    np.testing.assert_allclose(state.tags.estimates[0], first.mean(0), atol=1e-6)
    # Replace the particles by two inside / two far outside reader 0's footprint, keep them in the ring.
    pts = np.array([[-0.09, -0.03], [-0.08, -0.02], [0.5, 0.5], [-0.6, 0.4]], np.float32)
    tags = state.tags._replace(
        particles=state.tags.particles.at[0].set(pts), history=state.tags.history.at[0, 0].set(pts)
    )
    state = state._replace(tags=tags)
    state, _ = ps_slam.step(jax.random.PRNGKey(2), state, config, params, STILL, _det([(0, 0)]))
    hist = np.asarray(state.tags.history[0])  # jitter 0: each lineage repeats its point
    np.testing.assert_allclose(hist[0], hist[1], atol=1e-7)
    assert sorted(map(tuple, np.round(hist[1], 4))) == sorted(map(tuple, np.round(pts[[0, 0, 1, 1]], 4)))
    np.testing.assert_allclose(state.tags.estimates[0], pts[:2].mean(0), atol=1e-6)


def test_kidnapped_robot_is_redrawn_around_the_detected_tags():
    """Robot particles 1 m away from where the re-detected tags say it is: the step flags the
    robot as lost, redraws it so the detecting readers sit over the tags, and leaves the map alone."""
    config = _pf(**WIDE)
    params = pf_slam.PFSLAMParams(NO_NOISE, SENSOR)
    true_pose = np.array([3.0, 2.0, 0.0])
    tag_a = true_pose[:2] + OFFSETS[0]
    tag_b = true_pose[:2] + OFFSETS[7]

    def kidnapped_state(config):
        state = pf_slam.init(jax.random.PRNGKey(0), config, params, true_pose - np.array([1.0, 0.0, 0.0]))
        t = state.tags
        for n, p in ((0, tag_a), (1, tag_b)):
            t = t._replace(
                particles=t.particles.at[n].set(
                    jnp.broadcast_to(jnp.asarray(p, jnp.float32), (config.num_tag_particles, 2))
                ),
                estimates=t.estimates.at[n].set(jnp.asarray(p, jnp.float32)),
                counts=t.counts.at[n].set(3),
            )
        return state._replace(tags=t)

    state = kidnapped_state(config)
    before = np.asarray(state.tags.estimates)
    new_state, info = pf_slam.step(jax.random.PRNGKey(1), state, config, params, STILL, _det([(0, 0), (1, 7)]))
    assert bool(info.lost)
    assert np.linalg.norm(np.asarray(info.estimate[:2]) - true_pose[:2]) < 0.03
    assert abs(float(info.estimate[2])) < 0.3  # heading drawn uniformly, fixed by the two tags
    np.testing.assert_array_equal(np.asarray(new_state.tags.estimates), before)
    # Negative control: without recovery the particles stay a metre away.
    config_off = _pf(**WIDE, recovery=False)
    _, info_off = pf_slam.step(
        jax.random.PRNGKey(1), kidnapped_state(config_off), config_off, params, STILL, _det([(0, 0), (1, 7)])
    )
    assert not bool(info_off.lost)
    assert np.linalg.norm(np.asarray(info_off.estimate[:2]) - true_pose[:2]) > 0.9


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(num_particles=0), "num_particles"),
        (dict(num_tag_particles=0), "num_tag_particles"),
        (dict(max_tags=0), "max_tags"),
        (dict(motion_model="teleport"), "motion_model"),
        (dict(ess_threshold=0.0), "ess_threshold"),
        (dict(recovery_log_likelihood=1.0), "recovery_log_likelihood"),
    ],
)
def test_invalid_pf_config_is_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        pf_slam.PFSLAMConfig(**kwargs)


def test_invalid_ps_config_and_params_are_refused():
    with pytest.raises(ValueError, match="lag"):
        ps_slam.PSSLAMConfig(lag=0)
    config = _ps()
    with pytest.raises(ValueError, match="tag_jitter_sd"):
        ps_slam.init(
            jax.random.PRNGKey(0), config, ps_slam.PSSLAMParams(NO_NOISE, SENSOR, jnp.asarray(-1.0)), np.zeros(3)
        )
    with pytest.raises(ValueError, match="half_width"):
        bad = SENSOR._replace(half_width=jnp.asarray(0.0))
        pf_slam.init(jax.random.PRNGKey(0), _pf(), pf_slam.PFSLAMParams(NO_NOISE, bad), np.zeros(3))
    with pytest.raises(ValueError, match="side"):
        hf_rfid.reader_params(0.0)


def test_bad_detections_and_capacity_are_refused():
    config = _pf(max_tags=10)
    params = pf_slam.PFSLAMParams(NO_NOISE, SENSOR)
    state = pf_slam.init(jax.random.PRNGKey(0), config, params, np.zeros(3))
    det = _det([(1, 8)])  # reader 8 does not exist (8 readers: 0..7)
    with pytest.raises(ValueError, match="readers"):
        pf_slam.step(jax.random.PRNGKey(1), state, config, params, STILL, det)
    with pytest.raises(ValueError, match="same shape"):
        pf_slam.step(
            jax.random.PRNGKey(1),
            state,
            config,
            params,
            STILL,
            hf_rfid.TagDetections(jnp.zeros(3, jnp.int32), jnp.zeros(4, jnp.int32), jnp.zeros(4, bool)),
        )
    with pytest.raises(ValueError, match="max_tags ≥ 11"):
        pf_slam.check_capacity(config, 11)
    with pytest.raises(ValueError, match="same number of steps"):
        dets = jax.tree_util.tree_map(lambda x: jnp.stack([x] * 3), _det([(1, 0)]))
        pf_slam.run(jax.random.PRNGKey(1), state, config, params, jnp.stack([STILL] * 2), dets)


def test_params_are_checked_once_per_value_and_numpy_params_changed_in_place_again():
    """An online loop passes the same params at every step: they are validated once per value
    (:mod:`jaxnav.core.filter`), never by object identity, so a NumPy leaf changed in place
    after a valid call is checked again, and PS-SLAM refuses PF-SLAM's params it has never seen."""
    config = _pf()
    params = pf_slam.PFSLAMParams(NO_NOISE, SENSOR)
    state = pf_slam.init(jax.random.PRNGKey(0), config, params, np.zeros(3))
    state, _ = pf_slam.step(jax.random.PRNGKey(1), state, config, params, STILL, _det([(1, 0)]))
    bad = pf_slam.PFSLAMParams(NO_NOISE, SENSOR._replace(half_width=jnp.asarray(-1.0)))
    with pytest.raises(ValueError, match="half_width"):
        pf_slam.step(jax.random.PRNGKey(1), state, config, bad, STILL, _det([(1, 0)]))
    sd = np.zeros(3, np.float32)
    mutable = pf_slam.PFSLAMParams(OmniNoise(sd), SENSOR)
    state, _ = pf_slam.step(jax.random.PRNGKey(1), state, config, mutable, STILL, _det([(1, 0)]))
    sd[0] = np.nan  # changed in place after a valid call
    with pytest.raises(ValueError):
        pf_slam.step(jax.random.PRNGKey(1), state, config, mutable, STILL, _det([(1, 0)]))
    ps_config = ps_slam.PSSLAMConfig(num_particles=config.num_particles, num_tag_particles=4, max_tags=8, lag=2)
    with pytest.raises(ValueError, match="PSSLAMParams"):
        ps_slam.init(jax.random.PRNGKey(0), ps_config, params, np.zeros(3))


def _slot_sequence():
    """Six steps of 8 detection slots under 300 mm readers: a tag seen by two readers, valid slots
    behind masked ones, an ID beyond the table, five valid slots in one step, an empty step."""
    rows = [
        [(1, 0), (1, 3), (2, 1)],
        [None, (1, 0), (99, 2), (2, 1), None, (3, 2)],
        [(1, 0), (2, 1), (3, 2), (4, 4), (5, 5)],
        [],
        [None, None, None, (5, 5), (4, 4), (1, 0), (1, 3)],
        [(6, 6), (2, 1)],
    ]
    ids, readers, mask = np.zeros((6, 8), np.int32), np.zeros((6, 8), np.int32), np.zeros((6, 8), bool)
    for t, row in enumerate(rows):
        for k, entry in enumerate(row):
            if entry is not None:
                ids[t, k], readers[t, k], mask[t, k] = entry[0], entry[1], True
    controls = jnp.tile(jnp.asarray([0.05, 0.02, 0.1, 0.1], jnp.float32), (6, 1))
    return controls, hf_rfid.TagDetections(jnp.asarray(ids), jnp.asarray(readers), jnp.asarray(mask))


def _slot_filter(module, lanes, side=0.3, motion_sd=(0.02, 0.02, 0.01)):
    sensor = hf_rfid.reader_params(side, beta=0.05)
    motion = OmniNoise(jnp.asarray(motion_sd, jnp.float32))
    if module is pf_slam:
        config = pf_slam.PFSLAMConfig(32, 24, 8, parallel_slots=lanes)
        params = pf_slam.PFSLAMParams(motion, sensor)
    else:
        config = ps_slam.PSSLAMConfig(32, 24, 8, parallel_slots=lanes, lag=3)
        params = ps_slam.PSSLAMParams(motion, sensor, ps_slam.default_jitter(sensor))
    return config, params


@pytest.mark.parametrize("module", [pf_slam, ps_slam], ids=["pf_slam", "ps_slam"])
@pytest.mark.parametrize("lanes", [1, 2, 4])
def test_parallel_slots_filter_like_all_slots(module, lanes):
    """With ``parallel_slots`` a step processes the valid slots moved to the front, and all slots when
    more are valid (step 2 has five, step 4 four): the same states and traces as ``parallel_slots=None``."""
    controls, det = _slot_sequence()
    outs = []
    for slots in (None, lanes):
        config, params = _slot_filter(module, slots)
        state = module.init(jax.random.PRNGKey(0), config, params, jnp.asarray([0.5, 0.5, 0.0]))
        outs.append(module.run(jax.random.PRNGKey(1), state, config, params, controls, det))
    (want_state, want), (got_state, got) = outs
    for a, b in zip(jax.tree_util.tree_leaves((got_state, got)), jax.tree_util.tree_leaves((want_state, want))):
        if jnp.issubdtype(a.dtype, jnp.floating):
            np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)
        else:
            np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(np.asarray(got.num_ignored), [0, 1, 0, 0, 0, 0])
    np.testing.assert_array_equal(np.asarray(got.slot_ids[1]), [-1, 1, -1, 2, -1, 3, -1, -1])
    assert int(got.num_new.sum()) == 6 and int(got_state.tags.counts[1]) == 4


def test_parallel_slots_keep_the_derivatives_of_all_slots():
    """Reverse and forward derivatives of the log-likelihood through ``run`` (w.r.t. the reader model's
    log β and the motion noise) are those of ``parallel_slots=None``: the compacted step's overflow is a
    loop that reverse mode cannot differentiate, so its derivatives come from the all-slot update.

    Per module, one jitted program: the reverse derivative of ``parallel_slots=None`` (``jax.grad``), and
    of ``parallel_slots=2`` one linearisation (``jax.linearize``) evaluated forward (the JVP) and
    transposed (the VJP: ``jax.grad`` is this linearisation transposed), which share its primal pass."""
    controls, det = _slot_sequence()

    motion_sd = (0.3, 0.3, 0.2)  # 30 mm per step against 60 mm footprints: particles leave them

    def loglik(module, lanes):
        config, params = _slot_filter(module, lanes, side=0.06, motion_sd=motion_sd)

        def f(log_beta, motion_sd):
            p = params._replace(sensor=params.sensor._replace(log_beta=log_beta), motion=OmniNoise(motion_sd))
            state = module.init(jax.random.PRNGKey(0), config, p, jnp.asarray([0.5, 0.5, 0.0]))
            return jnp.sum(module.run(jax.random.PRNGKey(1), state, config, p, controls, det)[1].log_likelihood)

        return f

    @functools.partial(jax.jit, static_argnums=0)
    def derivatives(module, args, tangent):
        want = jax.grad(loglik(module, None), argnums=(0, 1))(*args)
        value, linear = jax.linearize(loglik(module, 2), *args)
        got = jax.linear_transpose(linear, *args)(jnp.ones_like(value))
        return want, got, linear(*tangent)

    args = (jnp.asarray(np.log(0.05), jnp.float32), jnp.asarray(motion_sd, jnp.float32))
    tangent = (jnp.ones_like(args[0]), jnp.zeros_like(args[1]))
    for module in (pf_slam, ps_slam):
        want, got, jvp_got = derivatives(module, args, tangent)
        assert np.all(np.isfinite(np.asarray(want[1]))) and abs(float(want[0])) > 0 and np.any(np.asarray(want[1]) != 0)
        for a, b in zip(got, want):
            np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(jvp_got, want[0], rtol=1e-4)
