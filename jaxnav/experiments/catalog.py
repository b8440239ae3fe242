"""The list of every experiment jaxnav reproduces, study by study.

Each study module holds its experiments in a tuple ``EXPERIMENTS``; this
module imports those modules and lists their experiments, nothing else: no
experiment registers itself, and no study imports this module or
:mod:`jaxnav.experiments.registry`. To add an experiment, add it to its
study's ``EXPERIMENTS`` (or a new study module to :data:`STUDIES`).

* :mod:`jaxnav.experiments.hf_slam.tables`, :mod:`~jaxnav.experiments.hf_slam.figures`:
  [W] ch. 3–4, HF-RFID SLAM (Tables 3.1, 3.2, 4.1, 4.2; Figs. 3.5, 3.7, 4.4, 3.12);
  :mod:`~jaxnav.experiments.hf_slam.readings`: PS-SLAM under each reading of [W] Alg. 2.
* :mod:`jaxnav.experiments.ir.tables`: [W] ch. 5, IR emitter positioning (Tables 5.2, 5.3, §5.4).
* :mod:`jaxnav.experiments.uhf.figures`: [A] §5.2, UHF-RFID tag localization (Figs. 5.3, 5.5, 5.6).
* :mod:`jaxnav.experiments.range_slam.simulation`: range-only SLAM among unknown beacons (beyond the
  theses: [W]'s future work on other sensors).
"""

from __future__ import annotations

import functools
import types
from collections.abc import Mapping

from jaxnav.experiments.experiment import Experiment
from jaxnav.experiments.hf_slam import figures as hf_figures
from jaxnav.experiments.hf_slam import readings as hf_readings
from jaxnav.experiments.hf_slam import tables as hf_tables
from jaxnav.experiments.ir import tables as ir_tables
from jaxnav.experiments.range_slam import simulation as range_slam
from jaxnav.experiments.uhf import figures as uhf_figures

__all__ = ["STUDIES", "experiments"]

STUDIES = (hf_tables, hf_figures, hf_readings, ir_tables, uhf_figures, range_slam)
"""The modules whose ``EXPERIMENTS`` tuples make the catalog, in this order."""


@functools.cache
def experiments() -> Mapping[str, Experiment]:
    """Every experiment of :data:`STUDIES` by name, in their order (read-only).

    Raises:
        ValueError: two experiments share a name.
    """
    out: dict[str, Experiment] = {}
    for study in STUDIES:
        for exp in study.EXPERIMENTS:
            if exp.name in out:
                raise ValueError(f"experiment {exp.name!r} is listed twice (again in {study.__name__})")
            out[exp.name] = exp
    return types.MappingProxyType(out)
