"""The result-table formatter shared by every study (jaxnav.experiments.report)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from jaxnav.experiments import report


def test_numbers_and_values_that_do_not_exist():
    assert report.number(1.25, 1) == "1.2" and report.number(3, 0) == "3"
    assert report.number(None, 1) == report.NONE == "–"  # no reference value
    assert report.number(math.nan, 1) == report.NA == "n/a"  # nothing to score: never a number
    assert report.number(math.inf, 1, nan="n/a (nothing mapped)") == "n/a (nothing mapped)"


def test_summaries_write_the_mean_the_interval_and_the_unscored_runs():
    s = {"mean": 12.0, "ci95": [10.0, 14.0]}
    assert report.plus_minus(s, 1) == "12.0 ± 2.0"
    assert report.interval(s, 1) == "12.0 [10.0, 14.0]"
    some = {**s, "unscored_runs": 2}
    assert report.plus_minus(some, 1) == "12.0 ± 2.0 (2 runs n/a)"
    assert report.plus_minus(some, 1, note=False) == "12.0 ± 2.0" and report.unscored_note(some) == "2 runs n/a"
    assert report.interval({**s, "unscored_runs": 1}, 0) == "12 [10, 14] (1 run n/a)"
    none = {"mean": math.nan, "ci95": [math.nan, math.nan], "unscored_runs": 4}
    assert report.plus_minus(none, 1, nan="n/a (nothing mapped)") == "n/a (nothing mapped)"
    assert report.interval(none, 1) == "n/a"


def test_diverged_runs_are_said_with_the_number_of_runs():
    assert report.diverged_note(2, 100) == "2 of 100 runs diverged" and report.diverged_note(1) == "1 run diverged"
    assert report.diverged_note(0, 8) == "" and report.diverged_line("row", 0, 8) == ""
    assert report.diverged_line("16 tags/m², PF-SLAM", 1, 8) == (
        "16 tags/m², PF-SLAM: 1 of 8 runs diverged (non-finite results), left out of every column"
    )
    point = {"mean": 12.0, "ci95": [10.0, 14.0], "unscored_runs": 1, "diverged_runs": 2, "runs": 8}
    assert report.interval(point, 0) == "12 [10, 14] (1 run n/a, 2 of 8 runs diverged)"
    assert report.plus_minus(point, 0, note=False) == "12 ± 2 (2 of 8 runs diverged)"
    every = {"mean": math.nan, "ci95": [math.nan, math.nan], "diverged_runs": 8, "runs": 8}
    assert report.interval(every, 1) == "n/a (8 of 8 runs diverged)"


def test_text_table_layout():
    columns = [report.Column("name", 6, "<"), report.Column("x", 5), report.Column("note", gap="  ", align="<")]
    text = report.text(columns, [["a", "1.0", "first"], ["bb", "22.5", ""]], title=["T"], footer=["F"])
    assert text.splitlines() == [
        "T",
        "name      x  note",
        "-----------------",
        "a       1.0  first",
        "bb     22.5",  # trailing blanks cut
        "F",
    ]
    assert report.text(columns[:1], [["a"]], rule=False).splitlines() == ["name", "a"]
    # a cell as wide as its column or wider never touches its neighbour
    wide = report.text([report.Column("a", 3), report.Column("b", 3)], [["1234", "567"]], rule=False)
    assert wide.splitlines() == ["  a  b", " 1234 567"]
    with pytest.raises(ValueError, match="2 cells for 3 columns"):
        report.text(columns, [["a", "b"]])
    with pytest.raises(ValueError, match="align"):
        report.Column("x", 3, "^")


def test_markdown_table_layout():
    md = report.markdown(["a", "b"], [["1", "2"]], title="**T**", footer=["note 1", "note 2"])
    assert md.splitlines() == ["**T**", "", "| a | b |", "| --- | --- |", "| 1 | 2 |", "", "note 1", "", "note 2"]
    assert report.markdown(["a"], []).splitlines() == ["| a |", "| --- |"]
    with pytest.raises(ValueError, match="1 cells for 2 columns"):
        report.markdown(["a", "b"], [["1"]])


def test_every_study_uses_the_one_formatter():
    """The table renderers of the studies are built on this module (no study formats its own layout)."""
    import inspect

    from jaxnav.experiments import curves
    from jaxnav.experiments.hf_slam import simulation as hf_simulation
    from jaxnav.experiments.hf_slam import tables as hf_tables
    from jaxnav.experiments.ir import positioning as ir_positioning
    from jaxnav.experiments.ir import tables as ir_tables
    from jaxnav.experiments.mrclam import evaluation as mrclam
    from jaxnav.experiments.uhf import figures as uhf_figures
    from jaxnav.experiments.uhf import real as uhf_real

    for fn in (
        hf_tables.render_table,
        hf_tables.markdown_table,
        curves.markdown,
        hf_simulation.format_errors,
        ir_tables.render_table,
        ir_tables.markdown_table,
        ir_positioning.format_errors,
        uhf_figures.render_table,
        uhf_figures.markdown_table,
        uhf_real.format_results,
        mrclam.format_table,
    ):
        src = inspect.getsource(fn)
        assert "report.text(" in src or "report.markdown(" in src, fn.__qualname__


def test_uhf_real_results_count_a_diverged_seed_instead_of_averaging_it():
    from jaxnav.experiments.uhf import real as uhf_real
    from jaxnav.models import uhf_rfid as U

    truth = np.asarray([0.5, 1.0])
    estimates = np.tile(truth + [0.1, 0.0], (3, 50, 1))
    estimates[2, -1] = np.nan  # the last seed diverged
    errors = np.linalg.norm(estimates - truth, axis=-1)
    result = uhf_real.TagResult("exp", 0, "rssi", truth, estimates, errors, errors[:, -1], U.GammaParams(2.0, 1.0))
    text = uhf_real.format_results([result])
    assert "exp tag 0 rssi: 1 of 3 runs diverged" in text
    assert "0.100" in text and "nan" not in text.lower()
