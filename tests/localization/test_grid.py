"""Grid (histogram) localization ([A] Alg. 2, Thrun et al. Tab. 8.1).

What is shown, and where the tolerances come from:

* tracking: a grid estimate is a cell-centre average, so with a posterior much
  narrower than a cell it is the truth *quantised* to the grid: RMS position
  error Δ·√(2/12) ≈ 0.41 Δ for a uniformly placed truth, at most the half
  diagonal Δ/√2 ≈ 0.71 Δ; heading at most Δθ/2. The bounds (RMS < 0.5 Δ,
  max < Δ, heading < Δθ) leave room for the filter's own error (MCL's is
  ~0.15 Δ here). The same data with mirrored bearings break them (the
  negative control).
* agreement with MCL on the same data: the gap is at most the quantisation
  (0.71 Δ) plus both filters' errors; bound 1.5 Δ, mean 0.5 Δ.
* a 180°-symmetric map of identical landmarks: two modes of equal mass, each a
  copy of the known-association posterior (entropy + log 2); with known
  identities (the negative control) one mode.
* the convolution prediction equals a brute-force dense transition built cell
  by cell from the same kernels (float64, 1e-10), and loses exactly the mass
  the dense matrix sends off the grid; the 1-D kernel equals its defining
  integral (scipy quadrature); the 2-D kernel has the motion model's mean and
  cross-covariance; a noise-free sub-cell move is split linearly.

Compilation is what costs time here, so every run of ``CONFIG`` uses the same
shapes (T = 60 steps, K = 8 slots, M = 8 map entries) and shares one compiled scan.
"""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate, stats

from jaxnav.demo import demo_setting
from jaxnav.localization import grid, mcl
from jaxnav.models import landmarks as lm
from jaxnav.models import motion
from jaxnav.sim import landmark_world as world
from jaxnav.sim import trajectories

START = jnp.asarray([5.0, 1.5, 0.0])
ROOM = (0.0, 10.0, 0.0, 10.0)
CONFIG = grid.GridConfig(ROOM, 40, 40, 36, "velocity")  # Δ = 0.25 m, Δθ = 10°
CELL = CONFIG.cell_size[0]
BIN = CONFIG.cell_size[2]
STEPS = 60
NUM_CELLS = 40 * 40 * 36


def _params(landmarks=None):
    _, p = demo_setting(10)
    # A strongly typed map: a weakly typed one would compile the scan a second time.
    landmarks = p.landmarks if landmarks is None else landmarks
    return grid.GridParams(p.motion, p.sensor, jnp.asarray(landmarks, jnp.float32))


@functools.cache
def _sim(seed=10):
    params = _params()
    controls = trajectories.loop_controls(STEPS, 0.5, 0.21, 0.25)
    # max_range 20 m > the room's diagonal: every landmark is seen (the symmetric test needs the cut-off,
    # and an equal argument list shares the simulator's compilation).
    key = jax.random.PRNGKey(seed)
    return world.simulate(key, params.landmarks, START, controls, params.motion, params.sensor, max_range=20.0)


def _angle_diff(a, b):
    return np.abs(np.angle(np.exp(1j * (np.asarray(a, np.float64) - np.asarray(b, np.float64)))))


@functools.cache
def _tracking(config):
    params, sim = _params(), _sim()
    _, trace = grid.run(None, grid.init(None, config, params, START), config, params, sim.controls, sim.observations)
    # NumPy float32, as the eager jnp ops were: the same rounding, no small programs compiled.
    err = np.linalg.norm(np.asarray(trace.estimate)[:, :2] - np.asarray(sim.true_poses)[:, :2], axis=1)
    return trace, err, _angle_diff(trace.estimate[:, 2], sim.true_poses[:, 2])


# --------------------------------------------------------------------------- (a) tracking


