"""Reproductions and real-data experiments, one subpackage per study, on top of the library.

Studies:

* :mod:`jaxnav.experiments.hf_slam`: [W] ch. 3–4, HF-RFID SLAM on simulated tag carpets.
* :mod:`jaxnav.experiments.ir`: [W] ch. 5, IR emitter positioning.
* :mod:`jaxnav.experiments.uhf`: [A], UHF-RFID tag localization (simulated and the AdaRF real reads).
* :mod:`jaxnav.experiments.mrclam`: classical filters and PF/PS-SLAM on the UTIAS MRCLAM real dataset.
* :mod:`jaxnav.experiments.uwb`: range-only localization and SLAM on the TU Chemnitz UWB log.
* :mod:`jaxnav.experiments.range_slam`: range-only SLAM among unknown beacons, simulated.

Shared, study-free layer:

* :mod:`~jaxnav.experiments.experiment`: the :class:`~jaxnav.experiments.experiment.Cell`
  and :class:`~jaxnav.experiments.experiment.Experiment` types.
* :mod:`~jaxnav.experiments.registry`: run an experiment by name (``registry.run``),
  look one up (``registry.get``), list them (``registry.names``, ``registry.experiments``).
* :mod:`~jaxnav.experiments.catalog`: the explicit list of every study's experiments.
* :mod:`~jaxnav.experiments.sweep`: chunked, resumable batch Monte Carlo over the cells.
* :mod:`~jaxnav.experiments.stats`: means, 95 % intervals and runs with nothing to score.
* :mod:`~jaxnav.experiments.report`: the result-table formatter (terminal text, Markdown).
* :mod:`~jaxnav.experiments.curves`: results that are curves (summaries, tables, figures).

Importing this package imports no study; import the subpackage you need.
"""
