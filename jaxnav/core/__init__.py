"""Particle-filter core: log-weights, resampling, ring buffers, batch Monte Carlo."""

from jaxnav.core.batch import monte_carlo as monte_carlo
from jaxnav.core.batch import run_keys as run_keys
from jaxnav.core.resampling import (
    SCHEMES as SCHEMES,
)
from jaxnav.core.resampling import (
    ResampleResult as ResampleResult,
)
from jaxnav.core.resampling import (
    conditional_resample as conditional_resample,
)
from jaxnav.core.resampling import (
    gaussian_draw as gaussian_draw,
)
from jaxnav.core.resampling import (
    gaussian_refresh as gaussian_refresh,
)
from jaxnav.core.resampling import (
    get_resampler as get_resampler,
)
from jaxnav.core.resampling import (
    inverse_cdf as inverse_cdf,
)
from jaxnav.core.resampling import (
    multinomial as multinomial,
)
from jaxnav.core.resampling import (
    resample_weights as resample_weights,
)
from jaxnav.core.resampling import (
    residual as residual,
)
from jaxnav.core.resampling import (
    stratified as stratified,
)
from jaxnav.core.resampling import (
    systematic as systematic,
)
from jaxnav.core.ring import (
    RingBuffer as RingBuffer,
)
from jaxnav.core.ring import (
    ring_init as ring_init,
)
from jaxnav.core.ring import (
    ring_latest as ring_latest,
)
from jaxnav.core.ring import (
    ring_mean as ring_mean,
)
from jaxnav.core.ring import (
    ring_ordered as ring_ordered,
)
from jaxnav.core.ring import (
    ring_push as ring_push,
)
from jaxnav.core.ring import (
    ring_valid_mask as ring_valid_mask,
)
from jaxnav.core.weights import (
    Normalized as Normalized,
)
from jaxnav.core.weights import (
    circular_mean as circular_mean,
)
from jaxnav.core.weights import (
    ess as ess,
)
from jaxnav.core.weights import (
    log_ess as log_ess,
)
from jaxnav.core.weights import (
    log_marginal_increment as log_marginal_increment,
)
from jaxnav.core.weights import (
    normalize as normalize,
)
from jaxnav.core.weights import (
    particle_mean as particle_mean,
)
from jaxnav.core.weights import (
    sanitize_log_weights as sanitize_log_weights,
)
from jaxnav.core.weights import (
    step_ess as step_ess,
)
from jaxnav.core.weights import (
    weighted_cov as weighted_cov,
)
from jaxnav.core.weights import (
    weighted_mean as weighted_mean,
)
from jaxnav.core.weights import (
    wrap_angle as wrap_angle,
)
