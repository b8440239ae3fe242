"""UHF-RFID sensor models: RSSI and phase of a passive tag seen by a monostatic reader ([A] ch. 4).

A reader at ``g = (x_g, y_g, z_g, ψ_g)`` (m, m, m, rad: position and the yaw of
its antenna boresight, [A] §4.3.1) interrogates a passive tag at
``X = (x, y, z)`` (m) above the ground plane ``z = 0``. Each read gives an
RSSI ``y`` (a received power, **W**) and a phase ``φ`` (**rad**, in
``[0, 2π)``). Every function is pure, broadcasts over leading axes, and is
differentiable in its continuous arguments (tag position, ``k``, ``θ``, ``λ``,
``σ``, phase offset); :func:`jax.grad` never returns NaN for valid inputs.

This module gathers the names of the model under one import; each part is
defined, with the thesis's equations and our choices where it is ambiguous, in
its own module:

* :mod:`jaxnav.models.uhf_antenna`: the reader antenna's cone pattern
  (:func:`~jaxnav.models.uhf_antenna.antenna_gain`, ``G_0``/``G_SLL``/``G_BLL``,
  [A] §4.3.1);
* :mod:`jaxnav.models.uhf_channel`: wavelengths and units, the two-ray path
  loss, the received power ``y = P_T η_T G_R² G_T² L² |h|⁴`` with
  ``|h|² ~ Gamma(k, θ)`` (:func:`~jaxnav.models.uhf_channel.power_scale`,
  :func:`~jaxnav.models.uhf_channel.sample_rssi`) and the predicted phase
  ``φ = (−4πD/λ + θ_off) mod 2π`` ([A] §4.1.2, App. A);
* :mod:`jaxnav.models.uhf_read_model`: the RSSI weight (the scaled
  squared-Gamma density, [A] App. C), the phase weight ``N(Δ; 0, σ²)`` on
  [A]'s distance metric (§4.3.2), and the fused per-read log-likelihood a
  filter uses (:func:`~jaxnav.models.uhf_read_model.read_log_likelihood`);
* :mod:`jaxnav.models.uhf_reads`: the reads of a tag in fixed, masked slots
  (:class:`~jaxnav.models.uhf_reads.UHFReads`), their checks, and
  :func:`~jaxnav.models.uhf_reads.wrap_phase`.

The estimation of ``(k, θ)`` from an anchor tag ([A] §4.3.1, App. D–E) is
:mod:`jaxnav.models.uhf_calibration`.
"""

from __future__ import annotations

from jaxnav.models.uhf_antenna import (
    DEFAULT_ANTENNA,
    AntennaParams,
    antenna_gain,
    off_boresight_angle,
    validate_antenna,
)
from jaxnav.models.uhf_channel import (
    _TINY_DISTANCE,  # noqa: F401  (the distance clamp the numpy peer of the benchmarks mirrors)
    A_WAVELENGTH,
    DEFAULT_CHANNEL,
    DEFAULT_GAMMA,
    DEFAULT_WAVELENGTH,
    SPEED_OF_LIGHT,
    WAVELENGTH_866MHZ,
    ChannelParams,
    GammaParams,
    db_to_linear,
    dbm_to_watt,
    linear_to_db,
    mean_power,
    phase,
    power_scale,
    received_power,
    sample_rssi,
    two_ray_breakpoint,
    two_ray_path_loss,
    validate_channel,
    validate_gamma,
    watt_to_dbm,
    wavelength_from_frequency,
)
from jaxnav.models.uhf_read_model import (
    DEFAULT_PHASE_SIGMA_FRACTION,
    log_w_phase,
    log_w_rssi,
    phase_distance,
    read_log_likelihood,
    read_log_terms,
    read_model_float32,
    read_model_in_domain,
    rssi_log_likelihood,
    validate_read_model,
)
from jaxnav.models.uhf_reads import (
    MAX_RSSI_W,
    UHFReads,
    UsableReads,
    read_mask,
    usable_reads,
    valid_values,
    validate_phase,
    validate_reads,
    validate_rssi,
    wrap_phase,
)

__all__ = [
    "SPEED_OF_LIGHT",
    "A_WAVELENGTH",
    "WAVELENGTH_866MHZ",
    "DEFAULT_WAVELENGTH",
    "DEFAULT_PHASE_SIGMA_FRACTION",
    "AntennaParams",
    "DEFAULT_ANTENNA",
    "ChannelParams",
    "DEFAULT_CHANNEL",
    "GammaParams",
    "DEFAULT_GAMMA",
    "UHFReads",
    "validate_reads",
    "read_log_likelihood",
    "read_log_terms",
    "read_model_float32",
    "validate_read_model",
    "read_model_in_domain",
    "dbm_to_watt",
    "watt_to_dbm",
    "db_to_linear",
    "linear_to_db",
    "wavelength_from_frequency",
    "off_boresight_angle",
    "antenna_gain",
    "two_ray_breakpoint",
    "two_ray_path_loss",
    "power_scale",
    "received_power",
    "mean_power",
    "sample_rssi",
    "log_w_rssi",
    "rssi_log_likelihood",
    "wrap_phase",
    "phase",
    "phase_distance",
    "log_w_phase",
    "validate_antenna",
    "validate_channel",
    "validate_gamma",
    "validate_rssi",
    "valid_values",
    "read_mask",
    "validate_phase",
    "MAX_RSSI_W",
    "usable_reads",
    "UsableReads",
]
