"""[W] ch. 5 reproduced: IR emitter positioning with IR MCL ([W] Alg. 3, §5.4).

* :mod:`~jaxnav.experiments.ir.positioning`: one simulated drive: settings,
  simulate, filter, score, draw (re-exported here).
* :mod:`~jaxnav.experiments.ir.tables`: the experiments of [W] §5.4 (Tables 5.2,
  5.3; failure, speeds, rotation) and ours (installation error).

The tables are listed in :mod:`jaxnav.experiments.catalog` and run by name
with :func:`jaxnav.experiments.registry.run`.
"""

from jaxnav.experiments.ir.positioning import (
    ALGORITHMS,
    COLUMN_HEADS,
    COLUMNS,
    DRIVES,
    FAILED_CODE,
    HEIGHTS,
    LAYOUTS,
    QUICK,
    ROTATION_SCORED_FROM,
    SPEEDS,
    Drive,
    DriveInputs,
    IRErrors,
    IRSetting,
    drive_inputs,
    drive_once,
    format_errors,
    installed_layout,
    path_and_record,
    plot_drive,
    run_once,
    score,
)

__all__ = [
    "IRSetting",
    "DriveInputs",
    "IRErrors",
    "COLUMNS",
    "COLUMN_HEADS",
    "LAYOUTS",
    "ALGORITHMS",
    "DRIVES",
    "HEIGHTS",
    "SPEEDS",
    "FAILED_CODE",
    "ROTATION_SCORED_FROM",
    "QUICK",
    "path_and_record",
    "drive_inputs",
    "installed_layout",
    "run_once",
    "Drive",
    "drive_once",
    "format_errors",
    "plot_drive",
    "score",
]
