"""Reproductions and real-data experiments: one module per study."""

from jaxnav.experiments import hf_slam as hf_slam
from jaxnav.experiments import mrclam as mrclam
