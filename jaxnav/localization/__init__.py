"""Localization filters with a known map.

* :mod:`~jaxnav.localization.mcl` — Monte Carlo localization ([A] Alg. 3);
* :mod:`~jaxnav.localization.augmented_mcl` — MCL with random-particle injection (kidnapped robot);
* :mod:`~jaxnav.localization.kld_mcl` — MCL with KLD-adaptive particle count ([A] ref. 9);
* :mod:`~jaxnav.localization.ekf`, :mod:`~jaxnav.localization.ukf` — Gaussian filters ([A] Alg. 1);
* :mod:`~jaxnav.localization.grid` — histogram filter ([A] Alg. 2).
"""

from jaxnav.localization import augmented_mcl as augmented_mcl
from jaxnav.localization import ekf as ekf
from jaxnav.localization import grid as grid
from jaxnav.localization import kld_mcl as kld_mcl
from jaxnav.localization import mcl as mcl
from jaxnav.localization import ukf as ukf