def test_tracks_a_known_start_to_the_order_of_the_cell_size():
    trace, err, herr = _tracking(CONFIG)
    sim = _sim()
    assert np.sqrt(np.mean(err**2)) < 0.5 * CELL, np.sqrt(np.mean(err**2))
    assert err.max() < CELL, err.max()
    assert herr.max() < BIN, np.degrees(herr.max())
    map_err = np.linalg.norm(np.asarray(trace.map_estimate[:, :2] - sim.true_poses[:, :2]), axis=1)
    assert map_err.max() < CELL  # the MAP cell is the truth's cell or a neighbour
    assert not np.any(trace.degenerate)
    # Away from the walls nothing leaves the grid, and R = 3 holds the whole kernel.
    assert float(trace.mass_lost.max()) < 1e-5 and float(trace.kernel_truncation.max()) < 1e-5
    assert np.all(np.isfinite(trace.log_likelihood))
    assert np.all((trace.entropy >= 0) & (trace.entropy <= math.log(NUM_CELLS)))


def test_negative_control_a_mirrored_bearing_breaks_the_tracking_bounds():
    """The same run with every bearing's sign flipped (a mirrored sensor, a classic bug) fails the
    bounds above, so they have teeth; it reuses the compiled scan."""
    params, sim = _params(), _sim()
    mirrored = sim.observations._replace(z=sim.observations.z.at[:, :, 1].multiply(-1.0))
    _, trace = grid.run(None, grid.init(None, CONFIG, params, START), CONFIG, params, sim.controls, mirrored)
    err = np.linalg.norm(np.asarray(trace.estimate[:, :2] - sim.true_poses[:, :2]), axis=1)
    assert np.sqrt(np.mean(err**2)) > CELL and err.max() > 2 * CELL, (np.sqrt(np.mean(err**2)), err.max())


# --------------------------------------------------------------------------- (b) against MCL


def test_agrees_with_mcl_on_the_same_data():
    sim = _sim()
    trace, _, _ = _tracking(CONFIG)
    m_config, m_params = demo_setting(2000)
    m_state = mcl.init(jax.random.PRNGKey(1), m_config, m_params, START)
    _, m_trace = mcl.run(jax.random.PRNGKey(2), m_state, m_config, m_params, sim.controls, sim.observations)
    gap = np.linalg.norm(np.asarray(trace.estimate[:, :2] - m_trace.estimate[:, :2]), axis=1)
    assert gap.max() < 1.5 * CELL, gap.max()
    assert gap.mean() < 0.5 * CELL, gap.mean()
    assert _angle_diff(trace.estimate[:, 2], m_trace.estimate[:, 2]).max() < BIN


# --------------------------------------------------------------------------- (c) symmetric world


@functools.cache
def _centres():
    return np.asarray(grid.cell_centres(CONFIG))


def _mass_near(log_belief, pose, radius=0.5, heading_tol=0.35):
    cells = _centres()
    p = np.exp(np.asarray(log_belief, np.float64))
    near = (np.linalg.norm(cells[..., :2] - pose[:2], axis=-1) < radius) & (
        _angle_diff(cells[..., 2], pose[2]) < heading_tol
    )
    return p[near].sum()


