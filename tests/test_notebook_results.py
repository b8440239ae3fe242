"""Every number a notebook shows from the committed results agrees with the committed JSON.

The notebooks of ``notebooks/`` are stored with their outputs (``tests/test_notebooks.py``), and some
of them show the full-size reproductions committed in ``benchmarks/results/experiments/``. A stored
output made from an older JSON shows numbers that the reproduction pages of the documentation (made
from the JSON when the site is built) no longer show. These tests read the stored outputs only:
nothing is executed, and the whole file takes a few seconds.

**Which cells are compared.** A code cell *shows committed results* when its source names the
results folder (``benchmarks/results``, as one string, as ``"benchmarks" / "results"`` or as
``Path("benchmarks", "results")``), or a variable an earlier such cell set to that folder. Each
string literal of its source that names a committed ``benchmarks/results/experiments/NAME.json`` is
an experiment it shows, and each of its outputs must be one of

* an experiment's table, a ``text/markdown`` output opening with ``**NAME**``: it must equal
  ``registry.get(NAME).markdown(json)`` (the function that writes ``NAME.md`` and the reproduction
  page from the JSON) line by line, and number by number: every mean, interval bound, thesis value,
  run count and median. A number that differs is reported with the notebook, the code cell, the
  table's row and column, the number shown, the number the JSON gives and, where one formats to it,
  the JSON entry it comes from;
* an experiment's figure, an ``image/png`` output after that table: it must be the committed
  ``NAME.png`` byte for byte (IPython's ``Image`` stores the file as it is).

Every experiment the cell names must be shown. Any other output of such a cell (a count, a message,
a figure drawn by the cell) fails as one these tests cannot check, so that a new way of showing
committed results comes with its comparison here. The markdown cells just before the cell (its
introduction) may state how many runs the results rest on (``R = 100``, ``50 runs``): each such
number must be the run count of one of the experiments shown.

At present the cells compared are code cell 7 of ``hf_rfid_slam`` ([W]'s HF-RFID SLAM tables and
figures), code cell 7 of ``ir_positioning`` ([W]'s IR positioning tables) and code cell 6 of
``uhf_rfid_localization`` ([A]'s Figs. 5.3, 5.5, 5.6 and ``uhf-refresh``);
:func:`test_results_cells_found` checks that those notebooks keep one.

**Which cells are not compared, and why.** Every other number a notebook shows is computed when it
runs, and nothing committed holds it: the simulations and the quick variants of the experiments
(``registry.run(..., quick=True)``) at the notebooks' small sizes (``hf_rfid_slam``,
``ir_positioning``, ``uhf_rfid_localization``, ``mcl_quickstart``), and the filters run on the real
datasets of the data folder (``mrclam_real_data``, ``uhf_calibration``, the real-data section of
``uhf_rfid_localization``). That those cells run is the test of ``tests/test_notebooks.py``.
"""

from __future__ import annotations

import base64
import copy
import itertools
import json
import pathlib
import re

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((REPO / "notebooks").glob("*.ipynb"))
EXPERIMENTS = REPO / "benchmarks" / "results" / "experiments"
COMMITTED = {p.stem for p in EXPERIMENTS.glob("*.json") if not p.name.endswith(".runs.json")}
# The notebooks that show committed results (at least one cell each; any other notebook may add one).
SHOWS_RESULTS = {"hf_rfid_slam.ipynb", "ir_positioning.ipynb", "uhf_rfid_localization.ipynb"}

READS_RESULTS = re.compile(r"""benchmarks(?:/|["']\s*[/,]\s*["'])results""")
LITERAL = re.compile(r"""["']([A-Za-z0-9_.-]+)["']""")
TABLE_HEAD = re.compile(r"\A\*\*([A-Za-z0-9_.-]+)\*\*")
# A number as shown: an optional minus (not one of a range such as 100-300), digits, decimals.
NUMBER = re.compile(r"(?<![\d.])-?\d+(?:\.\d+)?")
SEPARATOR = re.compile(r"^\|(?:\s*-+\s*\|)+\s*$")
# The columns of a table that name its row rather than hold a result.
LABEL_COLUMNS = ("setting", "method", "row", "quantity")
RUN_COUNT = re.compile(r"\bR\s*=\s*(\d[\d,]*)|\b(\d[\d,]*)\s+runs\b")


