"""IR photodiode receiver simulator with FFT decoding ([W] §5.1–5.2, Figs. 5.4–5.7).

**Overview**

Two receivers on the robot top (one per side, robot-frame ``offsets``,
default (0, ±0.10) m; [W] Fig. 5.4 gives no distances) look up at the
ceiling emitters of an :class:`~jaxnav.models.ir_layouts.EmitterLayout`. Every LED
is on-off keyed with a square wave of duty ``D`` (default ½) at its code's
frequency ([W] Table 5.1); a unique-ID array drives one LED per code of its
set, all co-located, each with its own random phase.

.. rubric:: Physical model (per LED, receiver ``r``, emitter ``e``)

LED facing down, photodiode facing up, vertical distance ``h`` (default
1.2 m, [W] §5.4), horizontal distance ``e_d``, ``d² = h² + e_d²``. A
Lambertian LED of order ``m`` and optical power ``P`` has radiant intensity
``I(φ) = P (m+1)/(2π) cos^m φ``; the irradiance on the photodiode is
``I(φ) cos ψ / d²`` with ``cos φ = cos ψ = h/d`` (inverse square, receiver
incidence cosine). The linear on-amplitude at the ADC is

    a = G · P (m+1)/(2π) · h^{m+1} / d^{m+3}                      [V]

(``G``: photodiode responsivity × area × amplifier gain, V per W/m²). The
waveform is the sum of every LED's 0…a square wave plus photodiode noise
``N(0, noise_sd²)`` per sample (:func:`sample_waveform`).

Level and detection (the receiver front end). The voltage ``V`` of [W]
eq. 5.3 is the level the receiver reads for the detected emitter; we model
it per LED as

    V = V_sat · tanh(a / V_sat) − V_off                           [V]

(:func:`received_voltage`): the amplifier's large-signal compression
(8 V rail in [W] Fig. 5.5) and a fixed offset subtracted in the front end —
the detection threshold: an LED is *detected* when ``V > 0``, i.e. when
``a > a_th = V_sat·artanh(V_off/V_sat)`` (:func:`detection_amplitude`).
The compression is applied to the level read from the spectrum, not to the
waveform (a modelling choice), so OOK signals from several LEDs add linearly and create no
intermodulation products (a saturated sum would put 100 + 150 Hz = 250 Hz,
code 3, into the spectrum).

Calibration of the defaults. ``m = 30`` (half-power half-angle
``arccos 2^{−1/30}`` = 12.3°, a narrow 5 mm IR LED), ``P = 20 mW``; ``G``,
``V_sat`` and ``V_off`` were fitted once, offline (scipy least squares,
float64, on a 0.5 mm grid), so that ``V(e_d)`` at h = 1.2 m matches [W] eq. 5.3 over 0–280 mm:
``a(0) = 9.815 V`` (G = 143.24 V·m²/W), ``V_sat = 5.744 V``,
``V_off = 3.474 V``. Against eq. 5.3 the curve has an RMS difference of
0.023 V and a maximum of 0.085 V (at e_d = 0: eq. 5.3 has a 0.06 V hump at
44 mm that no monotone physical model reproduces); it crosses zero at
282.7 mm (eq. 5.3: 283.6 mm; [W]: "within 280 mm"). A quadratic refit of the
noise-free curve over 0–300 mm gives ``(−3.12·10⁻⁵, 2.34·10⁻³, 1.852)``
beside [W]'s ``(−3.27·10⁻⁵, 2.855·10⁻³, 1.820)``. The height enters
through ``h^{m+1}/d^{m+3}``: at 1.1 and 1.3 m the level right under an
emitter is 2.08 and 1.68 V against 1.90 V at 1.2 m, which is what degrades
eq. 5.3 in [W] Table 5.3.

**Sampling and decoding ([W] §5.2, Fig. 5.6)**

``fs`` (default 10 kHz) for a window of ``T`` seconds (default 20 ms,
``N = fs·T = 200`` samples). ``T`` must be a multiple of 20 ms: every code
frequency is a multiple of 50 Hz, so each falls exactly on an FFT bin (bin
width ``1/T``) and a square wave with an integer number of periods has no
leakage. The receiver is modelled with an ideal anti-aliasing filter at
``fs/2``: the waveform holds each square wave's harmonics up to (strictly
below) Nyquist and nothing above, and is synthesised exactly on the rfft
grid (``jnp.fft.irfft``), so there is no aliasing.

Harmonics. A square wave has odd harmonics of amplitude ``1/h`` (and even
ones for ``D ≠ ½``). None ever lands on a code bin: in units of 50 Hz the
codes are 2, 3, 5, 7, 11, 13, 17, 19, 23 — 2 and odd primes — so
``h·c = c'`` forces ``h = 1`` (:func:`jaxnav.models.ir_codebook.harmonic_collisions`
is empty; e.g. 3 × 150 = 450, 3 × 350 = 1050, 5 × 250 = 1250 Hz are no
codes). The decoder therefore reads the nine fundamental bins and needs no
harmonic subtraction. It relies on no harmonic, so the sampling condition
is ``fs > 2 × 1150 Hz`` (the highest code below Nyquist); the harmonics the
simulator includes are those the anti-aliasing filter passes.

:func:`decode` (``jnp.fft.rfft``): per receiver and code, the on-amplitude
estimate ``â_c = |X[k_c]| · π / (N sin πD)`` (exact for a lone LED without
noise; per-component noise sd ``noise_sd·π/(√(2N) sin πD)`` = 0.079 V by
default, :func:`amplitude_noise_sd`). A code is *present* if
``â_c ≥ a_th`` and *absent* if ``â_c < guard·a_th`` and
``â_c < rel_guard·max â`` (defaults 0.8, a margin of ≈ 10 noise sd below
the threshold, and ½). The window is a **valid detection** iff

1. at least one code is present;
2. every code is present or absent — none in between. An ID at the edge of
   the range, where some of an array's LEDs pass the threshold and others do
   not, is dropped instead of being read as a subset. A code of the emitter
   in range that a farther emitter sharing it partly cancels is caught the
   same way: it could count as absent only below half the strongest code,
   which needs the farther emitter to be more than half as bright, i.e.
   within 0.66 m at 1.2 m — closer than the layouts' ``conflict_radius``
   allows for emitters sharing a code;
3. the present codes have consistent amplitudes, ``max â ≤ max_spread · min â``
   (an array's LEDs are co-located and equally bright; default 1.5);
4. with a ``layout`` given, the set of present codes is the ID of some
   emitter of the layout.

Otherwise ``valid = False`` and ``mask = 0``: no detection, never a guess.
Two emitters in range at once give a set of codes that is no layout ID for
the layouts built by :mod:`jaxnav.models.ir_layouts` (its "Decodability" rules), so
rule 4 drops it. The reported voltage is ``V`` of the mean ``â`` over the
present codes.

**Interface**

``config`` (:class:`ReceiverConfig`, static, hashable): ``fs_hz``,
``window_s``. ``params`` (:class:`ReceiverParams`, differentiable pytree):
height, LED power, Lambertian order, gain, front end, noise, offsets, duty,
decoder margins. :func:`received_amplitude` / :func:`received_voltage`
``(pose, layout, params) -> [R, E]``; :func:`sample_waveform` ``(key, pose,
layout, params, config) -> [R, N]``; :func:`decode` ``(waveform, params,
config, layout=None) -> IRDetection``; :func:`detect` is the two together;
:func:`calibration_sweep` makes the (e_d, V) sweep of [W] Fig. 5.7 for
:func:`jaxnav.models.ir.fit_voltage_model`. All are pure and jit/vmap-able;
the public wrappers validate concrete arguments on the host first.
Gradients flow to every continuous parameter through the amplitudes (the
noise is reparameterised); :func:`decode` thresholds and is not
differentiable in its masks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import rng
from jaxnav.core.filter import check_key
from jaxnav.core.validation import (
    check_finite,
    check_nonnegative,
    check_positive,
    check_positive_int,
    check_shape,
    is_concrete,
)
from jaxnav.models import ir
from jaxnav.models.ir import IRDetection

__all__ = [
    "ReceiverConfig",
    "ReceiverParams",
    "DEFAULT_CONFIG",
    "default_params",
    "validate_params",
    "received_amplitude",
    "received_voltage",
    "level",
    "detection_amplitude",
    "detection_range",
    "amplitude_noise_sd",
    "sample_waveform",
    "decode",
    "detect",
    "measure_voltage",
    "calibration_sweep",
]

# Calibrated defaults (module docstring, "Calibration of the defaults").
_LAMBERTIAN_ORDER = 30.0
_LED_POWER_W = 0.02
_GAIN = 143.24  # V per W/m²: a(0) = 9.815 V at h = 1.2 m
_V_SAT = 5.744
_V_OFFSET = 3.474


@dataclass(frozen=True)
class ReceiverConfig:
    """Static sampling configuration (hashable; a static ``jit`` argument).

    Attributes:
        fs_hz: ADC sampling rate (Hz); must exceed twice the highest code
            frequency, 2 × 1150 Hz (decoding reads fundamentals only).
        window_s: FFT window (s); a positive multiple of 20 ms so that all
            nine code frequencies (multiples of 50 Hz) fall on bins, and
            ``fs_hz · window_s`` must be an integer.
    """

    fs_hz: float = 10_000.0
    window_s: float = 0.02

    def __post_init__(self) -> None:
        for name in ("fs_hz", "window_s"):
            v = getattr(self, name)
            if (
                isinstance(v, bool)
                or not isinstance(v, (int, float, np.floating, np.integer))
                or not (math.isfinite(v) and v > 0)
            ):
                raise ValueError(f"{name} must be a finite positive number, got {v!r}")
        f_max = max(ir.FREQUENCIES_HZ)
        if not self.fs_hz > 2.0 * f_max:
            raise ValueError(
                f"fs_hz = {self.fs_hz:g} Hz is below twice the highest code frequency ({f_max:g} Hz): "
                f"the sampling rate must exceed {2 * f_max:g} Hz (the decoder reads the fundamentals only; "
                "no harmonic is relied on, see jaxnav.models.ir.harmonic_collisions)"
            )
        n = self.fs_hz * self.window_s
        if abs(n - round(n)) > 1e-6 * max(1.0, n):
            raise ValueError(f"fs_hz · window_s must be an integer number of samples, got {n:g}")
        periods = self.window_s * 50.0
        if abs(periods - round(periods)) > 1e-6 or round(periods) < 1:
            raise ValueError(
                f"window_s must be a positive multiple of 0.02 s so that every code frequency "
                f"(multiples of 50 Hz) falls on an FFT bin, got {self.window_s:g} s"
            )

    @property
    def n_samples(self) -> int:
        """Samples per window, ``N = fs·T``."""
        return int(round(self.fs_hz * self.window_s))

    @property
    def code_bins(self) -> np.ndarray:
        """``[9]`` rfft bin of each code frequency (``f·T``)."""
        return np.array([int(round(f * self.window_s)) for f in ir.FREQUENCIES_HZ], dtype=np.int32)

    def harmonic_table(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Static ``(code index, harmonic order, bin)`` of every harmonic below Nyquist."""
        n = self.n_samples
        codes, orders, bins = [], [], []
        for c, k in enumerate(self.code_bins):
            h = 1
            while 2 * h * k < n:  # strictly below the Nyquist bin n/2
                codes.append(c)
                orders.append(h)
                bins.append(h * k)
                h += 1
        return np.array(codes, np.int32), np.array(orders, np.int32), np.array(bins, np.int32)