def test_identical_landmarks_in_a_symmetric_world_give_two_equal_modes():
    """Four identical landmarks, symmetric under a 180° turn about the room centre (5, 5) and under no
    other rotation; uniform start. Observations that cannot tell the landmarks apart (``association=
    "unknown"``) leave two modes of equal mass, at the true pose and at its image
    ``(10 − x, 10 − y, θ + π)``. The same data with known identities (the negative control) give one."""
    half = np.asarray([[3.0, 1.0], [-1.0, 2.5]])
    landmarks = np.concatenate([5.0 + half, 5.0 - half])
    # The world is simulated with the map padded to CONFIG's 8 entries by 4 landmarks far outside the
    # room, out of range (so never observed): the simulator and the known-association run then reuse
    # the compilations of the other tests.
    padded = _params(np.concatenate([landmarks, np.full((4, 2), 50.0)]))
    controls = trajectories.loop_controls(STEPS, 0.5, 0.21, 0.25)
    sim = world.simulate(
        jax.random.PRNGKey(0), padded.landmarks, START, controls, padded.motion, padded.sensor, max_range=20.0
    )
    assert not np.any(sim.observations.mask[:, 4:]) and np.all(sim.observations.mask[:, :4].sum(1) >= 3)
    truth = np.asarray(sim.true_poses[-1])
    image = np.asarray([10.0 - truth[0], 10.0 - truth[1], truth[2] + math.pi])

    params = _params(landmarks)  # the four identical landmarks: the mixture is over these
    unknown = grid.GridConfig(ROOM, 40, 40, 36, "velocity", association="unknown")
    final, trace = grid.run(None, grid.init(None, unknown, params), unknown, params, sim.controls, sim.observations)
    at_truth, at_image = _mass_near(final.log_belief, truth), _mass_near(final.log_belief, image)
    # Grid, motion kernels and likelihood are exactly symmetric: the masses agree to float32 round-off
    # and hold (almost) everything between them.
    assert abs(at_truth - 0.5) < 1e-3 and abs(at_image - 0.5) < 1e-3, (at_truth, at_image)
    # A unimodal summary fails: the mean sits near the centre, far from both modes; the MAP is in one.
    assert np.linalg.norm(np.asarray(trace.estimate[-1, :2]) - 5.0) < CELL
    map_pose = np.asarray(trace.map_estimate[-1])
    assert min(np.linalg.norm(map_pose[:2] - truth[:2]), np.linalg.norm(map_pose[:2] - image[:2])) < CELL

    # Known identities (ids 0–3 index the padded map).
    k_final, k_trace = grid.run(None, grid.init(None, CONFIG, padded), CONFIG, padded, sim.controls, sim.observations)
    k_truth, k_image = _mass_near(k_final.log_belief, truth), _mass_near(k_final.log_belief, image)
    assert k_truth > 0.99 and k_image < 1e-6, (k_truth, k_image)
    # Each mode of the ambiguous belief is a copy of the unambiguous one: entropy + log 2.
    np.testing.assert_allclose(float(trace.entropy[-1]), float(k_trace.entropy[-1]) + math.log(2.0), atol=0.05)


# --------------------------------------------------------------------------- (d) the convolution


def _cic_by_quadrature(m, mean, sd):
    """E[tri(D − m)], D ~ N(mean, sd²), by integrating the tent against the density."""
    if sd == 0:
        return max(0.0, 1.0 - abs(mean - m))
    f = lambda t: max(0.0, 1.0 - abs(t - m)) * stats.norm.pdf(t, mean, sd)  # noqa: E731
    return integrate.quad(f, m - 1.0, m + 1.0, points=[m, mean] if abs(mean - m) < 1 else [m], limit=200)[0]


_cic_1d_jit = jax.jit(grid.cic_1d)


@pytest.mark.parametrize("mean, sd", [(0.3, 0.0), (-0.5, 0.0), (0.37, 0.05), (1.2, 0.4), (-0.1, 1.5), (0.0, 3.0)])
def test_one_dimensional_kernel_is_its_defining_integral(mean, sd):
    """K(m) = E[tri(D − m)]: for σ = 0 the linear split of a fractional shift."""
    offsets = np.arange(-20, 21, dtype=np.float64)
    with jax.enable_x64(True):
        got = np.asarray(_cic_1d_jit(jnp.asarray(offsets), jnp.float64(mean), jnp.float64(sd**2)))
    want = np.asarray([_cic_by_quadrature(m, mean, sd) for m in offsets])
    np.testing.assert_allclose(got, want, atol=1e-9)
    np.testing.assert_allclose(got.sum(), 1.0, atol=1e-9)
    np.testing.assert_allclose(got @ offsets, mean, atol=1e-9)  # the mean move is exact


