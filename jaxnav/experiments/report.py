"""Result tables as terminal text and Markdown: the one table formatter of every study.

A study turns its JSON result into rows of cell strings with the helpers
for numbers and summaries below, and :func:`text` or :func:`markdown` lays
them out:

* :func:`text`: optional title lines, a header of :class:`Column` heads, a
  rule of ``-`` as long as the header (optional), one line per row
  (fixed-width cells), optional footer lines.
* :func:`markdown`: an optional title paragraph, a pipe table, optional
  footer paragraphs (each after a blank line).

Values that do not exist are written in two distinct ways: a reference value
the source does not give (``None``) as :data:`NONE` ("–"), a score with
nothing to score (NaN, see :mod:`jaxnav.experiments.stats`) as :data:`NA`
("n/a") or a study's more precise text such as ``"n/a (nothing mapped)"``;
never as a number. Runs left out of a summary are always said: ``"(2 runs n/a)"``
for runs with nothing to score, ``"2 of 100 runs diverged"`` for runs whose
filter diverged (:func:`unscored_note`, :func:`diverged_note`,
:func:`diverged_line`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

__all__ = [
    "NONE",
    "NA",
    "Column",
    "number",
    "plus_minus",
    "interval",
    "unscored_note",
    "diverged_note",
    "diverged_line",
    "text",
    "markdown",
]

NONE = "–"
"""A value the source does not give (e.g. the thesis prints none)."""
NA = "n/a"
"""A score with nothing to score (NaN)."""


def _finite(value) -> bool:
    return value is not None and math.isfinite(float(value))


def number(value: float | None, digits: int, nan: str = NA, none: str = NONE) -> str:
    """``value`` with ``digits`` decimals; ``none`` for ``None``, ``nan`` for NaN or ±inf."""
    if value is None:
        return none
    if not math.isfinite(float(value)):
        return nan
    return f"{float(value):.{digits}f}"


def unscored_note(summary: dict) -> str:
    """``"k runs n/a"`` when ``summary["unscored_runs"]`` is k > 0 (:func:`jaxnav.experiments.stats.column_summary`), else ``""``."""
    k = int(summary.get("unscored_runs", 0) or 0)
    return f"{k} run{'s' if k != 1 else ''} {NA}" if k else ""


def diverged_note(diverged: int, runs: int | None = None) -> str:
    """``"k of R runs diverged"`` (``"k runs diverged"`` without ``runs``) when k > 0, else ``""``."""
    k = int(diverged or 0)
    if not k:
        return ""
    if runs is None:
        return f"{k} run{'s' if k != 1 else ''} diverged"
    return f"{k} of {runs} run{'s' if runs != 1 else ''} diverged"


def diverged_line(label: str, diverged: int, runs: int) -> str:
    """A table's footer line for a row with diverged runs (``""`` when none diverged)."""
    note = diverged_note(diverged, runs)
    return f"{label}: {note} (non-finite results), left out of every column" if note else ""


def _with_note(text: str, summary: dict, note: bool) -> str:
    notes = [unscored_note(summary)] if note else []
    notes.append(diverged_note(summary.get("diverged_runs", 0), summary.get("runs")))
    joined = ", ".join(n for n in notes if n)
    return f"{text} ({joined})" if joined else text


def _nan_with_note(nan: str, summary: dict) -> str:
    """``nan`` for a summary no run could score, with its diverged runs said (the text says why the rest had none)."""
    k = diverged_note(summary.get("diverged_runs", 0), summary.get("runs"))
    return f"{nan} ({k})" if k else nan


def plus_minus(summary: dict, digits: int, nan: str = NA, note: bool = True) -> str:
    """``"mean ± half-interval"`` of ``{"mean", "ci95": [lo, hi]}``, then ``" (k runs n/a)"`` when runs had
    no value (unless ``note=False``) and ``"k of R runs diverged"`` when the summary holds ``"diverged_runs"``
    (and ``"runs"``); ``nan`` when the mean is NaN (no run had a value)."""
    if not _finite(summary["mean"]):
        return _nan_with_note(nan, summary)
    lo, hi = summary["ci95"]
    return _with_note(f"{number(summary['mean'], digits)} ± {number((hi - lo) / 2, digits)}", summary, note)


def interval(summary: dict, digits: int, nan: str = NA, note: bool = True) -> str:
    """``"mean [lo, hi]"`` of ``{"mean", "ci95": [lo, hi]}``, with the notes of :func:`plus_minus`;
    ``nan`` when the mean is NaN (no run had a value)."""
    if not _finite(summary["mean"]):
        return _nan_with_note(nan, summary)
    lo, hi = summary["ci95"]
    return _with_note(f"{number(summary['mean'], digits)} [{number(lo, digits)}, {number(hi, digits)}]", summary, note)


@dataclass(frozen=True)
class Column:
    """A column of a :func:`text` table.

    Attributes:
        head: its header.
        width: cell width in characters (0: as wide as the cell); a cell as wide or wider is not
            cut but gets one blank on its outer side, so that it never touches its neighbour.
        align: ``">"`` right or ``"<"`` left.
        gap: text put before every cell of the column (e.g. two spaces).
    """

    head: str
    width: int = 0
    align: str = ">"
    gap: str = ""

    def __post_init__(self) -> None:
        if self.align not in ("<", ">"):
            raise ValueError(f"align must be '<' or '>', got {self.align!r}")

    def cell(self, value: str) -> str:
        if self.width and len(value) >= self.width:  # too wide: keep one blank between it and its neighbour
            value = " " + value if self.align == ">" else value + " "
        return self.gap + (f"{value:{self.align}{self.width}}" if self.width else value)


def text(
    columns: Sequence[Column],
    rows: Sequence[Sequence[str]],
    title: Sequence[str] = (),
    footer: Sequence[str] = (),
    rule: bool = True,
) -> str:
    """A fixed-width table: ``title`` lines, the heads, a rule of ``-`` under them (unless ``rule=False``),
    one line per row, ``footer`` lines; trailing blanks of the heads and rows are cut."""
    head = "".join(c.cell(c.head) for c in columns).rstrip()
    lines = [*title, head] + (["-" * len(head)] if rule else [])
    for row in rows:
        if len(row) != len(columns):
            raise ValueError(f"a row has {len(row)} cells for {len(columns)} columns: {row!r}")
        lines.append("".join(c.cell(v) for c, v in zip(columns, row)).rstrip())
    return "\n".join([*lines, *footer])


def markdown(
    heads: Sequence[str],
    rows: Sequence[Sequence[str]],
    title: str | None = None,
    footer: Sequence[str] = (),
) -> str:
    """A Markdown pipe table after an optional ``title`` paragraph, then each ``footer`` paragraph."""
    lines = [] if title is None else [title, ""]
    lines += ["| " + " | ".join(heads) + " |", "|" + " --- |" * len(heads)]
    for row in rows:
        if len(row) != len(heads):
            raise ValueError(f"a row has {len(row)} cells for {len(heads)} columns: {row!r}")
        lines.append("| " + " | ".join(row) + " |")
    for paragraph in footer:
        lines += ["", paragraph]
    return "\n".join(lines)
