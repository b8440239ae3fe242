"""jaxnav.calibration: fitting a filter's parameters by its log-likelihood, and the gradient estimators
through the filters' resampling (selected by the config's ``gradient``)."""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from jaxnav import calibration
from jaxnav.demo import START, demo_setting
from jaxnav.localization import ekf, mcl, ukf
from jaxnav.models import landmarks as lm
from jaxnav.sim import landmark_world as world
from jaxnav.sim import trajectories

TRUE_SD = (0.2, 0.05)  # range (m) and bearing (rad) noise of the simulated data
TRUE_POSE_SD = (0.04, 0.04, 0.02)  # additive pose noise per step (m, m, rad) of the motion-noise data


def _observed_information(grad, x, step=1e-2):
    """The observed information ``−∇²total(x)`` by central differences of ``grad``, the compiled gradient
    of ``total`` (steps of ``step`` in each coordinate, symmetrised): within 1e-4 of ``jax.hessian``
    here, whose forward-over-reverse program of a 100-step filter takes four times as long to compile."""
    x = jnp.asarray(x)
    rows = [
        (np.asarray(grad(x + step * e), np.float64) - np.asarray(grad(x - step * e), np.float64)) / (2 * step)
        for e in jnp.eye(x.size, dtype=x.dtype)
    ]
    hessian = np.stack(rows)
    return -(hessian + hessian.T) / 2


def _world(num_particles: int, num_steps: int, seed: int = 3):
    config, params = demo_setting(num_particles)
    params = params._replace(sensor=lm.RangeBearingNoise(jnp.asarray(TRUE_SD)))
    controls = trajectories.loop_controls(num_steps, speed=0.5, turn_rate=0.21, dt=0.25)
    sim = world.simulate(
        jax.random.PRNGKey(seed), params.landmarks, jnp.asarray(START), controls, params.motion, params.sensor
    )
    return config, params, sim


SENSOR_ONLY = mcl.MCLParams(motion=False, sensor=True, landmarks=False)
# L-BFGS for the Gaussian filters' exact likelihoods: with a backtracking line search, which reaches
# the same optimum here as optax's default zoom search in as many steps, and compiles in under half
# its time (the zoom search evaluates the objective at three places in its program, this at two).
LBFGS = optax.lbfgs(linesearch=optax.scale_by_backtracking_linesearch(max_backtracking_steps=15))


@jax.jit
def _ekf_log_sd_gradient(key, state, params, data, log_sensor_sd, log_pose_sd, sensor_mask, pose_mask):
    """``∇`` of the EKF's total log-likelihood ``T · exact(key, params)`` in the log noise levels: the
    entries of the sensor's ``sd`` and the motion's ``pose_sd`` where the masks are True are
    ``exp(log_sd)``, the others are ``params``' own. One compiled program serves the observed information
    of both exact fits (the sensor's and the motion's noise), whose data share their shapes."""
    num_steps = jax.tree_util.tree_leaves(data)[0].shape[0]
    exact = calibration.log_likelihood_objective(ekf.kernel, ekf.EKFConfig(), state, data)

    def total(log_sensor_sd, log_pose_sd):
        sensor_sd = jnp.where(sensor_mask, jnp.exp(log_sensor_sd), params.sensor.sd)
        pose_sd = jnp.where(pose_mask, jnp.exp(log_pose_sd), params.motion.pose_sd)
        moved = params._replace(sensor=lm.RangeBearingNoise(sensor_sd), motion=params.motion._replace(pose_sd=pose_sd))
        return exact(key, moved) * num_steps

    return jax.grad(total, argnums=(0, 1))(log_sensor_sd, log_pose_sd)


@functools.partial(jax.jit, static_argnums=0)
def _sensor_sd_gradient(config, key, state, params, data):
    """``∇_σ objective(key, params with the sensor's sd σ)`` of MCL's log-likelihood objective: one compiled
    program per config, shared by the tests that take this gradient."""
    objective = calibration.log_likelihood_objective(mcl.kernel, config, state, data)
    return jax.grad(lambda sd: objective(key, params._replace(sensor=lm.RangeBearingNoise(sd))))(params.sensor.sd)