TINY = grid.GridConfig((0.0, 1.2, 0.0, 1.0), 6, 5, 8, "velocity", kernel_radius=3)  # Δ = 0.2 m, Δθ = 45°
TINY_CONTROL = (0.3, 0.5, 1.0)  # 1.5 cells per step, 0.64 of a heading bin


def _tiny_params(noise=True):
    if noise:
        m = motion.VelocityNoise(jnp.asarray([0.05, 0.01, 0.01, 0.05, 0.0, 0.0]), jnp.asarray([0.03, 0.03, 0.05]))
    else:
        m = motion.VelocityNoise(jnp.zeros(6), jnp.zeros(3))
    p = grid.GridParams(m, lm.RangeBearingNoise(jnp.asarray([0.1, 0.05])), jnp.asarray([[0.0, 0.0]]))
    return jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float64), p)


@jax.jit
def _tiny_predict(log_belief, params, control):
    """The public ``predict`` and ``motion_kernels`` of TINY, compiled together (one compilation)."""
    state = grid.GridState(log_belief)
    return grid.predict(state, TINY, params, control), grid.motion_kernels(TINY, params, control)


def _dense_transition(config, kernels):
    """The K × K matrix T[dst, src] of [A] Alg. 2 line 2, filled cell by cell from the kernels."""
    nx, ny, nt = config.shape
    r = config.kernel_radius
    shift, xy, heading = (np.asarray(a) for a in kernels[:3])
    t = np.zeros((nx, ny, nt, nx, ny, nt))
    for i in range(nx):
        for j in range(ny):
            for k in range(nt):
                for a in range(-r, r + 1):
                    for b in range(-r, r + 1):
                        di, dj = i + shift[k, 0] + a, j + shift[k, 1] + b
                        if 0 <= di < nx and 0 <= dj < ny:  # off the grid: lost
                            t[di, dj, :, i, j, k] += xy[k, r + a, r + b] * heading[k, :]
    return t.reshape(nx * ny * nt, nx * ny * nt)


def test_convolution_prediction_equals_a_dense_transition_and_loses_only_what_leaves():
    belief = np.random.default_rng(0).dirichlet(np.ones(6 * 5 * 8)).reshape(TINY.shape)
    with jax.enable_x64(True):
        log_pred, kernels = _tiny_predict(jnp.asarray(np.log(belief)), _tiny_params(), jnp.asarray(TINY_CONTROL))
        got = np.exp(np.asarray(log_pred))
        kernels = jax.tree_util.tree_map(np.asarray, kernels)
    assert got.dtype == np.float64
    dense = _dense_transition(TINY, kernels)
    want = (dense @ belief.ravel()).reshape(TINY.shape)
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-15)
    assert float(np.max(kernels.truncation)) < 1e-6
    # Mass: each source keeps what its kernel puts on the grid; a good part leaves this small grid.
    kept_per_source = dense.sum(axis=0)
    np.testing.assert_allclose(got.sum(), belief.ravel() @ kept_per_source, rtol=1e-12)
    assert 0.05 < 1.0 - got.sum() < 0.95
    assert np.all(kept_per_source <= 1.0 + 1e-12)
    # A source whose whole kernel stays on the grid keeps all its mass.
    np.testing.assert_allclose(kept_per_source.max(), 1.0, atol=1e-12)


