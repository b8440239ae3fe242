"""Particle-filter core: log-weights, resampling, ring buffers, batch Monte Carlo."""

from jaxnav.core.batch import monte_carlo as monte_carlo, run_keys as run_keys
from jaxnav.core.resampling import (
    SCHEMES as SCHEMES,
    ResampleResult as ResampleResult,
    conditional_resample as conditional_resample,
    gaussian_refresh as gaussian_refresh,
    gaussian_draw as gaussian_draw,
    get_resampler as get_resampler,
    inverse_cdf as inverse_cdf,
    multinomial as multinomial,
    resample_weights as resample_weights,
    residual as residual,
    stratified as stratified,
    systematic as systematic,
)
from jaxnav.core.ring import (
    RingBuffer as RingBuffer,
    ring_init as ring_init,
    ring_latest as ring_latest,
    ring_mean as ring_mean,
    ring_ordered as ring_ordered,
    ring_push as ring_push,
    ring_valid_mask as ring_valid_mask,
)
from jaxnav.core.weights import (
    Normalized as Normalized,
    circular_mean as circular_mean,
    ess as ess,
    log_ess as log_ess,
    log_marginal_increment as log_marginal_increment,
    normalize as normalize,
    particle_mean as particle_mean,
    sanitize_log_weights as sanitize_log_weights,
    step_ess as step_ess,
    weighted_cov as weighted_cov,
    weighted_mean as weighted_mean,
    wrap_angle as wrap_angle,
)
