"""[A] reproduced: UHF-RFID tag localization from RSSI and phase ([A] Alg. 6), simulated and real.

* :mod:`~jaxnav.experiments.uhf.localization`: one simulated run of [A] §5.2
  (settings, simulate, fit the anchor, filter) and the RMSE summaries
  (re-exported here).
* :mod:`~jaxnav.experiments.uhf.figures`: [A]'s Figs. 5.3, 5.5, 5.6 and ours (``uhf-refresh``).
* :mod:`~jaxnav.experiments.uhf.real`: Alg. 6 on the AdaRF real reads.

The figures are listed in :mod:`jaxnav.experiments.catalog` and run by name
with :func:`jaxnav.experiments.registry.run`.
"""

from jaxnav.experiments.uhf.localization import (
    ANCHOR_LAMBDAS,
    CLOSE_ANCHOR,
    FAILED_M,
    FINAL_FRACTION,
    MARGIN,
    METHODS,
    MULTIPATHS,
    PASS_DEPTHS,
    PASS_HEIGHTS,
    QUICK,
    SPEED,
    WAVELENGTH,
    Scene,
    UHFInputs,
    UHFSetting,
    anchor_position,
    draw_scene,
    final_mse,
    prior_rmse,
    rmse_summary,
    run_inputs,
    run_once,
)

__all__ = [
    "WAVELENGTH",
    "MARGIN",
    "SPEED",
    "PASS_DEPTHS",
    "PASS_HEIGHTS",
    "CLOSE_ANCHOR",
    "ANCHOR_LAMBDAS",
    "METHODS",
    "FINAL_FRACTION",
    "FAILED_M",
    "MULTIPATHS",
    "QUICK",
    "UHFSetting",
    "UHFInputs",
    "Scene",
    "run_inputs",
    "anchor_position",
    "draw_scene",
    "run_once",
    "prior_rmse",
    "rmse_summary",
    "final_mse",
]
