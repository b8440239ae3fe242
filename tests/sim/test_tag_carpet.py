"""HF-RFID world simulator: carpets, lattice detection against brute force, trajectories, runs, gradients."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.models import hf_rfid
from jaxnav.sim import tag_carpet as tc
from jaxnav.sim import trajectories

SD = jnp.asarray([0.01, 0.01, 0.02])


def _readers(side, dtype=jnp.float32):
    """Reader params in ``dtype``; σ = side/2 rounded once in ``dtype`` (not via float32)."""
    p = hf_rfid.reader_params(side=side)
    return hf_rfid.HFReaderParams(p.offsets.astype(dtype), jnp.asarray(side / 2, dtype), p.log_beta.astype(dtype))


def _valid_pairs(det, t=None):
    ids, rd, m = (np.asarray(a) if t is None else np.asarray(a)[t] for a in det)
    return ids[m], rd[m]


def _random_poses(rng, layout, num, outside=0.3):
    """Poses over the carpet and up to ``outside`` m beyond its border (to exercise the masking)."""
    xmin, ymin, xmax, ymax = layout.extent
    xy = rng.uniform([xmin - outside, ymin - outside], [xmax + outside, ymax + outside], (num, 2))
    th = rng.uniform(-math.pi, math.pi, (num, 1))
    return np.concatenate([xy, th], axis=1)


# ---------------------------------------------------------------------------
# carpet


def test_densities_map_to_the_thesis_pitches(getkey):
    for density, pitch in ((100, 0.10), (16, 0.25), (4, 0.50)):
        c = tc.make_carpet(getkey(), (2.0, 1.0), density=density)
        assert c.layout.pitch == pytest.approx(pitch, rel=1e-12)
        assert c.layout.density == pytest.approx(density, rel=1e-9)
        assert (c.layout.nx, c.layout.ny) == (int(round(2.0 / pitch)) + 1, int(round(1.0 / pitch)) + 1)
        assert c.layout.num_tags == c.layout.nx * c.layout.ny == c.jitter.shape[0]
    # floor(w/p) + 1 is not fooled by 0.3/0.1 = 2.9999999999999996
    assert tc.make_carpet(getkey(), (0.3, 0.25), pitch=0.1).layout.nx == 4
    assert tc.make_carpet(getkey(), (0.35, 0.0), pitch=0.1).layout.nx == 4
    assert tc.make_carpet(getkey(), (1.0, 1.0), density=9).layout.pitch == pytest.approx(1 / 3)


def test_ids_unique_and_positions_on_the_jittered_lattice(getkey):
    c = tc.make_carpet(getkey(), (1.2, 0.7), pitch=0.1, origin=(-0.4, 2.0), jitter=0.02)
    lay = c.layout
    iy, ix = np.meshgrid(np.arange(lay.ny), np.arange(lay.nx), indexing="ij")
    ids = np.asarray(tc.tag_ids(lay, ix.ravel(), iy.ravel()))
    assert len(set(ids.tolist())) == lay.num_tags
    np.testing.assert_array_equal(np.sort(ids), np.arange(lay.num_tags))
    bx, by = tc.tag_indices(lay, ids)
    np.testing.assert_array_equal(bx, ix.ravel())
    np.testing.assert_array_equal(by, iy.ravel())
    pos = np.asarray(tc.tag_positions(c))
    nominal = np.stack([-0.4 + ix.ravel() * 0.1, 2.0 + iy.ravel() * 0.1], axis=1)
    np.testing.assert_allclose(pos[ids] - nominal, np.asarray(c.jitter)[ids], atol=1e-6)
    # jitter < p/2, so rounding a position to the lattice recovers its ID
    rx = np.round((pos[:, 0] + 0.4) / 0.1).astype(int)
    ry = np.round((pos[:, 1] - 2.0) / 0.1).astype(int)
    np.testing.assert_array_equal(ry * lay.nx + rx, np.arange(lay.num_tags))


def test_jitter_is_uniform_within_its_bound(getkey):
    j = 0.02
    c = tc.make_carpet(getkey(), (10.0, 9.9), pitch=0.1, jitter=j)  # 101 × 100 tags
    v = np.asarray(c.jitter, np.float64).ravel()
    n = v.size
    assert np.all(np.abs(v) <= j) and np.max(np.abs(v)) > 0.999 * j
    # U(−J, J): mean 0 (sd J/√3), variance J²/3 (sd of the estimate √(4/45)·J²/√n); 5 standard errors
    assert abs(v.mean()) < 5 * j / math.sqrt(3 * n)
    assert abs(v.var() - j * j / 3) < 5 * math.sqrt(4 / 45) * j * j / math.sqrt(n)
    # no jitter: the exact lattice
    c0 = tc.make_carpet(getkey(), (1.0, 1.0), density=16, jitter=0.0)
    assert float(jnp.max(jnp.abs(c0.jitter))) == 0.0


def test_carpet_is_a_pytree_with_a_static_layout(getkey):
    traces = []

    @jax.jit
    def total(carpet):
        traces.append(carpet.layout)
        return jnp.sum(tc.tag_positions(carpet))

    a = tc.make_carpet(getkey(), (1.0, 1.0), density=16)
    b = tc.make_carpet(getkey(), (1.0, 1.0), density=16)  # same layout, other jitter
    c = tc.make_carpet(getkey(), (1.0, 1.0), density=100)
    np.testing.assert_allclose(total(a), np.sum(np.asarray(tc.tag_positions(a))), rtol=1e-5)
    total(b)
    assert len(traces) == 1  # jitter is a leaf: no retrace
    total(c)
    assert len(traces) == 2  # a new layout retraces
    assert jax.tree_util.tree_leaves(a) == [a.jitter]


# ---------------------------------------------------------------------------
# lattice detection == brute force


def _plant(rng, pos, offsets, sigma, num):
    """Poses that put a chosen tag 1 nm inside or outside an edge or a corner of a chosen footprint.

    Returns ``(poses [num, 3], tags [num], readers [num], inside [num])``.
    """
    poses, tags, readers, inside = [], [], [], []
    for i in range(num):
        b, n = rng.integers(offsets.shape[0]), rng.integers(pos.shape[0])
        delta = 1e-9 if i % 2 else -1e-9  # > 0: outside by 1 nm
        edge = lambda: (sigma + delta) * rng.choice([-1, 1])  # noqa: E731
        u = rng.uniform(-sigma, sigma)
        kind = i % 8 // 2
        e = [edge(), u] if kind == 0 else [u, edge()] if kind == 1 else [edge(), edge()]  # kinds 2, 3: a corner
        th = rng.uniform(-math.pi, math.pi)
        rot = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
        xy = pos[n] - rot @ (offsets[b] + np.array(e))
        poses.append([xy[0], xy[1], th])
        tags.append(n)
        readers.append(b)
        inside.append(delta < 0)
    return np.array(poses), np.array(tags), np.array(readers), np.array(inside)


@pytest.mark.parametrize("pitch", [0.1, 0.25, 0.5])
def test_lattice_lookup_equals_brute_force_float64(pitch, getkey):
    """Exact set and slot order against brute force in float64 (no rounding ties), per footprint:

    100 random poses (over the carpet and beyond its border) and 100 poses that
    put a tag 1 nm inside or outside an edge or corner of a footprint. The
    jitter bound J is 10 mm for the 60 mm footprint (the thesis setting) and
    0.45·p otherwise (near the largest allowed, which stresses the candidate
    window); a third of the tags are pushed to a corner of their jitter square
    (|j_x| = |j_y| = J).
    """
    rng = np.random.default_rng(int(pitch * 1000))
    checked = 0
    with jax.enable_x64(True):
        for side in (0.06, 0.3, 0.5):
            r = _readers(side, jnp.float64)
            off = np.asarray(r.offsets)
            jitter = 0.01 if side == 0.06 else 0.45 * pitch
            c = tc.make_carpet(getkey(), (2.0, 1.5), pitch=pitch, origin=(0.3, -0.2), jitter=jitter)
            jit = np.array(c.jitter)
            far = rng.random(jit.shape[0]) < 1 / 3
            jit[far] = np.where(jit[far] >= 0, jitter, -jitter)
            c = tc.TagCarpet(c.layout, jnp.asarray(jit))
            assert c.jitter.dtype == jnp.float64
            pos = np.asarray(tc.tag_positions(c))
            planted, tags, readers, inside = _plant(rng, pos, off, side / 2, 100)
            poses = np.concatenate([_random_poses(rng, c.layout, 100), planted])
            cap = tc.detection_capacity(c.layout, side, r.offsets)
            det = jax.vmap(lambda p: tc.detect(c, p, r))(jnp.asarray(poses))
            assert det.ids.shape == (200, cap)
            ids, rds, mask = (np.asarray(a) for a in det)
            for t in range(200):
                want_ids, want_rd = tc.detect_brute_force(pos, poses[t], r)
                k = len(want_ids)
                got_ids, got_rd = ids[t][mask[t]], rds[t][mask[t]]
                assert np.array_equal(got_ids, want_ids) and np.array_equal(got_rd, want_rd), (side, t)
                assert np.all(mask[t][:k]) and np.all(ids[t][k:] == -1)  # valid slots first, then −1
                checked += k
                if t >= 100:  # the planted tag is seen by its reader iff it is inside
                    i = t - 100
                    assert np.any((got_ids == tags[i]) & (got_rd == readers[i])) == inside[i], (side, i)
    assert checked > 500  # many detections were compared, not just empty sets


def test_float32_lookup_differs_from_float64_only_within_rounding(getkey):
    """In float32 a tag within ~1e-6 m of an edge may flip; every disagreement must be within 1e-5 m."""
    rng = np.random.default_rng(3)
    r = _readers(0.06)
    c = tc.make_carpet(getkey(), (3.0, 3.0), density=100, jitter=0.01)
    poses = _random_poses(rng, c.layout, 1000).astype(np.float32)
    det = jax.vmap(lambda p: tc.detect(c, p, r))(jnp.asarray(poses))
    pos = np.asarray(tc.tag_positions(c), np.float64)
    off = np.asarray(r.offsets, np.float64)
    flips = total = 0
    for t in range(len(poses)):
        want = set(zip(*tc.detect_brute_force(pos, poses[t], r)))
        got = set(zip(*_valid_pairs(det, t)))
        total += len(want)
        for n, b in want ^ got:
            x, y, th = poses[t].astype(np.float64)
            d = pos[n] - [x, y]
            e = (
                np.array([math.cos(th) * d[0] + math.sin(th) * d[1], -math.sin(th) * d[0] + math.cos(th) * d[1]])
                - off[b]
            )
            margin = 0.03 - np.max(np.abs(e))
            assert abs(margin) < 1e-5, (t, n, b, margin)
            flips += 1
    assert total > 500 and flips <= 3


def test_cost_does_not_depend_on_the_carpet_size(getkey):
    """The jaxpr of detect for 10 and ~100,000 tags: same equations and shapes but the jitter table."""
    r = _readers(0.06)
    small = tc.make_carpet(getkey(), (0.45, 0.1), density=100)
    big = tc.make_carpet(getkey(), (31.5, 31.6), density=100)
    assert small.layout.num_tags == 10 and big.layout.num_tags >= 100_000
    pose = jnp.asarray([0.2, 0.05, 0.3])

    def structure(jaxpr):
        out = []
        for eqn in jaxpr.eqns:
            out.append((eqn.primitive.name, tuple(str(v.aval) for v in eqn.outvars)))
            for p in eqn.params.values():
                sub = getattr(p, "jaxpr", None)
                if sub is not None:
                    out.extend(structure(getattr(sub, "jaxpr", sub)))
        return out

    f = lambda c, p: tc.detect(c, p, r, max_detections=24)  # noqa: E731
    js, jb = jax.make_jaxpr(f)(small, pose), jax.make_jaxpr(f)(big, pose)
    assert [str(v.aval) for v in js.jaxpr.invars] == ["float32[10,2]", "float32[3]"]
    assert [str(v.aval) for v in jb.jaxpr.invars] == [f"float32[{big.layout.num_tags},2]", "float32[3]"]
    ss, sb = structure(js.jaxpr), structure(jb.jaxpr)
    assert len(ss) > 20
    assert ss == sb
    # the big carpet runs and agrees with brute force at a few poses
    rng = np.random.default_rng(0)
    pos = np.asarray(tc.tag_positions(big), np.float64)
    for p in _random_poses(rng, big.layout, 5, outside=0.0):
        got = tc.detect(big, jnp.asarray(p, jnp.float32), r)
        want = tc.detect_brute_force(pos, p.astype(np.float32), r)
        assert set(zip(*_valid_pairs(got))) == set(zip(*want))


def test_two_readers_detecting_one_tag_fill_two_slots(getkey):
    """300 mm footprints overlap: a tag under the robot centre is seen by all 8 readers (|offset| ≤ 90 mm < 150 mm)."""
    r = _readers(0.3)
    c = tc.make_carpet(getkey(), (2.0, 2.0), density=4, jitter=0.0)  # 0.5 m pitch: one tag per footprint
    tag = 2 * c.layout.nx + 1  # (ix, iy) = (1, 2) at (0.5, 1.0)
    det = tc.detect(c, jnp.asarray([0.5, 1.0, 0.4]), r)
    ids, rd = _valid_pairs(det)
    np.testing.assert_array_equal(ids, [tag] * 8)
    np.testing.assert_array_equal(rd, np.arange(8))
    # at a pose where only some footprints reach the tag, exactly those readers report it
    pose = jnp.asarray([0.5 - 0.17, 1.0, 0.0])  # tag at robot-frame x = +0.17: readers with x offset > 0.02
    ids, rd = _valid_pairs(tc.detect(c, pose, r))
    np.testing.assert_array_equal(rd, [2, 3, 6, 7])
    np.testing.assert_array_equal(ids, [tag] * 4)


def test_detection_capacity_bounds_the_detections(getkey):
    """Thesis settings give small capacities; a NumPy brute force never exceeds the per-reader bound."""
    assert tc.detection_capacity(tc.CarpetLayout(0.1, 5, 5, max_jitter=0.01), 0.06, np.zeros((8, 2))) == 24
    assert tc.detection_capacity(tc.CarpetLayout(0.5, 5, 5, max_jitter=0.01), 0.3, np.zeros((8, 2))) == 8
    assert tc.detection_capacity(tc.CarpetLayout(0.25, 5, 5, max_jitter=0.01), 0.3, 8) == 32
    assert tc.detection_capacity(tc.CarpetLayout(0.1, 5, 5, max_jitter=0.01), 0.3, 8) == 144
    rng = np.random.default_rng(11)
    for pitch, side in ((0.1, 0.06), (0.1, 0.3), (0.1, 0.5), (0.25, 0.5), (0.5, 0.3)):
        r = _readers(side)
        c = tc.make_carpet(
            getkey(), (2.0, 2.0), pitch=pitch, jitter=0.49 * pitch
        )  # the largest jitter packs tags closest
        cap = tc.detection_capacity(c.layout, side, r.offsets)
        pos = np.asarray(tc.tag_positions(c))
        most = 0
        for p in _random_poses(rng, c.layout, 500, 0.0):
            _, rd = tc.detect_brute_force(pos, p, r)
            most = max(most, np.bincount(rd, minlength=8).max())
        assert 1 <= most <= cap // 8


def test_detect_under_jit_with_traced_readers_needs_footprint_side(getkey):
    c = tc.make_carpet(getkey(), (1.0, 1.0), density=100)
    r = _readers(0.06)
    pose = jnp.asarray([0.5, 0.5, 0.1])
    want = tc.detect(c, pose, r)
    got = jax.jit(lambda rr: tc.detect(c, pose, rr, footprint_side=0.06))(r)
    for a, b in zip(got, want):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="footprint_side"):
        jax.jit(lambda rr: tc.detect(c, pose, rr))(r)


def test_bad_input_is_refused_with_clear_messages(getkey):
    key = getkey()
    c = tc.make_carpet(key, (1.0, 1.0), density=100)
    r = _readers(0.06)
    pose = jnp.asarray([0.5, 0.5, 0.0])
    with pytest.raises(ValueError, match="side"):
        hf_rfid.reader_params(side=0.0)
    with pytest.raises(ValueError, match="half_width"):
        tc.detect(c, pose, r._replace(half_width=jnp.asarray(-0.03)))
    with pytest.raises(ValueError, match="footprint side must be > 0"):
        tc.detect(c, pose, r, footprint_side=0.0)
    with pytest.raises(ValueError, match="smaller than the readers' footprint"):
        tc.detect(c, pose, r, footprint_side=0.05)
    with pytest.raises(ValueError, match=r"jitter must be in \[0, pitch/2\)"):
        tc.make_carpet(key, (1.0, 1.0), density=100, jitter=0.05)
    with pytest.raises(ValueError, match="max_jitter"):
        tc.CarpetLayout(0.1, 3, 3, max_jitter=0.06)
    with pytest.raises(ValueError, match="exactly one of density"):
        tc.make_carpet(key, (1.0, 1.0))
    with pytest.raises(ValueError, match="exactly one of density"):
        tc.make_carpet(key, (1.0, 1.0), density=16, pitch=0.25)
    with pytest.raises(ValueError, match="density"):
        tc.make_carpet(key, (1.0, 1.0), density=-4)
    with pytest.raises(ValueError, match="below the detection capacity 24.*max_detections ≥ 24"):
        tc.detect(c, pose, r, max_detections=10)
    with pytest.raises(ValueError, match="max_detections"):
        tc.simulate(key, c, r, pose, jnp.tile(jnp.asarray([0.1, 0, 0, 0.1]), (5, 1)), SD, max_detections=3)
    with pytest.raises(ValueError, match="speed"):
        trajectories.rectangle_controls(1.0, 1.0, speed=0.0)
    with pytest.raises(ValueError, match="speed"):
        trajectories.rectangle_controls(1.0, 1.0, speed=-0.2)
    with pytest.raises(ValueError, match="speed_range"):
        trajectories.random_controls(key, num_steps=10, speed_range=(0.0, 0.4))
    with pytest.raises(ValueError, match="min ≤ max"):
        trajectories.random_controls(key, num_steps=10, speed_range=(0.4, 0.1))
    with pytest.raises(ValueError, match="too small"):
        trajectories.random_controls(key, bounds=(0, 0, 0.05, 1.0), num_steps=10)
    with pytest.raises(ValueError, match="odometry_sd"):
        tc.simulate(key, c, r, pose, jnp.tile(jnp.asarray([0.1, 0, 0, 0.1]), (5, 1)), -SD)
    with pytest.raises(ValueError, match="motion_model"):
        tc.simulate(key, c, r, pose, jnp.tile(jnp.asarray([0.1, 0, 0, 0.1]), (5, 1)), SD, motion_model="velocity")
    with pytest.raises(ValueError, match="kidnap.step"):
        tc.simulate(key, c, r, pose, jnp.tile(jnp.asarray([0.1, 0, 0, 0.1]), (5, 1)), SD, kidnap=tc.Kidnap(5, pose))


# ---------------------------------------------------------------------------
# trajectories


def _integrate64(start, controls):
    u = np.asarray(controls, np.float64)
    return np.asarray(start, np.float64)[None] + np.cumsum(u[:, :3] * u[:, 3:4], axis=0)


def test_rectangle_closes_after_each_lap_at_the_set_speed():
    start, u = trajectories.rectangle_controls(1.2, 0.8, speed=0.2, dt=0.1, laps=3, start=(0.5, 0.25))
    u = np.asarray(u, np.float64)
    lap = u.shape[0] // 3
    assert u.shape[0] == 3 * lap
    poses = _integrate64(start, u)
    for k in range(1, 4):
        np.testing.assert_allclose(poses[k * lap - 1, :2], [0.5, 0.25], atol=1e-5)
        np.testing.assert_allclose(poses[k * lap - 1, 2], 2 * math.pi * k, atol=1e-4)  # four quarter turns per lap
    moving = np.hypot(u[:, 0], u[:, 1]) > 0
    np.testing.assert_allclose(np.hypot(u[moving, 0], u[moving, 1]), 0.2, rtol=1e-6)
    assert np.all(u[moving, 2] == 0) and np.all(u[~moving, 2] > 0)  # turns in place at the corners
    # corners: the path visits (0.5, 0.25), (1.7, 0.25), (1.7, 1.05), (0.5, 1.05)
    for corner in ([1.7, 0.25], [1.7, 1.05], [0.5, 1.05]):
        assert np.min(np.linalg.norm(poses[:lap, :2] - corner, axis=1)) < 1e-5
    xy = poses[:, :2]
    assert xy[:, 0].min() > 0.5 - 1e-6 and xy[:, 0].max() < 1.7 + 1e-6
    # facing the direction of travel
    heading = np.concatenate([[0.0], poses[:-1, 2]])[moving]
    np.testing.assert_allclose(np.cos(heading), u[moving, 0] / 0.2, atol=1e-5)
    # a length that is not a multiple of speed·Δt (0.57/0.02 = 28.5 steps): n = round(L/(vΔt)) steps, so
    # the speed is off by at most a relative 1/(2n) ≤ vΔt/(2L − vΔt); here exactly that on the 0.57 m edges
    _, u2 = trajectories.rectangle_controls(1.03, 0.57, speed=0.2, dt=0.1, laps=1, turn_at_corners=False)
    u2 = np.asarray(u2, np.float64)
    spd = np.hypot(u2[:, 0], u2[:, 1])
    assert np.all(np.abs(spd / 0.2 - 1) <= 0.02 / (2 * 0.57 - 0.02) + 1e-6)
    assert np.abs(spd / 0.2 - 1).max() > 0.01
    np.testing.assert_allclose(_integrate64(jnp.zeros(3), u2)[-1], [0, 0, 0], atol=1e-6)
    assert np.all(u2[:, 2] == 0)  # no turns: θ stays 0


BOUNDS = (0.2, 0.3, 1.8, 1.5)
STEPS = 3000


@pytest.fixture(scope="module")
def world():
    """A 100 tags/m² carpet, 60 mm readers and a 3000-step random trajectory, shared by the simulation tests
    (one compilation of each simulator for the whole module)."""
    carpet = tc.make_carpet(jax.random.PRNGKey(1), (2.0, 2.0), density=100)
    start, u = trajectories.random_controls(jax.random.PRNGKey(2), bounds=BOUNDS, num_steps=STEPS)
    return carpet, _readers(0.06), start, u


def test_random_trajectory_stays_inside_bounds_with_speeds_in_range(getkey, world):
    for i in range(3):
        start, u = world[2:] if i == 0 else trajectories.random_controls(getkey(), bounds=BOUNDS, num_steps=STEPS)
        poses = np.asarray(trajectories.integrate_controls(start, u))
        assert np.all(poses[:, 0] >= BOUNDS[0]) and np.all(poses[:, 0] <= BOUNDS[2])
        assert np.all(poses[:, 1] >= BOUNDS[1]) and np.all(poses[:, 1] <= BOUNDS[3])
        u = np.asarray(u)
        spd = np.hypot(u[:, 0], u[:, 1])
        assert spd.min() >= 0.1 * (1 - 1e-6) and spd.max() <= 0.4 * (1 + 1e-6)
        assert spd.max() - spd.min() > 0.2  # speeds are actually drawn from the range
        # heading: bounded rate (smooth), and it follows the direction of travel most of the time
        assert np.max(np.abs(u[:, 2])) <= 1.0 + 1e-6
        dth = np.angle(np.exp(1j * np.diff(np.concatenate([[0.0], poses[:, 2]]))))
        assert np.max(np.abs(dth)) <= 0.1 + 1e-5
        travel = np.arctan2(u[:, 1], u[:, 0])
        prev = np.concatenate([[0.0], poses[:-1, 2]])
        # ω = clip(wrap(travel direction − θ)/heading_time, ±turn_rate) with heading_time 0.5 s, turn_rate 1 rad/s
        np.testing.assert_allclose(u[:, 2], np.clip(np.angle(np.exp(1j * (travel - prev))) / 0.5, -1, 1), atol=1e-4)
        assert np.ptp(poses[:, 2]) > math.pi  # and the heading does turn
        # it explores the box
        assert np.ptp(poses[:, 0]) > 0.7 * 1.6 and np.ptp(poses[:, 1]) > 0.7 * 1.2


# ---------------------------------------------------------------------------
# simulation


def test_simulate_true_path_and_detections(getkey, world):
    c, r, start, u = world
    run = tc.simulate(getkey(), c, r, start, u, SD)
    assert run.true_poses.shape == (STEPS, 3) and run.odometry.shape == (STEPS, 4)
    assert run.detections.ids.shape == (STEPS, 24) and run.kidnapped.shape == (STEPS,)
    np.testing.assert_array_equal(run.start_pose, start)
    assert not bool(jnp.any(run.kidnapped))
    # the true robot moves exactly with the controls (float32 accumulation over 3000 steps: < 1e-4 m)
    want = _integrate64(start, u)
    np.testing.assert_allclose(run.true_poses[:, :2], want[:, :2], atol=1e-4)
    np.testing.assert_allclose(np.angle(np.exp(1j * (np.asarray(run.true_poses[:, 2]) - want[:, 2]))), 0, atol=1e-4)
    np.testing.assert_allclose(run.true_poses, trajectories.integrate_controls(start, u), atol=1e-6)
    # the detections are detect() at each true pose
    again = jax.vmap(lambda p: tc.detect(c, p, r))(run.true_poses)
    for a, b in zip(run.detections, again):
        np.testing.assert_array_equal(a, b)
    assert int(run.detections.mask.sum()) > 1000


def test_vmapped_runs_have_the_configured_odometry_noise(getkey, world):
    """Odometry − controls ~ N(0, σ²) per component over 4 vmapped runs (n = 12,000 per component):
    sample sd within 4 standard errors σ/√(2n), mean within 4σ/√n, correlations within 4/√n."""
    c, r, start, u = world
    sd = np.array([0.02, 0.005, 0.05])
    keys = jax.random.split(getkey(), 4)
    batch = jax.vmap(lambda k: tc.simulate(k, c, r, start, u, jnp.asarray(sd)))(keys)
    assert batch.odometry.shape == (4, STEPS, 4)
    np.testing.assert_array_equal(batch.odometry[..., 3], np.broadcast_to(u[:, 3], (4, STEPS)))
    res = np.asarray(batch.odometry[..., :3] - u[:, :3], np.float64).reshape(-1, 3)
    n = res.shape[0]
    assert np.all(np.abs(res.std(axis=0) - sd) < 4 * sd / math.sqrt(2 * n))
    assert np.all(np.abs(res.mean(axis=0)) < 4 * sd / math.sqrt(n))
    assert np.max(np.abs(np.corrcoef(res.T) - np.eye(3))) < 4 / math.sqrt(n)
    # one vmapped call equals the runs one by one; each key has its own noise
    one = tc.simulate(keys[2], c, r, start, u, jnp.asarray(sd))
    np.testing.assert_allclose(batch.odometry[2], one.odometry, rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(batch.detections.ids[2], one.detections.ids)
    assert float(jnp.max(jnp.abs(batch.odometry[0] - batch.odometry[1]))) > 0
    # inside a caller's jit, with the controls closed over (concrete, their slices traced): the same runs
    jitted = jax.jit(jax.vmap(lambda k: tc.simulate(k, c, r, start, jnp.asarray(u), jnp.asarray(sd))))(keys)
    np.testing.assert_allclose(jitted.odometry, batch.odometry, rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(jitted.detections.ids, batch.detections.ids)
    # negative control: σ = 0 gives the controls exactly
    clean = tc.simulate(getkey(), c, r, start, u, jnp.zeros(3))
    np.testing.assert_array_equal(clean.odometry, u)


def test_omni_body_odometry_is_in_the_robot_frame(getkey, world):
    c, r, start, u = world
    sd = np.array([0.02, 0.01, 0.03])
    run = tc.simulate(getkey(), c, r, start, u, jnp.asarray(sd), motion_model="omni_body")
    prev = np.concatenate([np.asarray(start)[None], np.asarray(run.true_poses[:-1])])
    ct, st = np.cos(prev[:, 2]), np.sin(prev[:, 2])
    un = np.asarray(u, np.float64)
    body = np.stack([ct * un[:, 0] + st * un[:, 1], -st * un[:, 0] + ct * un[:, 1], un[:, 2]], axis=1)
    res = np.asarray(run.odometry[:, :3], np.float64) - body
    assert np.all(np.abs(res.std(axis=0) - sd) < 4 * sd / math.sqrt(2 * STEPS))
    # noise-free body odometry integrated with the omni_body model reproduces the true path
    clean = tc.simulate(getkey(), c, r, start, u, jnp.zeros(3), motion_model="omni_body")
    body_path = trajectories.integrate_controls(start, clean.odometry, "omni_body")
    np.testing.assert_allclose(body_path[:, :2], run.true_poses[:, :2], atol=1e-4)
    # negative control: read as world-frame velocities it does not
    wrong = trajectories.integrate_controls(start, clean.odometry, "omni")
    assert float(jnp.max(jnp.abs(wrong[:, :2] - run.true_poses[:, :2]))) > 0.1


def test_kidnap_teleports_and_zeroes_the_odometry(getkey, world):
    c, r, start, u = world
    target = jnp.asarray([1.2, 0.9, -1.0])
    step = 1234
    run = tc.simulate(getkey(), c, r, start, u, SD, kidnap=tc.Kidnap(step, target))
    np.testing.assert_array_equal(np.nonzero(np.asarray(run.kidnapped))[0], [step])
    np.testing.assert_allclose(run.true_poses[step], target, atol=1e-7)
    np.testing.assert_array_equal(run.odometry[step], [0.0, 0.0, 0.0, u[step, 3]])
    assert float(jnp.max(jnp.abs(run.odometry[step + 1, :3] - u[step + 1, :3]))) > 0  # noise elsewhere
    # before, the controls from the start; afterwards the same controls from the new pose
    np.testing.assert_allclose(run.true_poses[:step], trajectories.integrate_controls(start, u[:step]), atol=1e-6)
    # after the jump, against the float64 integration from the new pose: two float32 programs of
    # the same recursion may round differently (XLA contracts multiply-adds per program), and over
    # 4,000 steps their headings drifted 1.2e-6 apart; float32 accumulation stays below 1e-4
    after = np.asarray(run.true_poses[step + 1 :])
    want = _integrate64(target, u[step + 1 :])
    np.testing.assert_allclose(after[:, :2], want[:, :2], atol=1e-4)
    np.testing.assert_allclose(np.angle(np.exp(1j * (after[:, 2] - want[:, 2]))), 0, atol=1e-4)
    again = tc.detect(c, target, r)
    for a, b in zip(jax.tree_util.tree_map(lambda x: x[step], run.detections), again):
        np.testing.assert_array_equal(a, b)


def test_kidnapping_scenario_returns_to_a_mapped_place(getkey):
    c = tc.make_carpet(getkey(), (1.6, 1.6), density=100)
    r = _readers(0.06)
    run = tc.kidnapping_scenario(getkey(), c, r, SD, width=1.0, height=1.0)
    ks = np.nonzero(np.asarray(run.kidnapped))[0]
    assert len(ks) == 1
    k = int(ks[0])
    poses = np.asarray(run.true_poses)
    np.testing.assert_array_equal(run.odometry[k, :3], [0, 0, 0])
    # B → C is a jump, and C is a pose the robot had before
    assert np.linalg.norm(poses[k, :2] - poses[k - 1, :2]) > 0.5
    d = np.linalg.norm(poses[:k, :2] - poses[k, :2], axis=1)
    assert d.min() < 1e-5
    # the tags detected on the way from C were mapped before the kidnapping
    before = set(np.asarray(run.detections.ids)[:k][np.asarray(run.detections.mask)[:k]].tolist())
    after_ids = np.asarray(run.detections.ids)[k : k + 30][np.asarray(run.detections.mask)[k : k + 30]]
    assert len(after_ids) > 10 and set(after_ids.tolist()) <= before
    # and it drives on to D: one more lap after finishing the first
    assert poses.shape[0] > k + 280


# ---------------------------------------------------------------------------
# smooth relaxation and gradients


def test_soft_inside_tends_to_the_footprint_indicator(getkey):
    e = jax.random.uniform(getkey(), (5000, 2), minval=-0.06, maxval=0.06)
    hard = np.asarray(jnp.all(jnp.abs(e) < 0.03, axis=-1))
    far = np.asarray(jnp.min(jnp.abs(jnp.abs(e) - 0.03), axis=-1) > 0.003)
    for tau in (1e-3, 1e-4):
        soft = np.asarray(hf_rfid.soft_inside(e, 0.03, tau))
        assert np.all((soft >= 0) & (soft <= 1))  # (0, 1) mathematically; float32 exp underflows far outside
        assert np.all(np.isfinite(np.asarray(hf_rfid.log_soft_inside(e, 0.03, tau))))
        bound = 4 * math.exp(-0.003 / tau)  # each of the four logistic factors is within e^{−d/τ} of its limit
        assert np.max(np.abs(soft - hard)[far]) < bound
    # on an edge midpoint the soft indicator is 1/2 (times ≈1 from the other three sides)
    np.testing.assert_allclose(hf_rfid.soft_inside(jnp.asarray([0.03, 0.0]), 0.03, 1e-4), 0.5, rtol=1e-4)
    np.testing.assert_allclose(
        hf_rfid.log_soft_inside(e, 0.03, 1e-3), np.log(hf_rfid.soft_inside(e, 0.03, 1e-3)), rtol=1e-4, atol=1e-6
    )


def _x64_run(getkey, side=0.3):
    c = tc.make_carpet(getkey(), (1.5, 1.5), density=16, jitter=0.02)
    r = _readers(side, jnp.float64)
    start, u = trajectories.rectangle_controls(
        0.75, 0.75, speed=0.25, dt=0.1, laps=1, start=(0.375, 0.375), turn_rate=math.pi / 2
    )
    run = tc.simulate(getkey(), c, r, start, u, SD.astype(jnp.float64))
    return c, r, start, u, run


def test_grad_of_soft_likelihood_wrt_footprint_half_width(getkey):
    """jax.grad in σ equals central finite differences (float64), and points to the true σ = 0.15 m."""
    with jax.enable_x64(True):
        c, r, _, _, run = _x64_run(getkey)
        assert int(run.detections.mask.sum()) > 100
        tau, window = 0.0075, 0.35  # window ≥ σ + 20τ for every σ below
        vg = jax.jit(
            jax.value_and_grad(
                lambda hw: hf_rfid.soft_detection_log_likelihood(
                    tc.tag_map(c, window), run.true_poses, run.detections, r.offsets, hw, tau, window
                )
            )
        )
        ll, g = (lambda hw: vg(hw)[0]), (lambda hw: vg(hw)[1])  # one compilation for values and gradients
        hw0 = jnp.asarray(0.15, jnp.float64)
        h = 1e-6
        fd = (ll(hw0 + h) - ll(hw0 - h)) / (2 * h)
        assert np.isfinite(float(g(hw0)))
        np.testing.assert_allclose(g(hw0), fd, rtol=1e-5)
        for hw in (0.11, 0.19):
            hw = jnp.asarray(hw, jnp.float64)
            np.testing.assert_allclose(g(hw), (ll(hw + h) - ll(hw - h)) / (2 * h), rtol=1e-5)
        # the soft likelihood prefers the true footprint: ascent below it, descent above it
        assert float(g(jnp.asarray(0.12))) > 0 > float(g(jnp.asarray(0.18)))
        assert float(ll(hw0)) > max(float(ll(jnp.asarray(0.12))), float(ll(jnp.asarray(0.18))))
        # leaving out the pairs beyond the window is harmless: a wider window adds terms of size ≤ e^{−(w−σ)/τ}
        wide = jax.jit(
            lambda hw: hf_rfid.soft_detection_log_likelihood(
                tc.tag_map(c, 0.5), run.true_poses, run.detections, r.offsets, hw, tau, 0.5
            )
        )(hw0)
        assert abs(float(wide) - float(ll(hw0))) < 1e-6


def test_grad_of_soft_likelihood_wrt_odometry_noise_sd(getkey):
    """Reparameterised path x(σ) = ∫ (controls + σ·z) with fixed normals z: jax.grad in σ equals central FD."""
    with jax.enable_x64(True):
        c, r, start, u, run = _x64_run(getkey)
        z = jax.random.normal(getkey(), (u.shape[0], 3), jnp.float64)
        tau, window = 0.02, 0.6

        def ll(sd):
            noisy = u.at[:, :3].add(sd * z)
            path = trajectories.integrate_controls(start, noisy)
            return hf_rfid.soft_detection_log_likelihood(
                tc.tag_map(c, window), path, run.detections, r.offsets, r.half_width, tau, window
            )

        vg = jax.jit(jax.value_and_grad(ll))
        ll = lambda sd: vg(sd)[0]  # noqa: E731
        sd0 = jnp.asarray([0.01, 0.02, 0.05], jnp.float64)
        g = np.asarray(vg(sd0)[1])
        assert np.all(np.isfinite(g)) and np.max(np.abs(g)) > 1.0
        h = 1e-6
        fd = np.array([(ll(sd0.at[i].add(h)) - ll(sd0.at[i].add(-h))) / (2 * h) for i in range(3)])
        np.testing.assert_allclose(g, fd, rtol=1e-4, atol=1e-6 * np.max(np.abs(fd)))