DEFAULT_CONFIG = ReceiverConfig()


class ReceiverParams(NamedTuple):
    """Receiver and emitter physics (a differentiable pytree; scalars unless noted).

    Attributes:
        height: emitter-to-receiver vertical distance h (m); 1.2 in [W] §5.4.
        led_power: optical power P of one LED (W).
        lambertian_order: m of the LED pattern ``cos^m φ``.
        gain: G, ADC volts per W/m² of irradiance.
        v_sat: front-end compression V_sat (V).
        v_offset: front-end offset / detection threshold V_off (V), ``0 < V_off < V_sat``.
        noise_sd: photodiode noise sd per sample (V).
        offsets: ``[R, 2]`` receiver positions in the robot frame (m).
        duty: OOK duty cycle D in (0, 1).
        guard: decoder guard factor in (0, 1) (module docstring, rule 2).
        rel_guard: decoder relative guard factor in (0, 1) (rule 2).
        max_spread: decoder amplitude-consistency ratio ≥ 1 (rule 3).
    """

    height: jax.Array
    led_power: jax.Array
    lambertian_order: jax.Array
    gain: jax.Array
    v_sat: jax.Array
    v_offset: jax.Array
    noise_sd: jax.Array
    offsets: jax.Array
    duty: jax.Array
    guard: jax.Array
    rel_guard: jax.Array
    max_spread: jax.Array