def test_two_dimensional_kernel_has_the_motion_models_mean_and_cross_covariance():
    """Correlated noise (velocity model, diagonal headings): the stencil's mean is the move d/Δ and
    its x-y covariance is Σ_xy/(ΔxΔy); the variances exceed Σ's by the cell-assignment spread."""
    with jax.enable_x64(True):
        control = jnp.asarray(TINY_CONTROL)
        params = _tiny_params()
        kernels = jax.tree_util.tree_map(np.asarray, _tiny_predict(jnp.zeros(TINY.shape), params, control)[1])
        ths = -np.pi + (np.arange(TINY.ntheta) + 0.5) * TINY.cell_size[2]
        poses = jnp.asarray(np.stack([0 * ths, 0 * ths, ths], -1))
        moves = np.asarray(jax.jit(motion.velocity_mean)(poses, control))[:, :2]  # one program, not one per op
        covs = np.asarray(
            jax.jit(jax.vmap(motion.velocity_process_cov, (0, None, None)))(poses, control, params.motion)
        )
    dx, dy, _ = TINY.cell_size
    r = TINY.kernel_radius
    off = np.arange(-r, r + 1, dtype=np.float64)
    for k in range(TINY.ntheta):
        kern = np.asarray(kernels.xy[k])
        np.testing.assert_allclose(kern.sum(), 1.0, atol=1e-12)
        assert kern.min() >= 0.0
        sx, sy = np.asarray(kernels.shift[k])
        mx = kern.sum(1) @ off + sx
        my = kern.sum(0) @ off + sy
        np.testing.assert_allclose([mx, my], moves[k] / [dx, dy], atol=1e-6)
        cxy = np.einsum("ab,a,b->", kern, off + sx - mx, off + sy - my)
        np.testing.assert_allclose(cxy, covs[k, 0, 1] / (dx * dy), atol=1e-6)
        assert abs(covs[k, 0, 1]) / (dx * dy) > 1e-2  # the check has teeth: these headings are correlated
        vx = kern.sum(1) @ (off + sx - mx) ** 2
        vy = kern.sum(0) @ (off + sy - my) ** 2
        assert vx >= covs[k, 0, 0] / dx**2 - 1e-9 and vy >= covs[k, 1, 1] / dy**2 - 1e-9
        # Heading rows: circular, sum to one, mean move ωΔt = 0.5 rad.
        row = np.asarray(kernels.heading[k])
        np.testing.assert_allclose(row.sum(), 1.0, atol=1e-12)
        lag = (np.arange(TINY.ntheta) - k + TINY.ntheta // 2) % TINY.ntheta - TINY.ntheta // 2
        np.testing.assert_allclose(row @ lag, 0.5 / TINY.cell_size[2], atol=1e-6)


def test_a_noise_free_sub_cell_move_is_split_linearly_not_rounded_away():
    """No noise, 0.06 m (≈ 0.3 cell) per step at heading 22.5°: a point mass is shared linearly
    between neighbouring cells (cloud in cell) and, over three steps, its mean moves exactly
    3 × 0.06 m. Rounding each move to the nearest cell would leave it where it was. (The spread it
    acquires, f(1 − f)Δ² per step, is the price of that exact mean: numerical diffusion.)"""
    heading = math.pi / 8  # the centre of bin 4
    fx, fy = 0.06 * math.cos(heading) / 0.2, 0.06 * math.sin(heading) / 0.2
    with jax.enable_x64(True):
        params = _tiny_params(noise=False)
        control = jnp.asarray([0.06, 0.0, 1.0])
        state = grid.init(None, TINY, params, jnp.asarray([0.3, 0.3, heading]))  # the centre of cell (1, 1, 4)
        log_b = state.log_belief
        first = np.exp(np.asarray(_tiny_predict(log_b, params, control)[0]))
        for _ in range(3):
            log_b = _tiny_predict(log_b, params, control)[0]
        p = np.exp(np.asarray(log_b))
    # The kernel's σ is √1e-20 cell, not 0: a ~4e-11 leak to the neighbours.
    np.testing.assert_allclose(first.sum(axis=(1, 2)), [0, 1 - fx, fx, 0, 0, 0], atol=1e-9)
    np.testing.assert_allclose(first.sum(axis=(0, 2)), [0, 1 - fy, fy, 0, 0], atol=1e-9)
    np.testing.assert_allclose(first.sum(axis=(0, 1))[4], 1.0, atol=1e-9)
    np.testing.assert_allclose(p.sum(), 1.0, atol=1e-9)  # three steps: nothing reached the edge yet
    centres = (np.arange(6) + 0.5) * 0.2
    np.testing.assert_allclose(p.sum(axis=(1, 2)) @ centres, 0.3 + 3 * 0.06 * math.cos(heading), atol=1e-9)
    np.testing.assert_allclose(p.sum(axis=(0, 2)) @ centres[:5], 0.3 + 3 * 0.06 * math.sin(heading), atol=1e-9)


# --------------------------------------------------------------------------- correction


def test_factorised_likelihood_equals_landmarks_log_likelihood_at_the_cell_centres():
    params, sim = _params(), _sim()
    obs = jax.tree_util.tree_map(lambda x: x[2], sim.observations)
    obs = obs._replace(ids=obs.ids.at[7].set(99))  # one slot outside the map

    @jax.jit
    def both(params, obs):
        got, ignored = grid.cell_log_likelihood(CONFIG, params, obs)
        positions, valid, _ = lm.lookup(params.landmarks, obs)
        return got, ignored, lm.log_likelihood(grid.cell_centres(CONFIG), positions, obs.z, valid, params.sensor)

    got, ignored, want = both(params, obs)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-2)  # values reach −4e4: float32 round-off
    assert int(ignored) == 1


