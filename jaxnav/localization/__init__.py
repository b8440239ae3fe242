"""Localization filters: Monte Carlo localization ([A] Alg. 3); more to come."""

from jaxnav.localization import mcl as mcl