def default_params(**overrides: Any) -> ReceiverParams:
    """The calibrated defaults (module docstring) as float32 arrays; keyword overrides replace fields."""
    base = dict(
        height=1.2,
        led_power=_LED_POWER_W,
        lambertian_order=_LAMBERTIAN_ORDER,
        gain=_GAIN,
        v_sat=_V_SAT,
        v_offset=_V_OFFSET,
        noise_sd=0.5,
        offsets=ir.DEFAULT_RECEIVER_OFFSETS,
        duty=0.5,
        guard=0.8,
        rel_guard=0.5,
        max_spread=1.5,
    )
    unknown = set(overrides) - set(base)
    if unknown:
        raise ValueError(f"unknown receiver parameters {sorted(unknown)}; fields are {list(base)}")
    base.update(overrides)
    params = ReceiverParams(**{k: jnp.asarray(v, jnp.float32) for k, v in base.items()})
    validate_params(params)
    return params


def validate_params(params: ReceiverParams) -> None:
    """Host-side checks with the offending field named (value checks skipped for tracers)."""
    for name in (
        "height",
        "led_power",
        "lambertian_order",
        "gain",
        "v_sat",
        "v_offset",
        "noise_sd",
        "duty",
        "guard",
        "rel_guard",
        "max_spread",
    ):
        check_shape(f"params.{name}", getattr(params, name), ())
    check_shape("params.offsets", params.offsets, (None, 2))
    if np.shape(params.offsets)[0] < 1:
        raise ValueError("params.offsets must hold at least one receiver")
    check_positive("params.height (emitter-to-receiver height, m)", params.height)
    check_positive("params.led_power (W)", params.led_power)
    check_positive("params.gain", params.gain)
    check_positive("params.v_sat", params.v_sat)
    check_positive("params.v_offset", params.v_offset)
    check_nonnegative("params.lambertian_order", params.lambertian_order)
    check_nonnegative("params.noise_sd", params.noise_sd)
    check_finite("params.offsets", params.offsets)
    check_positive("params.max_spread", params.max_spread)
    if is_concrete(params):
        if not float(params.v_offset) < float(params.v_sat):
            raise ValueError(
                f"params.v_offset ({float(params.v_offset):g} V) must be below params.v_sat "
                f"({float(params.v_sat):g} V), or no LED could ever be detected"
            )
        for name in ("duty", "guard", "rel_guard"):
            v = float(getattr(params, name))
            if not 0.0 < v < 1.0:
                raise ValueError(f"params.{name} must be in (0, 1), got {v:g}")
        if float(params.max_spread) < 1.0:
            raise ValueError(f"params.max_spread must be ≥ 1, got {float(params.max_spread):g}")