def _load(path: pathlib.Path) -> dict:
    return json.loads(path.read_text(encoding="utf-8"))


def _text(value) -> str:
    return "".join(value) if isinstance(value, list) else (value or "")


def _code_cells(nb: dict) -> list[dict]:
    """The code cells that hold code, numbered as ``tests/test_notebooks.py`` numbers them."""
    return [c for c in nb["cells"] if c["cell_type"] == "code" and _text(c["source"]).strip()]


def results_cells(nb: dict) -> list[tuple[int, dict, list[str]]]:
    """``(index, cell, experiments)`` for each code cell that shows committed results.

    That is a cell whose source names the results folder, or a variable that an earlier such cell
    set to it (``root = ... / "benchmarks" / "results" / "experiments"``)."""
    out, folders = [], set()
    for i, cell in enumerate(_code_cells(nb)):
        source = _text(cell["source"])
        if READS_RESULTS.search(source) or any(re.search(rf"\b{v}\b", source) for v in folders):
            names = list(dict.fromkeys(n for n in LITERAL.findall(source) if n in COMMITTED))
            out.append((i, cell, names))
            for line in source.splitlines():
                assigned = re.match(r"\s*(\w+)\s*=[^=]", line)
                if assigned and READS_RESULTS.search(line):
                    folders.add(assigned.group(1))
    return out


def _result(name: str) -> dict:
    return _load(EXPERIMENTS / f"{name}.json")


