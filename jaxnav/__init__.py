"""jaxnav: vectorised JAX particle filters for indoor robot localization and SLAM.

Sub-packages: :mod:`jaxnav.core` (log-weights, resampling, ring buffers,
batch Monte Carlo), :mod:`jaxnav.models` (motion and sensor models),
:mod:`jaxnav.sim` (simulators), :mod:`jaxnav.localization` (filters with a
known map), :mod:`jaxnav.slam` (EKF-SLAM, FastSLAM), :mod:`jaxnav.io`
(dataset loaders), :mod:`jaxnav.metrics` (scoring) and
:mod:`jaxnav.experiments` (real-data and reproduction studies; imported on demand).
"""

from jaxnav._version import __version__ as __version__
from jaxnav import core as core, io as io, localization as localization, metrics as metrics, models as models, sim as sim, slam as slam