def _check_pose(pose: Any) -> None:
    check_shape("pose", pose, (3,))
    check_finite("pose", pose)


def _check_layout(layout: ir.EmitterLayout) -> None:
    if is_concrete(layout):
        ir.validate_layout(layout)
    else:
        check_shape("layout.positions", layout.positions, (None, 2))


# --------------------------------------------------------------------------------------
# Physics
# --------------------------------------------------------------------------------------


def _amplitude_at(e_d2: jax.Array, params: ReceiverParams) -> jax.Array:
    """Linear on-amplitude (V) at squared horizontal distance ``e_d2`` (m²), in log form."""
    h = params.height
    m = params.lambertian_order
    log_a = (
        jnp.log(params.gain)
        + jnp.log(params.led_power)
        + jnp.log1p(m)
        - jnp.log(2.0 * jnp.pi)
        + (m + 1.0) * jnp.log(h)
        - 0.5 * (m + 3.0) * jnp.log(h * h + e_d2)
    )
    return jnp.exp(log_a)


def level(amplitude: jax.Array, params: ReceiverParams) -> jax.Array:
    """Front-end level ``V = V_sat·tanh(a/V_sat) − V_off`` (V) of an on-amplitude ``a`` (V)."""
    return params.v_sat * jnp.tanh(amplitude / params.v_sat) - params.v_offset


def detection_amplitude(params: ReceiverParams) -> jax.Array:
    """``a_th = V_sat·artanh(V_off/V_sat)``: the on-amplitude (V) at which ``V = 0``."""
    return params.v_sat * jnp.arctanh(params.v_offset / params.v_sat)