# --------------------------------------------------------------------------- interface and robustness


def test_run_equals_a_loop_of_steps_and_new_data_never_recompile():
    params, sim = _params(), _sim()
    state = grid.init(None, CONFIG, params, START, jnp.asarray([0.2, 0.2, 0.1]))
    _, trace = grid.run(None, state, CONFIG, params, sim.controls, sim.observations)
    # Same config and shapes: new data, new parameter values and a new prior reuse the compiled scan.
    before = grid.run.trace_count()
    other = _sim(seed=99)
    params2 = params._replace(sensor=lm.RangeBearingNoise(jnp.asarray([0.2, 0.1])))
    grid.run(None, grid.init(None, CONFIG, params2), CONFIG, params2, other.controls, other.observations)
    assert grid.run.trace_count() == before
    s = state
    for t in range(3):
        s, info = grid.step(
            None, s, CONFIG, params, sim.controls[t], jax.tree_util.tree_map(lambda x: x[t], sim.observations)
        )
        for got, want in zip(info, jax.tree_util.tree_map(lambda x: x[t], trace)):
            np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)


def test_masked_and_out_of_map_observations_are_ignored_and_counted():
    """Slot 5 masked, with NaN data; slots 6 and 7 unmasked with ids outside the map (8 and −1)."""
    params, sim = _params(), _sim()
    obs = sim.observations
    masked = obs._replace(mask=obs.mask.at[:, 5:].set(False), z=obs.z.at[:, 5].set(jnp.nan))
    foreign = masked._replace(ids=obs.ids.at[:, 6].set(8).at[:, 7].set(-1), mask=masked.mask.at[:, 6:].set(True))
    state = grid.init(None, CONFIG, params, START)
    _, ref = grid.run(None, state, CONFIG, params, sim.controls, masked)
    _, got = grid.run(None, state, CONFIG, params, sim.controls, foreign)
    np.testing.assert_array_equal(got.estimate, ref.estimate)
    np.testing.assert_array_equal(got.num_ignored, np.full(STEPS, 2))
    np.testing.assert_array_equal(ref.num_ignored, np.zeros(STEPS))
    assert np.all(np.isfinite(ref.estimate))