@functools.partial(jax.jit, static_argnums=2)
def _forward_runs(keys, state, config, params, sim):
    """:func:`calibration_run` of each key: one compiled program per config."""
    return jax.vmap(lambda k: calibration_run(k, state, config, params, sim))(keys)


@pytest.fixture(scope="module")
def small():
    config, params, sim = _world(128, 30)
    state = mcl.init(jax.random.PRNGKey(1), config, params, jnp.asarray(START), jnp.asarray([0.05, 0.05, 0.02]))
    return config, params, sim, state


# --------------------------------------------------------------------------- the estimators in MCL


@pytest.mark.parametrize("threshold", [1.0, 0.5])
def test_score_estimator_leaves_the_forward_pass_unchanged(small, threshold, getkey):
    config, params, sim, state = small
    keys = jax.random.split(getkey(), 3)
    runs = {}
    for g in ("score", "naive"):
        runs[g] = _forward_runs(keys, state, mcl.MCLConfig(128, ess_threshold=threshold, gradient=g), params, sim)
    for a, b in zip(jax.tree_util.tree_leaves(runs["score"]), jax.tree_util.tree_leaves(runs["naive"]), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    if threshold < 1.0:
        resampled = np.asarray(runs["score"][1].resampled)
        assert 0 < resampled.mean() < 1  # the ESS rule decided both ways


def calibration_run(key, state, config, params, sim):
    from jaxnav.core import filter as filter_api

    return filter_api.scan(mcl.kernel, key, state, config, params, sim.controls, sim.observations)


def test_score_and_naive_gradients_differ(small, getkey):
    config, params, sim, state = small
    key = getkey()
    grads = {}
    for g in ("score", "naive"):
        grads[g] = _sensor_sd_gradient(
            mcl.MCLConfig(128, gradient=g), key, state, params, (sim.controls, sim.observations)
        )
    assert not np.allclose(np.asarray(grads["score"]), np.asarray(grads["naive"]))


def _soft_total(theta, key, alpha):
    from jaxnav.core import resampling

    alive = jnp.asarray([True, True, False, True, False, True])
    lw = jnp.where(alive, jnp.asarray([0.1, 0.5, 0.0, 0.2, 0.0, -0.3]) * theta, -jnp.inf)
    lw = lw - jax.nn.logsumexp(lw)
    res = resampling.conditional_resample(key, jnp.arange(6.0)[:, None], lw, gradient="soft", soft_mixing=alpha)
    return jax.nn.logsumexp(res.log_weights + jnp.arange(6.0) * theta)


_soft_gradients = jax.jit(jax.vmap(jax.grad(_soft_total), (None, 0, None)), static_argnums=2)


@pytest.mark.parametrize("alpha", [1.0, 0.5, 0.0])
def test_soft_gradient_is_finite_with_zero_weight_particles(alpha, getkey):
    keys = jax.random.split(getkey(), 16)
    grads = _soft_gradients(1.0, keys, alpha)
    assert np.all(np.isfinite(np.asarray(grads)))


def test_soft_step_that_keeps_no_live_particle_is_flagged_degenerate(getkey):
    """N = 64, one particle of positive weight, α = 0 (the proposal uniform), multinomial: about 37 % of
    the draws pick no live ancestor, and exactly those steps report ``degenerate`` with uniform carried weights; the
    other estimators never flag a step whose update kept a live particle."""
    from jaxnav.core import particle_filter, weights

    n = 64
    norm = weights.normalize(jnp.where(jnp.arange(n) == 5, 0.0, -jnp.inf))
    particles = jnp.arange(float(n))[:, None]

    @functools.partial(jax.jit, static_argnums=1)
    @functools.partial(jax.vmap, in_axes=(0, None))
    def flags(key, gradient):
        res, info = particle_filter.finish_step(
            key, particles, norm, scheme="multinomial", gradient=gradient, soft_mixing=0.0
        )
        return info.degenerate, jnp.any(res.ancestors == 5), res.log_weights

    keys = jax.random.split(getkey(), 200)
    degenerate, kept, carried = flags(keys, "soft")
    degenerate, kept = np.asarray(degenerate), np.asarray(kept)
    np.testing.assert_array_equal(degenerate, ~kept)
    assert 0.2 < degenerate.mean() < 0.55, degenerate.mean()
    np.testing.assert_allclose(np.asarray(carried)[degenerate], -math.log(n), rtol=1e-6)
    for gradient in ("score", "naive"):
        assert not np.any(np.asarray(flags(keys, gradient)[0]))


def test_soft_resampling_carries_importance_weights(small, getkey):
    config, params, sim, state = small
    key = getkey()
    soft = mcl.MCLConfig(128, gradient="soft", soft_mixing=0.3)
    final, trace = mcl.run(key, state, soft, params, sim.controls, sim.observations)
    w = np.exp(np.asarray(final.log_weights, np.float64))
    assert np.all(np.asarray(trace.resampled))
    assert abs(w.sum() - 1.0) < 1e-5 and w.std() > 0  # normalised, and not uniform after resampling
    # α = 1 draws from the weights themselves: the ancestors (and so the particles) of plain resampling
    plain = mcl.run(key, state, mcl.MCLConfig(128, gradient="naive"), params, sim.controls, sim.observations)
    one = mcl.run(
        key, state, mcl.MCLConfig(128, gradient="soft", soft_mixing=1.0), params, sim.controls, sim.observations
    )
    np.testing.assert_array_equal(np.asarray(one[0].particles), np.asarray(plain[0].particles))
    np.testing.assert_allclose(np.asarray(one[0].log_weights), np.asarray(plain[0].log_weights), atol=1e-5)


@pytest.mark.parametrize("gradient", ["score", "soft", "naive"])
def test_every_estimator_gives_a_finite_gradient(small, gradient, getkey):
    config, params, sim, state = small
    cfg = mcl.MCLConfig(128, gradient=gradient)
    g = _sensor_sd_gradient(cfg, getkey(), state, params, (sim.controls, sim.observations))
    assert np.all(np.isfinite(np.asarray(g))) and np.any(np.asarray(g) != 0)


@pytest.mark.parametrize(
    ("field", "value"), [("gradient", "reinforce"), ("gradient", None), ("soft_mixing", 1.5), ("soft_mixing", True)]
)
def test_config_refuses_an_unknown_estimator(field, value):
    with pytest.raises(ValueError, match=field):
        mcl.MCLConfig(128, **{field: value})


# --------------------------------------------------------------------------- fitting


@pytest.mark.slow
def test_fit_recovers_the_sensor_noise_from_three_times_too_large(getkey):
    """Data simulated with σ = (0.2 m, 0.05 rad); MCL (score estimator, Adam) and the EKF (its exact
    likelihood, L-BFGS) start from 3σ. Their sampling error: the standard error of the EKF's maximum
    likelihood estimate of log σ, from the observed information (the Hessian of the log-likelihood),
    about 2.3 % here. Both fits must lie within 3 standard errors of the truth, and the particle
    filter's optimum within half a standard error of the exact likelihood's (over six keys it lay
    0.16–0.21 standard errors above it, with 200 particles and 2 filters per step)."""
    num_steps = 100
    config, params, sim = _world(200, num_steps)
    wrong = params._replace(sensor=lm.RangeBearingNoise(3.0 * params.sensor.sd))
    data = (sim.controls, sim.observations)
    state = mcl.init(jax.random.PRNGKey(1), config, params, jnp.asarray(START), jnp.asarray([0.05, 0.05, 0.02]))
    objective = calibration.log_likelihood_objective(mcl.kernel, config, state, data, num_seeds=2)
    schedule = optax.cosine_decay_schedule(0.05, 80, alpha=0.1)  # smaller steps at the end: less gradient noise
    fitted = calibration.fit(
        objective, getkey(), wrong, trainable=SENSOR_ONLY, steps=80, optimizer=optax.adam(schedule)
    )

    ekf_config = ekf.EKFConfig()
    ekf_state = ekf.init(None, ekf_config, params, jnp.asarray(START), jnp.diag(jnp.asarray([0.05, 0.05, 0.02]) ** 2))
    exact = calibration.log_likelihood_objective(ekf.kernel, ekf_config, ekf_state, data)
    best = calibration.fit(exact, getkey(), wrong, trainable=SENSOR_ONLY, steps=8, optimizer=LBFGS)

    ukf_config = ukf.UKFConfig()
    ukf_state = ukf.init(None, ukf_config, params, jnp.asarray(START), jnp.diag(jnp.asarray([0.05, 0.05, 0.02]) ** 2))
    unscented = calibration.log_likelihood_objective(ukf.kernel, ukf_config, ukf_state, data)
    sigma_points = calibration.fit(unscented, getkey(), wrong, trainable=SENSOR_ONLY, steps=8, optimizer=LBFGS)

    key = getkey()

    def grad(log_sd):  # of total(log_sd) = T · exact(key, params with the sensor's sd exp(log_sd))
        no_pose = jnp.zeros(3, log_sd.dtype)
        masks = (jnp.ones(2, bool), jnp.zeros(3, bool))
        return _ekf_log_sd_gradient(key, ekf_state, params, data, log_sd, no_pose, *masks)[0]

    log_ekf = jnp.log(best.params.sensor.sd)
    information = _observed_information(grad, log_ekf)
    se = np.sqrt(np.diag(np.linalg.inv(information)))
    assert np.all(se < 0.05), se  # the data do pin the noise down
    log_true = np.log(TRUE_SD)
    log_mcl = np.log(np.asarray(fitted.params.sensor.sd))
    assert np.all(np.abs(np.asarray(log_ekf) - log_true) < 3 * se), (best.params.sensor.sd, se)
    assert np.all(np.abs(log_mcl - log_true) < 3 * se), (fitted.params.sensor.sd, se)
    assert np.all(np.abs(log_mcl - np.asarray(log_ekf)) < 0.5 * se), (fitted.params.sensor.sd, best.params.sensor.sd)
    log_ukf = np.log(np.asarray(sigma_points.params.sensor.sd))
    assert np.all(np.abs(log_ukf - np.asarray(log_ekf)) < se), (sigma_points.params.sensor.sd, best.params.sensor.sd)
    assert sigma_points.losses[-1] < sigma_points.losses[0]
    assert fitted.losses[-1] < fitted.losses[0]
    np.testing.assert_array_equal(fitted.trace.landmarks[-1], np.asarray(params.landmarks))  # not trained
    np.testing.assert_allclose(fitted.trace.sensor.sd[-1], np.asarray(fitted.params.sensor.sd), rtol=1e-6)


def test_exact_fit_recovers_the_motion_noise_from_three_times_too_large(getkey):
    """Data simulated with additive pose noise σ = (0.04 m, 0.04 m, 0.02 rad) per step and an accurate
    sensor (0.02 m, 0.01 rad), which measures each pose far better than a step's noise moves it: the
    EKF's exact likelihood, fitted by L-BFGS from 3σ, lands within 3 standard errors of the truth
    (about 8 % of σ, from the observed information). The guide says why MCL with few particles does
    not (its likelihood estimate is biased low where the motion noise is small)."""
    num_steps = 100
    config, params, _ = _world(8, num_steps)
    params = params._replace(
        motion=params.motion._replace(pose_sd=jnp.asarray(TRUE_POSE_SD)),
        sensor=lm.RangeBearingNoise(jnp.asarray([0.02, 0.01])),
    )
    controls = trajectories.loop_controls(num_steps, speed=0.5, turn_rate=0.21, dt=0.25)
    sim = world.simulate(
        jax.random.PRNGKey(3), params.landmarks, jnp.asarray(START), controls, params.motion, params.sensor
    )
    wrong = params._replace(motion=params.motion._replace(pose_sd=3.0 * params.motion.pose_sd))
    pose_sd_only = mcl.MCLParams(
        motion=params.motion._replace(alphas=False, pose_sd=True), sensor=False, landmarks=False
    )
    ekf_config = ekf.EKFConfig()
    state = ekf.init(None, ekf_config, params, jnp.asarray(START), jnp.diag(jnp.asarray([0.05, 0.05, 0.02]) ** 2))
    data = (sim.controls, sim.observations)
    exact = calibration.log_likelihood_objective(ekf.kernel, ekf_config, state, data)
    best = calibration.fit(exact, getkey(), wrong, trainable=pose_sd_only, steps=10, optimizer=LBFGS)

    key = getkey()

    def grad(log_sd):  # of total(log_sd) = T · exact(key, params with the motion's pose_sd exp(log_sd))
        no_sensor = jnp.zeros(2, log_sd.dtype)
        masks = (jnp.zeros(2, bool), jnp.ones(3, bool))
        return _ekf_log_sd_gradient(key, state, params, data, no_sensor, log_sd, *masks)[1]

    log_fit = np.log(np.asarray(best.params.motion.pose_sd))
    information = _observed_information(grad, log_fit)
    se = np.sqrt(np.diag(np.linalg.inv(information)))
    assert np.all(se < 0.15), se  # the data do pin the motion noise down
    assert np.all(np.abs(log_fit - np.log(TRUE_POSE_SD)) < 3 * se), (best.params.motion.pose_sd, se)
    np.testing.assert_array_equal(np.asarray(best.params.motion.alphas), np.asarray(params.motion.alphas))


def test_fit_is_deterministic_and_compiles_once(small, getkey):
    config, params, sim, state = small
    traces = []
    inner = calibration.log_likelihood_objective(mcl.kernel, config, state, (sim.controls, sim.observations))

    def objective(key, p):
        traces.append(1)  # runs once per trace, not per step
        return inner(key, p)

    key = getkey()
    first = calibration.fit(objective, key, params, trainable=SENSOR_ONLY, steps=4)
    assert len(traces) == 1
    second = calibration.fit(objective, key, params, trainable=SENSOR_ONLY, steps=4)
    np.testing.assert_array_equal(first.losses, second.losses)
    np.testing.assert_array_equal(np.asarray(first.params.sensor.sd), np.asarray(second.params.sensor.sd))
    assert first.losses.shape == (4,) and first.trace.sensor.sd.shape == (5, 2)


def test_a_line_search_fit_compiles_its_step_once(small):
    """L-BFGS's state starts with a weak-typed line-search counter that its first update returns strongly
    typed; ``fit`` fixes the types up front, so every step reuses the first step's program (the objective
    is traced as often in a 3-step fit as in a 1-step one)."""
    _, params, sim, _ = small
    state = ekf.init(None, ekf.EKFConfig(), params, jnp.asarray(START), jnp.diag(jnp.asarray([0.05, 0.05, 0.02]) ** 2))
    inner = calibration.log_likelihood_objective(ekf.kernel, ekf.EKFConfig(), state, (sim.controls, sim.observations))
    traces = []

    def objective(key, p):
        traces.append(1)  # once per trace of the objective (the gradient's and the line search's)
        return inner(key, p)

    counts = []
    for steps in (1, 3):
        traces.clear()
        calibration.fit(objective, jax.random.PRNGKey(0), params, trainable=SENSOR_ONLY, steps=steps, optimizer=LBFGS)
        counts.append(len(traces))
    assert counts[0] > 0 and counts[1] == counts[0], counts


def test_fit_trains_the_chosen_entries_only(small, getkey):
    config, params, sim, state = small
    objective = calibration.log_likelihood_objective(
        mcl.kernel, config, state, (sim.controls, sim.observations), num_seeds=2
    )
    alphas = np.asarray(params.motion.alphas)
    mask = mcl.MCLParams(
        motion=type(params.motion)(alphas=alphas > 0, pose_sd=False), sensor=np.array([True, False]), landmarks=False
    )
    out = calibration.fit(objective, getkey(), params, trainable=mask, steps=3)
    new_alphas = np.asarray(out.params.motion.alphas)
    np.testing.assert_array_equal(new_alphas[alphas == 0], 0.0)  # zeros kept (the log transform cannot reach them)
    assert np.all(new_alphas[alphas > 0] != alphas[alphas > 0])
    assert out.params.sensor.sd[1] == params.sensor.sd[1] and out.params.sensor.sd[0] != params.sensor.sd[0]
    np.testing.assert_array_equal(np.asarray(out.params.landmarks), np.asarray(params.landmarks))


def test_fit_accepts_an_optax_optimizer_and_a_minibatch(small, getkey):
    config, params, sim, state = small  # the module's world: no simulation of its own to compile
    stack = lambda tree: jax.tree_util.tree_map(lambda x: jnp.stack([x, x, x]), tree)  # noqa: E731
    objective = calibration.log_likelihood_objective(
        mcl.kernel, config, stack(state), stack((sim.controls, sim.observations)), batched=True, batch_size=2
    )
    out = calibration.fit(objective, getkey(), params, trainable=SENSOR_ONLY, steps=2, optimizer=optax.sgd(1e-3))
    assert np.all(np.isfinite(out.losses))


def test_fit_takes_an_optax_line_search_and_a_schedule(small, getkey):
    config, params, sim, state = small
    objective = calibration.log_likelihood_objective(mcl.kernel, config, state, (sim.controls, sim.observations))
    out = calibration.fit(objective, getkey(), params, trainable=SENSOR_ONLY, steps=2, optimizer=LBFGS)
    assert np.all(np.isfinite(out.losses))
    schedule = optax.linear_schedule(0.05, 0.01, 2)
    out = calibration.fit(objective, getkey(), params, trainable=SENSOR_ONLY, steps=2, learning_rate=schedule)
    assert np.all(np.isfinite(out.losses))
    np.testing.assert_array_equal(out.trace.sensor.sd[0], np.asarray(params.sensor.sd))  # the values passed


def _bad_fit(small, **overrides):
    config, params, sim, state = small
    objective = calibration.log_likelihood_objective(mcl.kernel, config, state, (sim.controls, sim.observations))
    kwargs = dict(trainable=SENSOR_ONLY, steps=1) | overrides
    return calibration.fit(objective, jax.random.PRNGKey(0), kwargs.pop("params", params), **kwargs)


@pytest.mark.parametrize(
    ("overrides", "match"),
    [
        (dict(trainable=False), "nothing to fit"),
        (dict(trainable=mcl.MCLParams(motion=False, sensor="yes", landmarks=False)), "trainable"),
        (dict(trainable=True), r"params.*landmarks.*<= 0|params\.motion.*<= 0"),
        (dict(transform="exp"), "transform"),
        (dict(steps=-1), "steps"),
        (dict(steps=1.5), "steps"),
        (dict(learning_rate=math.nan), "learning_rate"),
        (dict(learning_rate=-1.0), "learning_rate"),
        (dict(optimizer="sgd"), "optimizer"),
        (dict(params=None), "nothing to fit"),
        (dict(params=None, trainable=True), "nothing to fit"),
    ],
)
def test_fit_refuses_bad_arguments_by_name(small, overrides, match):
    with pytest.raises(ValueError, match=match):
        _bad_fit(small, **overrides)


def test_fit_refuses_a_bad_key(small):
    config, params, sim, state = small
    objective = calibration.log_likelihood_objective(mcl.kernel, config, state, (sim.controls, sim.observations))
    with pytest.raises(ValueError, match="key"):
        calibration.fit(objective, None, params, trainable=SENSOR_ONLY, steps=1)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [(dict(num_seeds=0), "num_seeds"), (dict(batched=True, batch_size=5), "batch_size"), (dict(inputs=()), "inputs")],
)
def test_objective_refuses_bad_arguments_by_name(small, kwargs, match):
    config, params, sim, state = small
    inputs = kwargs.pop("inputs", (sim.controls, sim.observations))
    if kwargs.get("batched"):
        state, inputs = jax.tree_util.tree_map(lambda x: jnp.asarray(x)[None], (state, inputs))
    with pytest.raises(ValueError, match=match):
        calibration.log_likelihood_objective(mcl.kernel, config, state, inputs, **kwargs)


@pytest.mark.parametrize("model", ["velocity", "odometry"])
def test_motion_noise_gradient_is_finite_when_the_robot_stands_still(model, getkey):
    """√variance of a control's noise at zero variance (a robot standing still, or α's that are zero) must
    not make the α gradient NaN: its derivative there is taken as 0."""
    from jaxnav.models import motion

    poses = jnp.zeros((16, 3))
    if model == "velocity":
        control, noise = jnp.asarray([0.0, 0.0, 0.1]), motion.VelocityNoise(jnp.full(6, 0.01), jnp.full(3, 0.01))
    else:
        control, noise = jnp.zeros(6), motion.OdometryNoise(jnp.full(4, 0.01), jnp.full(3, 0.01))
    sample = motion.get_motion_model(model).sample
    key = getkey()
    grad = jax.jit(jax.grad(lambda a: jnp.sum(sample(key, poses, control, noise._replace(alphas=a)) ** 2)))(
        noise.alphas
    )
    assert np.all(np.isfinite(np.asarray(grad)))