def detection_range(params: ReceiverParams) -> jax.Array:
    """Horizontal distance (m) at which ``V`` falls to 0 at ``params.height``, in closed form.

    ``(h² + e²)^{(m+3)/2} = G P (m+1)/(2π) h^{m+1} / a_th``; 0 if even ``e = 0`` is undetected.
    """
    h = params.height
    m = params.lambertian_order
    log_x = (
        jnp.log(params.gain)
        + jnp.log(params.led_power)
        + jnp.log1p(m)
        - jnp.log(2.0 * jnp.pi)
        + (m + 1.0) * jnp.log(h)
        - jnp.log(detection_amplitude(params))
    )
    e2 = jnp.exp(2.0 * log_x / (m + 3.0)) - h * h
    return jnp.sqrt(jnp.maximum(e2, 0.0))


def amplitude_noise_sd(params: ReceiverParams, config: ReceiverConfig = DEFAULT_CONFIG) -> jax.Array:
    """Noise sd (V) of each quadrature component of â: ``noise_sd·π / (√(2N)·sin πD)``."""
    n = config.n_samples
    return params.noise_sd * jnp.pi / (jnp.sqrt(2.0 * n) * jnp.sin(jnp.pi * params.duty))


def _received_amplitude(pose, layout, params):
    rx = ir.receiver_positions(pose, params.offsets)  # [R, 2]
    d = rx[:, None, :] - layout.positions[None, :, :]
    return _amplitude_at(jnp.sum(d * d, axis=-1), params)


def received_amplitude(pose: jax.Array, layout: ir.EmitterLayout, params: ReceiverParams) -> jax.Array:
    """``[R, E]`` linear on-amplitude (V) of one LED of each emitter at each receiver.

    ``pose = (x, y, θ)`` (m, m, rad); module docstring for the physics.
    """
    _check_pose(pose)
    _check_layout(layout)
    validate_params(params)
    return _received_amplitude(pose, layout, params)


def received_voltage(pose: jax.Array, layout: ir.EmitterLayout, params: ReceiverParams) -> jax.Array:
    """``[R, E]`` noise-free level V (V) of each emitter at each receiver, the model of [W] eq. 5.3.

    Differentiable in every continuous field of ``params`` and in ``pose``.
    ``V > 0`` inside the detection range.
    """
    return level(received_amplitude(pose, layout, params), params)


# --------------------------------------------------------------------------------------
# Waveform
# --------------------------------------------------------------------------------------


