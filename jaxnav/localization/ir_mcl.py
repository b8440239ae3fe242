"""Monte Carlo localization under IR ceiling emitters, [W] Alg. 3 (§5.2).

**Overview**

The robot carries ``R`` upward-looking IR receivers (two in [W], one on each
side of the robot top, Fig. 5.4) and localises against ceiling emitters of
known positions (:class:`jaxnav.models.ir_layouts.EmitterLayout`): unique-ID LED
arrays and repeated-ID single LEDs ([W] §5.1). A receiver window yields at
most one emitter ID and the level ``V`` (V) read for it
(:class:`jaxnav.models.ir.IRDetection`).

[W] Alg. 3, with where each line lives here:

* line 1 — *initialise* the particle set: :func:`init` draws ``N``
  (1,000 in [W] §5.4) poses uniform over the area, heading uniform
  ("the particles are initialized by randomly distributing in the
  environment", §5.2);
* lines 2–4 — *move* every particle with the motion model (``[W]`` eq. 3.6,
  the omnidirectional model; ``omni_body`` by default, see
  :class:`IRMCLConfig`);
* line 5 — if emitter ``n`` is detected (per receiver: ``detection.valid``
  and its ID carried by some emitter of the layout);
* lines 6–11 — if its ID is repeated, the belief of [W] eq. 5.1,
  ``bel_n = exp(−|x_n − x_r|² / 2σ²)``, is evaluated at every emitter ``n``
  with that ID and the one with the largest belief is taken as ``x_e``:
  the emitter nearest the estimate (:func:`jaxnav.models.ir.select_emitter`;
  ``x_r`` is the estimated position of the detecting receiver, computed from
  the predicted pose estimate, the weighted mean of the moved particles). A
  unique ID names its emitter directly;
* lines 12–14 — weight every particle by the likelihood of [W] eq. 5.2 in
  log form, ``log w += log α − (V − V̄(e_d))² / (2σ_V²)``, with ``e_d`` the
  horizontal distance (mm in eq. 5.3) from *that particle's* receiver position
  to ``x_e`` and ``V̄`` the voltage curve of eq. 5.3
  (:func:`jaxnav.models.ir.log_likelihood`). The receivers' terms add (they
  are independent given the pose);
* lines 16–20 — resample (systematic by default);
* the estimate is [W] eq. 5.4, the weighted mean of the particles (heading on
  the circle), taken after the weighting and before resampling.

Start of localization. [W] §5.2: "because the robot starts without known
initialized position and orientation values, the belief of the repeated ID
encoding emitters cannot be calculated at the beginning. The estimation of
the robot localization starts when a unique ID encoding emitter is
recognized." So until the first valid unique-ID detection the filter only
moves its particles: repeated-ID detections are ignored (counted in
``info.num_ignored``), the weights stay uniform, nothing is resampled, and
``state.started`` / ``info.started`` are False.

At the first unique-ID detection (receiver ``r0``, emitter ``e``) the
particles are **re-drawn** from the posterior of that detection under the
uniform prior of line 1: ``K·N`` candidates (``K = config.redraw_factor``,
16) with heading uniform on the circle and receiver ``r0`` at
``e + e_d (cos φ, sin φ)``, ``φ`` uniform and ``e_d ∈ [0,
detection_range]`` with density ``∝ e_d · exp(ℓ(V | e_d))`` (eq. 5.2 times
the polar area element); the other receivers' detections weight the
candidates, and ``N`` are kept by systematic resampling. Alg. 3 does not
spell this step out. It targets exactly [W]'s uniform set weighted by the
step's detections (a uniform prior times a likelihood that vanishes beyond
the range), but a uniform set of 1,000 poses over the 3.2 × 1.6 m area puts
~50 of them inside a 0.28 m disc, and with the heading free far fewer near
the one-dimensional set of poses consistent with both receivers' levels: the
filter then keeps a handful of headings, loses the true one, and diverges
at the next emitter (a first version of this module, re-drawing ``N``
poses uniform on the disc, diverged in 2 of 4 seeded runs at 1.2 m).
``info.reinitialised`` marks that step.

Heading. One emitter's levels are invariant to rotating the robot about the
emitter, so the heading is unobservable until a second emitter is seen
(0.8 m on in [W]'s lattice); the particles carry a ring of hypotheses
around the first emitter until then, and the estimate (a weighted mean)
means little. ``config.restart_when_lost`` (default True; not in [W])
repeats the re-draw after the start at a unique-ID detection that no
particle can explain (no particle's receiver within ``detection_range`` of
that emitter): the unique ID says where the robot is, and a filter that has
lost it recovers there instead of drifting on. In our runs it is rare at
1.2 m and rescues the runs with a ±0.1 m height error.

A detection beyond the range. ``V̄`` of eq. 5.3 is a fit over 0–300 mm and
crosses zero at the detection range (283.6 mm for [W]'s coefficients); a
particle whose receiver is farther than ``params.detection_range`` from
``x_e`` contradicts the detection. It gets the log-likelihood
``params.log_floor`` (default −50), and no particle's term falls below it:
a finite floor, not −∞, so that a detection that no particle explains (e.g.
an emitter picked wrongly by the belief while the estimate is off by more
than half the distance between two emitters of one ID) leaves the weights
as they were instead of producing NaN; ``info.degenerate`` stays False.

Noise. ``params.sigma_v`` is σ of eq. 5.2, which [W] does not give. The
simulated receiver's level noise is 0.01–0.05 V
(:mod:`jaxnav.sim.ir_receiver`), its physical model differs from eq. 5.3 by
up to 0.085 V at 1.2 m, and a height change of ±0.1 m ([W] Table 5.3) moves
the level under an emitter by ∓0.2 V. The default is **0.2 V**: on the
60 s experiment drive of ``tests/localization/test_ir_mcl.py`` (6 seeds) σ = 0.1 V gives
10 mm late error at 1.2 m but diverges in most runs at 1.3 m, σ = 0.2 V
gives 13 mm at 1.2 m and ~30 mm at 1.1 and 1.3 m (Table 5.3's shape),
σ = 0.3 V 16 mm at 1.2 m. A σ below the model error makes the filter
over-confident in eq. 5.3.

Not used: the absence of a detection (a particle under an emitter that the
receiver does not see) carries information that [W] does not use either.

The sensor. The receivers' likelihood and the attribution of a detection to its emitter are
:mod:`jaxnav.models.ir_sensor`'s, whose :data:`~jaxnav.models.ir_sensor.IR_RECEIVERS` runs them in
plain MCL too. This filter is not MCL with that sensor because of what is its own: the start at the
first unique ID and the restart when lost replace the particle set in the middle of a step (a
``lax.cond`` between the move and the weighting), and a repeated ID is attributed by the weights
carried from the last step, which MCL's sensor seam does not see.

Interface (shared by every jaxnav filter)::

    state = ir_mcl.init(key, config, params, area)
    state, info = ir_mcl.step(key, state, config, params, control, detection)
    final_state, trace = ir_mcl.run(key, state, config, params, controls, detections)

``run`` scans ``step`` over time with step key ``fold_in(key, t)``; a loop of
:func:`step` calls with those keys gives the same result. Shapes are fixed
by ``config.num_particles`` and the number of receivers ``R`` (the rows of
``params.offsets``); detections are masked, never dropped.

Units: m, rad, s, V (e_d in mm only inside eq. 5.3's coefficients).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import filter as filter_api
from jaxnav.core import gradients, memory, resampling, rng, weights
from jaxnav.core.particle_filter import PFInfo, extend_info, finish_step, keep_finite
from jaxnav.core.validation import (
    check_choice,
    check_fraction,
    check_positive_int,
    check_shape,
)
from jaxnav.models import ir, ir_sensor
from jaxnav.models.ir import IRDetection
from jaxnav.models.motion import (
    MODELS,
    OdometryNoise,
    OmniNoise,
    VelocityNoise,
    controls_in_domain,
    get_motion_model,
    noise_in_domain,
    validate_controls,
)
from jaxnav.models.motion import validate_noise as validate_motion_noise

__all__ = [
    "IRMCLConfig",
    "IRMCLParams",
    "IRMCLState",
    "IRMCLInfo",
    "DEFAULT_SIGMA_V",
    "DEFAULT_LOG_FLOOR",
    "model_range",
    "default_params",
    "init",
    "kernel",
    "step",
    "run",
]

_ANGLE_DIMS = (2,)

DEFAULT_SIGMA_V = 0.2
"""σ of [W] eq. 5.2 (V); [W] gives none (module docstring, "Noise")."""

DEFAULT_LOG_FLOOR = -50.0
"""Log-likelihood of a particle that contradicts a detection (the eq. 5.2 value of a 10σ residual)."""


@dataclass(frozen=True)
class IRMCLConfig:
    """Static configuration (hashable; a static argument of ``jit``).

    Attributes:
        num_particles: N (1,000 in [W] §5.4).
        motion_model: name in :data:`jaxnav.models.motion.MODELS`. Default
            ``"omni_body"``: [W] Alg. 3 line 3 moves the particles with
            eq. 3.6, the omnidirectional model ``x_t = x_{t−1} + V·Δt + ε·Δt``,
            and [W]'s robot is holonomic (it drives the trajectories of
            §5.4.1–5.4.2 with its heading held at 0). ``omni_body`` takes
            ``V = (v_x, v_y, ω)`` in the robot frame — what wheel odometry
            measures — and rotates it by each particle's heading; the
            world-frame ``omni`` would need the heading the filter starts
            without. The control is ``(v_x, v_y, ω, Δt)``
            (:mod:`jaxnav.sim.ir_world` makes it).
        resampling: name in :data:`jaxnav.core.resampling.SCHEMES`.
        ess_threshold: at a step that weighted the particles, resample when
            ESS < ``ess_threshold · N``; in (0, 1]; 1.0 (default) resamples
            at every such step, as Alg. 3 lines 16–20. A step without a
            detection leaves the weights as they are and does not resample.
        redraw_factor: ``K``; at the first unique-ID detection the particles
            are re-drawn from ``K·N`` candidates around the detected emitter
            (module docstring, "Start of localization").
        restart_when_lost: repeat that re-draw after the start at a unique-ID
            detection that no particle can explain (not in [W]; module
            docstring, "Heading").
        gradient: how ``jax.grad`` of the log-likelihood passes resampling, a name in
            :data:`jaxnav.core.gradients.GRADIENT_ESTIMATORS` (default ``"score"``, the forward pass
            unchanged; :mod:`jaxnav.core.gradients`).
        soft_mixing: ``α`` in ``[0, 1]`` of ``"soft"`` resampling; unused by the other estimators.
    """

    # the fields that size the state, named when it is too large (jaxnav.core.memory)
    SIZE_FIELDS: ClassVar[tuple[str, ...]] = ("num_particles",)
    num_particles: int = 1000
    motion_model: str = "omni_body"
    resampling: str = "systematic"
    ess_threshold: float = 1.0
    redraw_factor: int = 16
    restart_when_lost: bool = True
    gradient: str = "score"
    soft_mixing: float = 0.5

    def __post_init__(self) -> None:
        check_positive_int("num_particles", self.num_particles)
        check_positive_int("redraw_factor", self.redraw_factor)
        check_choice("motion_model", self.motion_model, MODELS)
        check_choice("resampling", self.resampling, resampling.SCHEMES)
        check_fraction("ess_threshold", self.ess_threshold)
        gradients.check_gradient(self.gradient, self.soft_mixing)


class IRMCLParams(NamedTuple):
    """Differentiable parameters (use :func:`default_params`).

    Attributes:
        motion: noise of the configured motion model (``OmniNoise`` for
            ``omni_body``: sd of ``(v_x, v_y, ω)``, m/s, m/s, rad/s).
        layout: the ceiling emitters (positions in m, ID bitmasks).
        voltage: the mean-voltage curve ``V̄(e_d)`` ([W] eq. 5.3; e_d in mm).
        sigma_v: σ of eq. 5.2 (V).
        offsets: ``[R, 2]`` receiver positions in the robot frame (m; x
            forward, y left).
        detection_range: horizontal receiver–emitter distance (m) beyond which
            a detection contradicts a particle; the disc of the
            re-initialisation. Default :func:`model_range` of ``voltage``.
        log_floor: log-likelihood given to a contradicting particle, and the
            lowest per-receiver term (module docstring).
    """

    motion: Any
    layout: ir.EmitterLayout
    voltage: ir.VoltageModel
    sigma_v: jax.Array
    offsets: jax.Array
    detection_range: jax.Array
    log_floor: jax.Array


class IRMCLState(NamedTuple):
    """Filter state carried between steps.

    Attributes:
        particles: ``[N, 3]`` poses (m, m, rad).
        log_weights: ``[N]`` normalised log-weights.
        started: bool, a unique ID has been detected and localization runs.
    """

    particles: jax.Array
    log_weights: jax.Array
    started: jax.Array


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class IRMCLInfo(PFInfo):
    """Per-step diagnostics (stacked over time by :func:`run`).

    Attributes:
        estimate: ``[3]`` weighted mean pose after the update ([W] eq. 5.4;
            circular θ). Before the start it is the mean of a uniform cloud,
            meaningless: check ``started``.
        ess: effective sample size after the update, before resampling.
        resampled: bool, whether this step resampled.
        log_likelihood: log of the weighted mean likelihood of the step's
            detections, the log marginal-likelihood increment (0 when none
            was applied, and at a re-draw, whose detections shaped the set).
        degenerate: bool, every particle had zero likelihood (only with a
            NaN input; the floor prevents it otherwise); weights were reset.
        started: bool, the state's ``started`` after this step.
        reinitialised: bool, this step re-drew the particles at the first
            unique-ID detection.
        num_detections: int32, detections used to weight the particles.
        num_ignored: int32, valid detections not used (a repeated ID before
            the start, an ID no emitter of the layout carries, or a level that is negative,
            not finite or beyond :data:`jaxnav.models.ir.MAX_VOLTAGE`, which the host refuses,
            so only inside a caller's ``jit``).
        emitter: ``[R]`` int32 index of the emitter each receiver's detection
            was attributed to (eq. 5.1; −1 when the receiver's detection was
            not used).
        invalid_inputs: bool, the step's control or parameters were outside the models' domain (a
            negative Δt or noise level, a value that is not finite or exceeds
            :data:`~jaxnav.core.validation.MAX_MAGNITUDE`), refused on the host, so only inside a
            caller's ``jit``: the state was carried over unchanged.
    """

    started: jax.Array
    reinitialised: jax.Array
    num_detections: jax.Array
    num_ignored: jax.Array
    emitter: jax.Array
    invalid_inputs: jax.Array = False


# ---------------------------------------------------------------------------
# parameters


def model_range(voltage: ir.VoltageModel) -> jax.Array:
    """Where ``V̄(e_d)`` of a concave quadratic crosses zero beyond its peak (m).

    The positive root of ``c2·e² + c1·e + c0 = 0`` (e in mm, ``c2 < 0``,
    ``c0 > 0``): 0.2836 m for [W] eq. 5.3, [W]'s "within 280 mm".
    """
    c2, c1, c0 = (jnp.asarray(c, jnp.float32) for c in voltage)
    disc = jnp.sqrt(jnp.maximum(c1 * c1 - 4.0 * c2 * c0, 0.0))
    return (-c1 - disc) / (2.0 * c2) / 1000.0


_DEFAULT_MOTION = {
    # sd of the robot-frame velocity noise ε of eq. 3.6 (m/s, m/s, rad/s): covers the simulated
    # odometry error of jaxnav.sim.ir_world (0.03 white + 4 % scale at 0.2 m/s) with margin
    "omni_body": lambda: OmniNoise(jnp.asarray([0.05, 0.05, 0.05], jnp.float32)),
    "omni": lambda: OmniNoise(jnp.asarray([0.05, 0.05, 0.05], jnp.float32)),
    "velocity": lambda: VelocityNoise(
        jnp.asarray([0.05, 0.0, 0.0, 0.05, 0.0, 0.0], jnp.float32), jnp.asarray([0.005, 0.005, 0.005], jnp.float32)
    ),
    "odometry": lambda: OdometryNoise(
        jnp.asarray([0.05, 0.01, 0.05, 0.01], jnp.float32), jnp.asarray([0.005, 0.005, 0.005], jnp.float32)
    ),
}


def default_params(config: IRMCLConfig, layout: ir.EmitterLayout, **overrides: Any) -> IRMCLParams:
    """Parameters for ``layout`` with [W]'s eq. 5.3 and our stated defaults; keywords replace fields.

    Defaults: ``voltage = W_VOLTAGE_MODEL``, ``sigma_v = 0.2`` V
    (:data:`DEFAULT_SIGMA_V`), ``offsets = DEFAULT_RECEIVER_OFFSETS``
    ((0, ±0.10) m), ``detection_range = model_range(voltage)``,
    ``log_floor = −50``, and a motion noise for ``config.motion_model``
    (``omni_body``: sd 0.05 m/s, 0.05 m/s, 0.05 rad/s). Validated.
    """
    if not isinstance(config, IRMCLConfig):
        raise ValueError(f"config must be an IRMCLConfig, got {type(config).__name__}")
    fields = set(IRMCLParams._fields) - {"layout"}
    unknown = set(overrides) - fields
    if unknown:
        raise ValueError(f"unknown IR-MCL parameters {sorted(unknown)}; fields are {sorted(fields)}")
    voltage = overrides.get("voltage", ir.W_VOLTAGE_MODEL)
    voltage = ir.VoltageModel(*(jnp.asarray(c, jnp.float32) for c in voltage))
    motion = overrides.get("motion")
    if motion is None:
        motion = _DEFAULT_MOTION[config.motion_model]()
    params = IRMCLParams(
        motion=motion,
        layout=layout,
        voltage=voltage,
        sigma_v=jnp.asarray(overrides.get("sigma_v", DEFAULT_SIGMA_V), jnp.float32),
        offsets=jnp.asarray(overrides.get("offsets", ir.DEFAULT_RECEIVER_OFFSETS), jnp.float32),
        detection_range=jnp.asarray(
            overrides["detection_range"] if "detection_range" in overrides else model_range(voltage), jnp.float32
        ),
        log_floor=jnp.asarray(overrides.get("log_floor", DEFAULT_LOG_FLOOR), jnp.float32),
    )
    _validate_params(config, params)
    return params


# ---------------------------------------------------------------------------
# host-side validation


def _validate_params(config: IRMCLConfig, params: IRMCLParams) -> None:
    if not isinstance(params, IRMCLParams):
        raise ValueError(f"params must be an IRMCLParams, got {type(params).__name__}")
    validate_motion_noise(config.motion_model, params.motion)
    ir_sensor.validate_receiver_params(params)


def _validate_state(config: IRMCLConfig, params: Any, state: IRMCLState) -> None:
    check_shape("state.particles", state.particles, (config.num_particles, 3))
    check_shape("state.log_weights", state.log_weights, (config.num_particles,))
    check_shape("state.started", state.started, ())


def _validate_inputs(config: IRMCLConfig, params: IRMCLParams, controls: Any, det: Any, time_axis: bool) -> None:
    validate_controls("controls" if time_axis else "control", controls, config.motion_model, time_axis)
    lead = (np.shape(controls)[0],) if time_axis else ()
    ir_sensor.check_detections("detections" if time_axis else "detection", det, lead, int(np.shape(params.offsets)[0]))


def _inputs_in_domain(config: IRMCLConfig, params: IRMCLParams, control: jax.Array, det: IRDetection) -> jax.Array:
    """``bool[]``, traceable: the control and the motion noise in the motion model's domain
    (:func:`jaxnav.models.motion.controls_in_domain`, :func:`jaxnav.models.motion.noise_in_domain`),
    and the receivers' parameters (:func:`jaxnav.models.ir_sensor.receiver_params_in_domain`): the
    value checks of the host, as ``jnp``. The detections are not part of it: an unusable level is
    dropped and counted."""
    del det
    ok = controls_in_domain(control, config.motion_model) & noise_in_domain(config.motion_model, params.motion)
    return ir_sensor.receiver_params_in_domain(params, ok)


# ---------------------------------------------------------------------------
# init


@memory.guard_init
def init(
    key: jax.Array,
    config: IRMCLConfig,
    params: IRMCLParams,
    area: tuple[float, float, float, float],
) -> IRMCLState:
    """[W] Alg. 3 line 1: ``N`` poses uniform over ``area``, uniform weights, not started.

    Args:
        key: one PRNG key (``jax.random.key(seed)`` or ``jax.random.PRNGKey(seed)``); a raw key of
            another length, a batch of keys or ``None`` raise ``ValueError`` naming it.
        config, params: as everywhere.
        area: ``(x_min, x_max, y_min, y_max)`` (m), e.g.
            :func:`jaxnav.sim.ir_world.layout_area`. Headings are uniform on
            the circle ([W]: no known initial orientation).
    """
    if not isinstance(config, IRMCLConfig):
        raise ValueError(f"config must be an IRMCLConfig, got {type(config).__name__}")
    filter_api.check_key(key)
    _validate_params(config, params)
    try:
        x0, x1, y0, y1 = (float(b) for b in area)
    except (TypeError, ValueError):
        raise ValueError(f"area must be (x_min, x_max, y_min, y_max) in m, got {area!r}") from None
    if not all(math.isfinite(v) for v in (x0, x1, y0, y1)) or not (x1 > x0 and y1 > y0):
        raise ValueError(f"area must be finite with x_min < x_max and y_min < y_max, got {area}")
    n = config.num_particles
    dtype = jnp.result_type(float)  # float64 under jax_enable_x64; the log-weights follow the particles
    u = rng.uniform(key, (n, 3), dtype)
    lo = jnp.asarray([x0, y0, -math.pi], dtype)
    hi = jnp.asarray([x1, y1, math.pi], dtype)
    p = lo + u * (hi - lo)
    return IRMCLState(p, jnp.full((n,), -np.log(n), dtype), jnp.asarray(False))


# ---------------------------------------------------------------------------
# step and run


_REDRAW_BINS = 512  # grid over e_d ∈ [0, detection_range] for the re-draw (0.55 mm bins at 283.6 mm)


def _redraw(key, headings, emitter_xy, offset, voltage, params):
    """Candidate poses from the posterior of one receiver's detection under the uniform prior.

    Receiver position ``e + e_d (cos φ, sin φ)``: ``φ`` uniform, ``e_d`` on
    ``[0, detection_range]`` with density ``∝ e_d · exp(ℓ(V | e_d))`` (the
    polar area element times eq. 5.2, floored), by inverse CDF on a grid of
    :data:`_REDRAW_BINS` bins, uniform in area within a bin. Candidate ``i``
    takes heading ``headings[i]`` and its robot position follows from
    ``offset``. Returns ``[M, 3]`` for ``headings [M]``.
    """
    m = headings.shape[0]
    dtype = headings.dtype
    k_bin, k_in, k_phi = jax.random.split(key, 3)
    width = params.detection_range / _REDRAW_BINS
    centres = (jnp.arange(_REDRAW_BINS, dtype=dtype) + 0.5) * width
    ll = jnp.maximum(ir.log_likelihood(voltage, centres, params.voltage, params.sigma_v), params.log_floor)
    logits = jnp.log(centres) + ll
    b = resampling.inverse_cdf(rng.uniform(k_bin, (m,), dtype), jnp.exp(logits - jnp.max(logits))).astype(dtype)
    lo, hi = b * width, (b + 1) * width
    u = rng.uniform(k_in, (m,), dtype)
    e_d = jnp.sqrt(lo * lo + u * (hi * hi - lo * lo))  # uniform in area between the bin's edges
    phi = 2.0 * jnp.pi * rng.uniform(k_phi, (m,), dtype)
    rx = emitter_xy + jnp.stack([e_d * jnp.cos(phi), e_d * jnp.sin(phi)], axis=-1)
    c, s = jnp.cos(headings), jnp.sin(headings)
    x = rx[:, 0] - (c * offset[0] - s * offset[1])
    y = rx[:, 1] - (s * offset[0] + c * offset[1])
    return jnp.stack([x, y, headings], axis=-1)


@filter_api.guard_inputs(_inputs_in_domain)
def kernel(
    key: jax.Array,
    state: IRMCLState,
    config: IRMCLConfig,
    params: IRMCLParams,
    control: jax.Array,
    det: IRDetection,
) -> tuple[IRMCLState, IRMCLInfo]:
    """One step of [W] Alg. 3, pure and traceable (:func:`step` is it validated and jitted)."""
    n = config.num_particles
    layout = params.layout
    k_move, k_redraw, k_pick, k_resample = jax.random.split(key, 4)

    # Alg. 3 lines 2–4: move every particle
    moved = get_motion_model(config.motion_model).sample(k_move, state.particles, control, params.motion)

    # a level that is negative, not finite or beyond the limit (refused on the host, so only inside a
    # caller's jit) makes its detection unusable: dropped and counted in num_ignored
    det, num_unusable = ir_sensor.usable_detections(det)

    # Alg. 3 line 5: which receivers saw an emitter of the layout (a unique ID: its only carrier)
    mask, match, known = ir_sensor.known_detections(det, layout)
    is_unique = known & (ir.popcount(mask) >= 2)

    # start at the first unique ID (module docstring): K·N candidates from receiver r0's posterior,
    # weighted by the other receivers' detections, N of them kept by systematic resampling. With
    # config.restart_when_lost also later, when no particle has receiver r within range of the
    # unique emitter it sees: the filter is lost, and the unique ID says where to look.
    carrier = jnp.argmax(match, axis=-1)  # [R] the emitter of a unique ID
    if config.restart_when_lost:
        d = ir_sensor.receiver_xy(moved, params.offsets) - layout.positions[carrier][None, :, :]
        reach = jnp.any(jnp.sum(d * d, axis=-1) <= params.detection_range**2, axis=0)  # [R]
        restart_r = is_unique & (~state.started | ~reach)
    else:
        restart_r = is_unique & ~state.started
    trigger = jnp.any(restart_r)
    started = state.started | trigger
    r0 = jnp.argmax(restart_r)
    not_r0 = jnp.arange(mask.shape[0]) != r0
    uniform = jnp.full((n,), -jnp.log(jnp.asarray(n, jnp.float32)), jnp.float32)

    def restart():
        k = config.redraw_factor
        k_head, k_cand = jax.random.split(k_redraw)
        headings = rng.uniform(k_head, (k * n,), moved.dtype, -jnp.pi, jnp.pi)
        cand = _redraw(k_cand, headings, layout.positions[carrier[r0]], params.offsets[r0], det.voltage[r0], params)
        idx, ok = ir_sensor.attribute(cand, jnp.full((k * n,), 1.0 / (k * n), cand.dtype), mask, known, params)
        loglik = ir_sensor.detections_log_likelihood(cand, idx, ok & not_r0, det.voltage, params)
        return jnp.take(cand, resampling.systematic(k_pick, loglik, n), axis=0)  # [A] App. B

    particles = jax.lax.cond(trigger, restart, lambda: moved)
    prior_lw = jnp.where(trigger, uniform, state.log_weights)

    # Alg. 3 lines 6–11: the emitter of each detection, by the belief of eq. 5.1 at the predicted estimate
    idx, ok = ir_sensor.attribute(particles, jnp.exp(prior_lw), mask, known & started, params)
    emitter = jnp.where(ok, idx, -1).astype(jnp.int32)

    # Alg. 3 lines 12–14: eq. 5.2 for each used receiver (at the restart already in the particles)
    apply = ok & ~trigger
    loglik = ir_sensor.detections_log_likelihood(particles, idx, apply, det.voltage, params)
    particles, loglik = keep_finite(state.particles, particles, loglik)
    norm = weights.normalize(prior_lw + loglik)

    # eq. 5.4 and Alg. 3 lines 16–20 (resampling only at a step that weighted the particles)
    threshold = jnp.where(jnp.any(apply), jnp.asarray(config.ess_threshold, jnp.float32), 0.0)
    res, base = finish_step(
        k_resample,
        particles,
        norm,
        threshold=threshold,
        scheme=config.resampling,
        angle_dims=_ANGLE_DIMS,
        gradient=config.gradient,
        soft_mixing=config.soft_mixing,
    )
    num_used = jnp.sum(ok, dtype=jnp.int32)
    info = extend_info(
        IRMCLInfo,
        base.replace(resampled=res.resampled | trigger),
        started=started,
        reinitialised=trigger,
        num_detections=num_used,
        num_ignored=jnp.sum(det.valid, dtype=jnp.int32) - num_used + num_unusable,
        emitter=emitter,
    )
    return IRMCLState(res.particles, res.log_weights, started), info


def _prepare(config: IRMCLConfig, controls: jax.Array, detections: IRDetection) -> tuple[jax.Array, IRDetection]:
    return jnp.asarray(controls, jnp.float32), ir_sensor.IR_RECEIVERS.prepare(detections)


step, run = filter_api.build(
    filter_api.FilterSpec(
        name="IR MCL",
        kernel=kernel,
        config_type=IRMCLConfig,
        state_type=IRMCLState,
        inputs=("control", "detection"),
        time_inputs=("controls", "detections"),
        check_params=_validate_params,
        check_state=_validate_state,
        check_inputs=_validate_inputs,
        valid_inputs=_inputs_in_domain,
        prepare=_prepare,
        step_doc="""One step of [W] Alg. 3: move, (start,) attribute, weight, resample.

        ``control`` is the ``[control_dim]`` odometry of the configured motion model (``omni_body``:
        ``(v_x, v_y, ω, Δt)``, robot frame, m/s, rad/s, s); ``detection`` one window's
        :class:`~jaxnav.models.ir.IRDetection` with ``mask``, ``valid``, ``voltage`` of shape ``[R]``
        (``amplitude`` is not used).""",
        run_doc="""IR MCL over a whole drive: ``controls [T, control_dim]`` odometry and ``detections`` an
        :class:`~jaxnav.models.ir.IRDetection` with leading axis ``T`` (e.g.
        ``ir_world.simulate(...).detections``); ``state`` from :func:`init`. ``trace`` is an
        :class:`IRMCLInfo` (``trace.estimate`` ``[T, 3]``, ``trace.emitter`` ``[T, R]``).""",
    ),
    __name__,
)