def _markdown(name: str, result: dict) -> str:
    from jaxnav.experiments import registry

    return registry.get(name).markdown(result)


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def _leaves(obj, path: str = ""):
    """``(path, number)`` for every number of a JSON value."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _leaves(v, f"{path}.{k}" if path else str(k))
    elif isinstance(obj, list):
        for k, v in enumerate(obj):
            yield from _leaves(v, f"{path}[{k}]")
    elif isinstance(obj, (int, float)) and not isinstance(obj, bool):
        yield path, obj


def _json_entry(result: dict, token: str, row: int | None, header: str | None, column: int | None) -> str:
    """Where the JSON holds the number shown as ``token`` (its path and unrounded value), or ''.

    Only an entry that the table's place names is given: for a line outside a table, a number of the
    JSON's top level (``runs``); for a row of ``rows``, a number of that row under the column's name
    (``dr [mm]``: ``rows[0].dr_mm.mean``); for a row of ``curves``, that curve's number at the column's
    point (``curves[1].mean[3]``)."""
    decimals = len(token.partition(".")[2])
    key = re.sub(r"\W+", "_", (header or "").replace("θ", "theta").lower()).strip("_")

    first, _, rest = key.partition("_")
    named = [rf"\.{re.escape(key)}\w*\."]  # dr [mm]: .dr_mm.; final RMSE: .final_rmse_m.
    if first in ("max", "median"):  # max dr [mm]: .dr_mm.max
        named.append(rf"\.{re.escape(rest)}\.{first}\.")

    def names_place(path: str) -> bool:
        if row is None or header is None:
            return re.fullmatch(r"\w+", path) is not None
        if path.startswith(f"rows[{row}]."):
            return bool(key) and any(re.search(n, f"{path}.") for n in named)
        return path.startswith(f"curves[{row}].") and f"[{column}]" in path.partition("]")[2]

    for path, value in _leaves(result):
        if f"{value:.{decimals}f}" == token and names_place(path):
            return f" ({path} = {value!r})"
    return ""


def compare_table(shown: str, expected: str, result: dict, where: str, most: int = 6) -> list[str]:
    """The numbers of ``shown`` that differ from those of ``expected``: a message each for the first ``most``."""
    problems = []
    shown_lines, expected_lines = shown.strip().splitlines(), expected.strip().splitlines()
    header: list[str] = []
    row = None
    for k, (s, e) in enumerate(itertools.zip_longest(shown_lines, expected_lines, fillvalue="")):
        if NUMBER.sub("#", s) != NUMBER.sub("#", e):  # another layout: the numbers cannot be paired
            problems.append(f"{where}: line {k + 1} shows {s[:160]!r} where the JSON gives {e[:160]!r}")
            break
        following = expected_lines[k + 1] if k + 1 < len(expected_lines) else ""
        if e.startswith("|") and SEPARATOR.match(following):
            header, row = _cells(e), None
            continue
        if SEPARATOR.match(e):
            row = 0
            continue
        if s == e:
            row = row + 1 if row is not None and e.startswith("|") else row
            continue
        if e.startswith("|"):
            pairs = zip(_cells(s), _cells(e))
            labels = [c for c, h in zip(_cells(e), header) if h in LABEL_COLUMNS]
            label = " | ".join(labels)
        else:
            pairs, label, labels = [(s, e)], None, []
        for j, (sc, ec) in enumerate(pairs):
            for st, et in zip(NUMBER.findall(sc), NUMBER.findall(ec)):
                if st == et:
                    continue
                column = None
                if label is None:
                    place = f"line {k + 1} ({e[:60]}…)"
                else:
                    column = header[j] if j < len(header) else f"column {j + 1}"
                    place = f"row {label!r}, column {column!r}"
                entry = _json_entry(result, et, row, column, j - len(labels))
                problems.append(f"{where}: {place}: shows {st}, the JSON gives {et}{entry}")
        if row is not None and e.startswith("|"):
            row += 1
    if len(problems) > most:
        problems[most:] = [f"{where}: and {len(problems) - most} more numbers that differ from the JSON"]
    return problems


def _introduction(nb: dict, cell: dict) -> list[str]:
    """The markdown cells just before ``cell``."""
    cells = nb["cells"]
    k = next(i for i, c in enumerate(cells) if c is cell)
    intro = []
    while k > 0 and cells[k - 1]["cell_type"] == "markdown":
        k -= 1
        intro.insert(0, _text(cells[k]["source"]))
    return intro


def results_problems(name: str, nb: dict) -> list[str]:
    """Every disagreement between the committed results and what notebook ``name`` shows of them."""
    problems = []
    for i, cell, names in results_cells(nb):
        where = f"{name}: code cell {i}"
        if not names:
            problems.append(f"{where} reads benchmarks/results but names no committed experiment to compare")
        runs = {_result(n)["runs"] for n in names}
        for text in _introduction(nb, cell):
            for m in RUN_COUNT.finditer(text):
                said = int((m.group(1) or m.group(2)).replace(",", ""))
                if said not in runs:
                    problems.append(
                        f"{name}: the text before code cell {i} says {m.group(0)!r}, but the results it shows "
                        f"rest on {', '.join(map(str, sorted(runs)))} runs"
                    )
        shown, last = [], None
        for out in cell.get("outputs", []):
            data = out.get("data", {})
            if "text/markdown" in data:
                text = _text(data["text/markdown"])
                head = TABLE_HEAD.match(text.strip())
                if head is None or head.group(1) not in COMMITTED:
                    problems.append(f"{where} shows a table of no committed experiment: {text.strip()[:80]!r}")
                    last = None
                    continue
                last = head.group(1)
                shown.append(last)
                result = _result(last)
                problems += compare_table(text, _markdown(last, result), result, f"{where}: {last}")
            elif "image/png" in data:
                png = base64.b64decode(_text(data["image/png"]))
                if last is None:
                    problems.append(f"{where} shows a figure after no experiment's table: it cannot be checked")
                elif png != (EXPERIMENTS / f"{last}.png").read_bytes():
                    problems.append(
                        f"{where}: the figure after the table of {last} is not the committed "
                        f"benchmarks/results/experiments/{last}.png (one drawn from other results)"
                    )
            else:
                text = _text(out.get("text")) or _text(data.get("text/plain"))
                if text.strip():
                    problems.append(f"{where} shows an output that cannot be checked against the JSON: {text[:120]!r}")
        problems += [f"{where} does not show {n}, whose JSON is committed" for n in names if n not in shown]
    return problems


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_shows_committed_results(path):
    """Each table and figure a notebook shows from benchmarks/results/experiments/ is the committed one."""
    problems = results_problems(path.name, _load(path))
    assert not problems, "\n".join(problems) + "\n(run: JAXNAV_DATA=<data folder> python docs/execute_notebooks.py)"


def test_results_cells_found():
    """The notebooks that show committed results have a cell that shows them: the comparison is not vacuous."""
    assert SHOWS_RESULTS <= {p.name for p in NOTEBOOKS}
    for path in NOTEBOOKS:
        cells = results_cells(_load(path))
        if path.name in SHOWS_RESULTS:
            assert cells, f"{path.name}: no code cell reads benchmarks/results"
        for i, _, names in cells:
            assert names, f"{path.name}: code cell {i} reads benchmarks/results but names no committed experiment"


def _first_results_table(nb: dict):
    """The first committed table a notebook shows: its cell index, output and experiment name."""
    for i, cell, _ in results_cells(nb):
        for out in cell["outputs"]:
            head = TABLE_HEAD.match(_text(out.get("data", {}).get("text/markdown", "")).strip())
            if head:
                return i, cell, out, head.group(1)
    raise AssertionError("no notebook output shows a committed table")


def _new(before: list[str], after: list[str]) -> list[str]:
    return [p for p in after if p not in before]


def test_edited_stored_outputs_are_caught():
    """A number, a figure, a table or a run count edited in a stored notebook is reported, with the JSON's value."""
    path = REPO / "notebooks" / "hf_rfid_slam.ipynb"
    nb = _load(path)
    i, _, out, name = _first_results_table(nb)
    out["data"]["text/markdown"] = _markdown(name, _result(name))  # as the JSON gives it, whatever is stored
    before = results_problems(path.name, nb)

    # a number of the first data row: the table's fourth value cell, one unit more in its last digit
    edited = copy.deepcopy(nb)
    _, cell, out, _ = _first_results_table(edited)
    lines = _text(out["data"]["text/markdown"]).split("\n")
    k = next(k for k, line in enumerate(lines) if SEPARATOR.match(line)) + 1
    cells = _cells(lines[k])
    value = NUMBER.findall(cells[5])[0]
    decimals = len(value.partition(".")[2])
    wrong = f"{float(value) + 10**-decimals:.{decimals}f}"
    cells[5] = cells[5].replace(value, wrong, 1)
    lines[k] = "| " + " | ".join(cells) + " |"
    out["data"]["text/markdown"] = "\n".join(lines)
    found = _new(before, results_problems(path.name, edited))
    assert len(found) == 1, found
    message = found[0]
    assert message.startswith(f"{path.name}: code cell {i}: {name}: "), message
    assert f"shows {wrong}, the JSON gives {value}" in message, message
    assert f"row {' | '.join(cells[:2])!r}, column 'dr [mm]'" in message, message
    entry = re.search(r"\((rows|curves)\[\d+\]\.\w+\.mean = ([\d.]+)\)", message)
    assert entry and f"{float(entry.group(2)):.{decimals}f}" == value, message

    # a stored figure drawn from other results
    edited = copy.deepcopy(nb)
    _, cell, _, _ = _first_results_table(edited)
    figure = next(o for o in cell["outputs"] if "image/png" in o.get("data", {}))
    figure["data"]["image/png"] = base64.b64encode(b"\x89PNG\r\n\x1a\n not the committed figure").decode()
    found = _new(before, results_problems(path.name, edited))
    assert len(found) == 1 and "is not the committed" in found[0] and f"code cell {i}" in found[0], found

    # a table left out of the stored outputs
    edited = copy.deepcopy(nb)
    _, cell, out, _ = _first_results_table(edited)
    cell["outputs"].remove(out)
    found = _new(before, results_problems(path.name, edited))
    assert any(f"does not show {name}" in p for p in found), found

    # an introduction that states another run count
    edited = copy.deepcopy(nb)
    _, cell, _, _ = _first_results_table(edited)
    k = next(k for k, c in enumerate(edited["cells"]) if c is cell)
    edited["cells"][k - 1]["source"] = _text(edited["cells"][k - 1]["source"]) + "\n\nR = 7 runs per cell."
    found = _new(before, results_problems(path.name, edited))
    assert found and all("'R = 7'" in p or "'7 runs'" in p for p in found), found