def test_degenerate_correction_keeps_the_prediction_and_is_flagged_never_nan(monkeypatch):
    """Every cell with zero likelihood keeps the prediction and flags the step. The validated
    inputs cannot reach this branch (a Gaussian log-likelihood of a measurement within the
    magnitude limit is finite, and a larger one is dropped), so the likelihood is replaced here."""
    params, sim = _params(), _sim()
    state = grid.init(None, CONFIG, params, START)
    control, obs = sim.controls[0], jax.tree_util.tree_map(lambda x: x[0], sim.observations)

    def nowhere(config, params, obs):
        return jnp.full(config.shape, -jnp.inf), jnp.zeros((), jnp.int32)

    monkeypatch.setattr(grid, "cell_log_likelihood", nowhere)
    new, info = jax.jit(grid.kernel, static_argnums=2)(None, state, CONFIG, params, control, obs)
    assert bool(info.degenerate) and info.log_likelihood == -np.inf
    predicted = np.asarray(grid.predict(state, CONFIG, params, control))
    predicted = predicted - np.log(np.sum(np.exp(predicted.astype(np.float64))))
    np.testing.assert_allclose(np.asarray(new.log_belief), predicted, rtol=1e-5, atol=1e-5)
    assert np.all(np.isfinite(np.asarray(info.estimate)))


def test_mass_leaving_the_grid_is_reported_and_a_fully_lost_belief_resets_to_uniform():
    params = _params()
    empty = lm.RangeBearingObs(jnp.zeros((STEPS, 8), jnp.int32), jnp.zeros((STEPS, 8, 2)), jnp.zeros((STEPS, 8), bool))
    near_edge = grid.init(None, CONFIG, params, jnp.asarray([9.9, 5.0, 0.0]), jnp.asarray([0.2, 0.2, 0.05]))
    controls = jnp.zeros((STEPS, 3)).at[:, 2].set(0.25)
    controls = controls.at[0, 0].set(0.8).at[1, 0].set(100.0)  # 0.2 m east, then 25 m: everything leaves
    _, trace = grid.run(None, near_edge, CONFIG, params, controls, empty)
    assert 0.3 < float(trace.mass_lost[0]) < 0.9
    np.testing.assert_allclose(float(trace.mass_lost[1]), 1.0)
    np.testing.assert_allclose(float(trace.entropy[1]), math.log(NUM_CELLS), rtol=1e-6)  # reset to uniform
    np.testing.assert_allclose(trace.log_likelihood, 0.0)  # no observation: η = 1
    assert not np.any(trace.degenerate)


def test_uniform_prior_localizes_globally():
    params, sim = _params(), _sim(seed=4)
    _, trace = grid.run(None, grid.init(None, CONFIG, params), CONFIG, params, sim.controls, sim.observations)
    err = np.linalg.norm(np.asarray(trace.estimate[10:, :2] - sim.true_poses[10:, :2]), axis=1)
    assert err.max() < CELL
    assert float(trace.entropy[0]) < 0.5 * math.log(NUM_CELLS)


def test_gaussian_prior_is_the_cell_assigned_gaussian():
    params = _params()
    state = grid.init(None, CONFIG, params, jnp.asarray([4.0, 6.0, 3.1]), jnp.asarray([0.5, 0.3, 0.2]))
    p = np.exp(np.asarray(state.log_belief, np.float64))
    np.testing.assert_allclose(p.sum(), 1.0, atol=1e-5)
    cells = np.asarray(grid.cell_centres(CONFIG), np.float64)
    np.testing.assert_allclose(np.einsum("xyk,xykd->d", p, cells[..., :2]), [4.0, 6.0], atol=1e-4)
    var_x = np.einsum("xyk,xyk->", p, (cells[..., 0] - 4.0) ** 2)
    np.testing.assert_allclose(var_x, 0.5**2 + CELL**2 / 6, rtol=1e-3)  # σ² + E[f(1−f)]Δ²
    # Heading straddles ±π: the circular mean is 3.1, not ~0.
    s = np.einsum("xyk,xyk->", p, np.sin(cells[..., 2]))
    c = np.einsum("xyk,xyk->", p, np.cos(cells[..., 2]))
    assert _angle_diff(math.atan2(s, c), 3.1) < 0.01
    uniform = grid.init(None, CONFIG, params)
    np.testing.assert_allclose(np.asarray(uniform.log_belief), -math.log(40 * 40 * 36), rtol=1e-6)


