"""Imports every module that registers an experiment (see :mod:`jaxnav.experiments.registry`)."""

from jaxnav.experiments import figures as figures  # noqa: F401
from jaxnav.experiments import ir_positioning as ir_positioning  # noqa: F401
from jaxnav.experiments import tables as tables  # noqa: F401
from jaxnav.experiments import uhf_localization as uhf_localization  # noqa: F401