def _sample_waveform(key, pose, layout, params, config):
    n = config.n_samples
    code_idx, orders, bins = config.harmonic_table()
    e = layout.positions.shape[0]
    amp = _received_amplitude(pose, layout, params)  # [R, E]
    r = amp.shape[0]
    bits = ir.mask_bits(layout.masks).astype(amp.dtype)  # [E, 9]
    led = amp[:, :, None] * bits[None]  # [R, E, 9] per-LED on-amplitude (0 if no LED)
    # one normal draw (much cheaper to compile than split + uniform + normal): the
    # first R·N values are the noise, the rest give each LED a uniform phase as the
    # angle of a standard 2-D Gaussian
    z = rng.normal(key, (r * n + 2 * e * ir.NUM_CODES,), amp.dtype)
    noise = z[: r * n].reshape(r, n)
    g = z[r * n :].reshape(2, e, ir.NUM_CODES)
    phase = jnp.arctan2(g[0], g[1])  # [E, 9], uniform on (-π, π]
    h = jnp.asarray(orders, amp.dtype)
    # complex amplitude of harmonic h of a 0..1 pulse train of duty D with phase φ:
    # (2/(hπ)) sin(hπD) e^{-i h φ} on cos(2π h f t)
    coef = 2.0 / (h * jnp.pi) * jnp.sin(h * jnp.pi * params.duty)  # [M]
    rot = jnp.exp(-1j * h[None, :] * phase[:, code_idx])  # [E, M]
    z = jnp.einsum("rem,em->rm", led[:, :, code_idx].astype(rot.dtype), rot) * coef  # [R, M]
    spec = jnp.zeros((r, n // 2 + 1), rot.dtype)
    spec = spec.at[:, bins].add(0.5 * n * z)
    spec = spec.at[:, 0].set(n * params.duty * jnp.sum(led, axis=(1, 2)))
    clean = jnp.fft.irfft(spec, n=n, axis=-1)
    return clean + params.noise_sd * noise


_sample_waveform_jit = jax.jit(_sample_waveform, static_argnames=("config",))


def sample_waveform(
    key: jax.Array,
    pose: jax.Array,
    layout: ir.EmitterLayout,
    params: ReceiverParams,
    config: ReceiverConfig = DEFAULT_CONFIG,
) -> jax.Array:
    """``[R, N]`` sampled photodiode signal (V) of every receiver for one window.

    Each LED's square wave (random phase per LED, from ``key``) with its
    harmonics below Nyquist (ideal anti-aliasing filter), summed linearly,
    plus Gaussian noise ``noise_sd`` per sample. Differentiable in ``params``
    and ``pose``.
    """
    check_key(key)
    _check_pose(pose)
    _check_layout(layout)
    validate_params(params)
    return _sample_waveform_jit(key, pose, layout, params, config)


# --------------------------------------------------------------------------------------
# Decoding
# --------------------------------------------------------------------------------------


def _amplitudes(waveform, params, config):
    n = config.n_samples
    spec = jnp.fft.rfft(waveform, axis=-1)
    x = spec[..., jnp.asarray(config.code_bins)]
    return jnp.abs(x) * jnp.pi / (n * jnp.sin(jnp.pi * params.duty))


def _decode(waveform, params, config, layout):
    a = _amplitudes(waveform, params, config)  # [R, 9]
    a_th = detection_amplitude(params)
    hi = a >= a_th
    lo = (a >= params.guard * a_th) | (a >= params.rel_guard * jnp.max(a, axis=-1, keepdims=True))
    present = jnp.any(hi, axis=-1)
    clean = jnp.all(hi == lo, axis=-1)
    a_max = jnp.max(jnp.where(hi, a, 0.0), axis=-1)
    a_min = jnp.min(jnp.where(hi, a, jnp.inf), axis=-1)
    consistent = a_max <= params.max_spread * a_min
    mask = ir.bits_to_mask(hi)
    valid = present & clean & consistent
    if layout is not None:
        valid = valid & jnp.any(mask[:, None] == layout.masks[None, :], axis=-1)
    count = jnp.maximum(jnp.sum(hi, axis=-1), 1)
    mean_a = jnp.sum(jnp.where(hi, a, 0.0), axis=-1) / count
    volts = level(mean_a, params)
    return IRDetection(
        mask=jnp.where(valid, mask, 0).astype(jnp.int32),
        valid=valid,
        voltage=jnp.where(valid, volts, 0.0),
        amplitude=a,
    )


_decode_jit = jax.jit(_decode, static_argnames=("config",))


def _check_waveform(waveform, config):
    check_shape("waveform", waveform, (None, config.n_samples))


def decode(
    waveform: jax.Array,
    params: ReceiverParams,
    config: ReceiverConfig = DEFAULT_CONFIG,
    layout: ir.EmitterLayout | None = None,
) -> IRDetection:
    """Decode each receiver's window by FFT (module docstring, rules 1–4).

    Args:
        waveform: ``[R, N]`` samples (V), ``N = config.n_samples``.
        params: receiver parameters (threshold, guard, duty, …).
        config: the sampling configuration the waveform was taken with.
        layout: if given, a set of codes that is no emitter's ID is not a detection.

    Returns:
        :class:`~jaxnav.models.ir.IRDetection` (``mask``, ``valid``, ``voltage``, ``amplitude``).
    """
    _check_waveform(waveform, config)
    validate_params(params)
    if layout is not None:
        _check_layout(layout)
    return _decode_jit(waveform, params, config, layout)


def _detect(key, pose, layout, params, config):
    return _decode(_sample_waveform(key, pose, layout, params, config), params, config, layout)


_detect_jit = jax.jit(_detect, static_argnames=("config",))


def detect(
    key: jax.Array,
    pose: jax.Array,
    layout: ir.EmitterLayout,
    params: ReceiverParams,
    config: ReceiverConfig = DEFAULT_CONFIG,
) -> IRDetection:
    """:func:`sample_waveform` then :func:`decode` against ``layout``: one window's detections."""
    check_key(key)
    _check_pose(pose)
    _check_layout(layout)
    validate_params(params)
    return _detect_jit(key, pose, layout, params, config)


def measure_voltage(
    waveform: jax.Array, mask: jax.Array, params: ReceiverParams, config: ReceiverConfig = DEFAULT_CONFIG
) -> jax.Array:
    """``[R]`` level V (V) read at the codes of a *known* ID bitmask, detected or not.

    The receiver's reading used for calibration ([W] Fig. 5.7): the mean â
    over the codes of ``mask``, through the front end. Negative beyond the range.
    """
    _check_waveform(waveform, config)
    a = _amplitudes(waveform, params, config)
    bits = ir.mask_bits(mask)
    mean_a = jnp.sum(jnp.where(bits, a, 0.0), axis=-1) / jnp.maximum(jnp.sum(bits), 1)
    return level(mean_a, params)


def _sweep(key, offsets_m, code_mask, params, config, n_windows):
    layout = ir.EmitterLayout(
        positions=jnp.zeros((1, 2), jnp.float32),
        masks=jnp.reshape(code_mask, (1,)),
        unique=jnp.zeros((1,), bool),
        ids=jnp.reshape(ir.mask_to_id(code_mask), (1,)),
    )
    n = offsets_m.shape[0]
    shift = jnp.concatenate([params.offsets[0], jnp.zeros(1, params.offsets.dtype)])
    poses = jnp.stack([offsets_m, jnp.zeros_like(offsets_m), jnp.zeros_like(offsets_m)], axis=1) - shift
    # window w at offset i uses key fold_in(fold_in(key, i), w)
    keys = jax.vmap(
        lambda i: jax.vmap(lambda w: jax.random.fold_in(jax.random.fold_in(key, i), w))(jnp.arange(n_windows))
    )(jnp.arange(n)).reshape((n * n_windows,) + key.shape)
    bits = ir.mask_bits(code_mask)

    def window(k, pose):
        w = _sample_waveform(k, pose, layout, params, config)
        a = _amplitudes(w[:1], params, config)[0]
        return level(jnp.sum(jnp.where(bits, a, 0.0)) / jnp.sum(bits), params)

    v = jax.vmap(window)(keys, jnp.repeat(poses, n_windows, axis=0))
    return jnp.mean(v.reshape(n, n_windows), axis=1)


_sweep_jit = jax.jit(_sweep, static_argnames=("config", "n_windows"))


def calibration_sweep(
    key: jax.Array,
    params: ReceiverParams,
    height: float = 1.2,
    offsets_mm: Any = None,
    code: int = 1,
    n_windows: int = 1,
    config: ReceiverConfig = DEFAULT_CONFIG,
) -> tuple[jax.Array, jax.Array]:
    """Simulated calibration sweep of [W] Fig. 5.7: receiver 0 moved away from one LED.

    A single repeated-ID LED (``code``) at the origin, the emitter-to-receiver
    height set to ``height`` (m; it overrides ``params.height``: a calibration
    is made at a known height, 1.2 m in [W]), receiver 0 at horizontal distances
    ``offsets_mm`` (default 0–300 mm at 10 mm steps, as [W]); at each, the
    mean of :func:`measure_voltage` over ``n_windows`` windows (window ``w``
    at offset ``i`` uses key ``fold_in(fold_in(key, i), w)``). Feed the result to
    :func:`jaxnav.models.ir.fit_voltage_model`.

    Returns:
        ``(e_d_mm [n], volts [n])``.
    """
    check_key(key)
    check_positive("height (emitter-to-receiver height, m)", height)
    if offsets_mm is None:
        offsets_mm = np.arange(0.0, 301.0, 10.0)
    off = np.asarray(offsets_mm, np.float64)
    check_shape("offsets_mm", off, (None,))
    check_nonnegative("offsets_mm", off)
    if off.size < 1:
        raise ValueError("offsets_mm must hold at least one distance")
    n_windows = check_positive_int("n_windows", n_windows)
    mask = ir.to_mask((code,))
    params = params._replace(height=jnp.asarray(height, jnp.float32))
    validate_params(params)
    volts = _sweep_jit(
        key, jnp.asarray(off / 1000.0, jnp.float32), jnp.asarray(mask, jnp.int32), params, config, n_windows
    )
    return jnp.asarray(off, jnp.float32), volts