# --------------------------------------------------------------------------- (e) bad input


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"bounds": (1.0, 0.0, 0.0, 1.0)}, "bounds must be four finite numbers"),
        ({"bounds": (0.0, 1.0, 0.0, math.inf)}, "bounds must be four finite numbers"),
        ({"bounds": (0.0, 1.0, 0.0)}, "bounds must be four finite numbers"),
        ({"bounds": "room"}, "bounds must be four numbers"),
        ({"nx": 0}, "nx must be a positive integer"),
        ({"ny": -3}, "ny must be a positive integer"),
        ({"ntheta": 2.5}, "ntheta must be a positive integer"),
        ({"kernel_radius": 0}, "kernel_radius must be a positive integer"),
        ({"motion_model": "warp"}, "motion_model must be one of"),
        ({"association": "guess"}, "association must be one of"),
    ],
)
def test_bad_config_is_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        grid.GridConfig(**kwargs)


def test_bad_params_state_and_inputs_are_refused_with_the_argument_named():
    params, sim = _params(), _sim()
    state = grid.init(None, CONFIG, params, START)
    run = lambda p=params, c=sim.controls, o=sim.observations, s=state: grid.run(None, s, CONFIG, p, c, o)  # noqa: E731
    with pytest.raises(ValueError, match="params.sensor.sd must be finite and strictly positive"):
        run(p=params._replace(sensor=lm.RangeBearingNoise(jnp.asarray([0.1, 0.0]))))
    with pytest.raises(ValueError, match="motion noise alphas must be finite and non-negative"):
        run(p=params._replace(motion=params.motion._replace(alphas=-params.motion.alphas)))
    with pytest.raises(ValueError, match="params.motion must be a VelocityNoise"):
        run(p=params._replace(motion=motion.OmniNoise(jnp.ones(3))))
    with pytest.raises(ValueError, match=r"params.landmarks must have shape \(\*, 2\)"):
        run(p=params._replace(landmarks=jnp.zeros((3, 3))))
    with pytest.raises(ValueError, match="params.landmarks holds 1 value.* not finite"):
        run(p=params._replace(landmarks=params.landmarks.at[0, 0].set(jnp.nan)))
    with pytest.raises(ValueError, match="params must be a GridParams"):
        run(p=tuple(params))
    with pytest.raises(ValueError, match="config must be a GridConfig"):
        grid.run(None, state, mcl.MCLConfig(), params, sim.controls, sim.observations)
    with pytest.raises(ValueError, match="observations must be a RangeBearingObs"):
        run(o=tuple(sim.observations))
    with pytest.raises(ValueError, match="controls holds 1 value.* not finite"):
        run(c=sim.controls.at[1, 0].set(jnp.nan))
    with pytest.raises(ValueError, match=r"controls must have shape \(\*, 3\)"):
        run(c=jnp.zeros((3, 4)))
    with pytest.raises(ValueError, match="same number of steps"):
        run(c=sim.controls[:2])
    with pytest.raises(ValueError, match=r"state.log_belief must have shape \(40, 40, 36\)"):
        run(s=grid.GridState(state.log_belief[:, :, :10]))
    with pytest.raises(ValueError, match="state.log_belief contains NaN"):
        run(s=grid.GridState(state.log_belief.at[0, 0, 0].set(jnp.nan)))
    with pytest.raises(ValueError, match="initial_pose must lie inside config.bounds"):
        grid.init(None, CONFIG, params, jnp.asarray([11.0, 5.0, 0.0]))
    with pytest.raises(ValueError, match="initial_sd must be finite and non-negative"):
        grid.init(None, CONFIG, params, START, jnp.asarray([0.1, -1.0, 0.1]))
    with pytest.raises(ValueError, match="initial_sd needs an initial_pose"):
        grid.init(None, CONFIG, params, None, jnp.ones(3))
    with pytest.raises(ValueError, match=r"initial_pose must have shape \(3\)"):
        grid.init(None, CONFIG, params, jnp.zeros(2))
