"""Reproductions and real-data experiments: one module per study."""

from jaxnav.experiments import mrclam as mrclam
