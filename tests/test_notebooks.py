"""The notebooks of notebooks/: each runs top to bottom (so none can rot), and each is stored with its outputs.

The documentation shows the notebooks with the outputs stored in them (it does not execute them),
so :func:`test_notebook_stored_with_outputs` checks that every notebook was executed top to bottom
in one kernel (``python docs/execute_notebooks.py`` does that) and holds a figure.

Data: a notebook that cannot run at all without a dataset from the data folder names it in its
metadata (``"jaxnav": {"requires_data": "<folder>"}``) and its execution is skipped, saying why,
only when that folder is absent. A notebook that needs a dataset in one section only names it as
``"uses_data"`` and runs either way: the cells of that section (tagged ``real-data``, the first of
them looking the data up) print a one-line message instead of their work when it is absent, which
:func:`test_notebook_data_section_without_data` checks by hiding the data.
"""

from __future__ import annotations

import json
import os
import pathlib
import re

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((REPO / "notebooks").glob("*.ipynb"))
IDS = [p.name for p in NOTEBOOKS]
DATA_TAG = "real-data"
HOW_TO_EXECUTE = "run: JAXNAV_DATA=<data folder> python docs/execute_notebooks.py"
# Notebooks whose time goes to running simulations rather than compiling them: their kernel gets
# XLA's default flags. The others compile more than they run and keep the suite's compile-fast
# flags (measured per notebook, executed alone: hf_rfid_slam 38 → 32 s, ir_positioning 42 → 29 s,
# mrclam_real_data 44 → 26 s, uhf_rfid_localization 49 → 21 s; mcl_quickstart 21 → 27 s, its
# 64-run Monte Carlo cell running twice as long).
RUN_BOUND = {"mcl_quickstart.ipynb"}


def _read(path):
    nbformat = pytest.importorskip("nbformat")
    return nbformat.read(path, as_version=4)


def _code_cells(nb):
    return [c for c in nb.cells if c.cell_type == "code" and c.source.strip()]


def _text(output) -> str:
    """The text of one output: a stream, a result or display (text/plain and text/markdown), an error."""
    parts = [output.get("text", "")]
    for mime in ("text/plain", "text/markdown"):
        parts.append(output.get("data", {}).get(mime, ""))
    if output.get("output_type") == "error":
        parts += [output.get("ename", ""), output.get("evalue", "")]
    return "\n".join("".join(p) if isinstance(p, list) else p for p in parts)


def _data_folder(dataset: str) -> pathlib.Path | None:
    """The data folder holding ``dataset`` where jaxnav's loaders look (``$JAXNAV_DATA``, ``../shared/data``)."""
    from jaxnav.io._data import data_candidates

    return next((base for base in data_candidates(None) if (base / dataset).is_dir()), None)


def _execute(nb, workdir: pathlib.Path):
    nbclient = pytest.importorskip("nbclient")
    client = nbclient.NotebookClient(
        nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(workdir)}}
    )
    client.execute()
    errors = [_text(o) for c in _code_cells(nb) for o in c.outputs if o.get("output_type") == "error"]
    assert not errors, errors


@pytest.mark.parametrize("path", NOTEBOOKS, ids=IDS)
def test_notebook_executes(path, tmp_path, monkeypatch, xla_defaults_env):
    """Each notebook runs top to bottom without an error (on a copy: the repository's file is not written).

    The kernel of a notebook in :data:`RUN_BOUND` gets XLA's default flags: its simulations run long
    enough that the suite's compile-fast flags would cost more run time than they save compilation."""
    from jaxnav.io._data import ENV_VAR

    monkeypatch.setenv("MPLBACKEND", "Agg")
    if path.name in RUN_BOUND:
        monkeypatch.setenv("XLA_FLAGS", xla_defaults_env["XLA_FLAGS"])
    nb = _read(path)
    meta = nb.metadata.get("jaxnav", {})
    needed, used = meta.get("requires_data"), meta.get("uses_data")
    for dataset in filter(None, (needed, used)):
        folder = _data_folder(dataset)
        if folder is not None:  # the kernel runs elsewhere: point it at the folder found here
            monkeypatch.setenv(ENV_VAR, str(folder))
        elif dataset == needed:
            pytest.skip(f"{path.name} needs the dataset {dataset!r} (set {ENV_VAR} to the folder holding it)")
    _execute(nb, tmp_path)
    if used and _data_folder(used) is not None:  # with the data, its section did its work
        section = [c for c in _code_cells(nb) if DATA_TAG in c.metadata.get("tags", [])]
        assert section, f"{path.name} uses {used!r} but tags no cell {DATA_TAG!r}"
        assert not any("skipped" in _text(o).lower() for c in section for o in c.outputs)


def _uses_data(path: pathlib.Path) -> bool:
    return "uses_data" in json.loads(path.read_text(encoding="utf-8"))["metadata"].get("jaxnav", {})


@pytest.mark.parametrize("path", [p for p in NOTEBOOKS if _uses_data(p)], ids=lambda p: p.name)
def test_notebook_data_section_without_data(path, tmp_path, monkeypatch):
    """With the data absent, each cell of the data section prints a message instead of failing."""
    from jaxnav.io._data import ENV_VAR

    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.setenv(ENV_VAR, str(tmp_path / "no-data"))  # hides the data wherever it is
    nb = _read(path)
    code = _code_cells(nb)
    section = [c for c in code if DATA_TAG in c.metadata.get("tags", [])]
    assert section, f"{path.name} uses data but tags no cell {DATA_TAG!r}"
    nb.cells = [code[0]] + section  # the imports, then the data section alone (the simulations take long)
    (tmp_path / "no-data").mkdir()
    _execute(nb, tmp_path)
    lookup, *rest = section
    message = "".join(_text(o) for o in lookup.outputs)
    assert ENV_VAR in message and "skipped" in message.lower(), message
    for cell in rest:
        printed = "".join(_text(o) for o in cell.outputs)
        assert printed.strip().lower().startswith("skipped"), printed
        assert len(printed.strip().splitlines()) == 1, printed


# Absolute paths that name one machine's folders (a home, a temporary folder, the checkout and its parent).
_PLACES = [r"/home/\w", r"/Users/\w", r"/tmp/\w", r"/private/var/", r"[A-Za-z]:\\Users\\", re.escape(str(REPO))]
if REPO.parent.parent != REPO.parent:
    _PLACES.append(re.escape(str(REPO.parent) + os.sep))
MACHINE_PATH = re.compile("|".join(_PLACES))


@pytest.mark.parametrize("path", NOTEBOOKS, ids=IDS)
def test_notebook_stored_with_outputs(path):
    """The stored notebook ran top to bottom in one kernel, without error, and holds at least one figure."""
    nb = _read(path)
    code = _code_cells(nb)
    assert code, f"{path.name} has no code"
    counts = [c.get("execution_count") for c in code]
    unrun = [i for i, n in enumerate(counts) if n is None]
    assert not unrun, f"{path.name}: code cells {unrun} (of {len(code)}) were stored without running ({HOW_TO_EXECUTE})"
    assert counts == list(range(1, len(code) + 1)), (
        f"{path.name}: execution counts {counts}, not 1, 2, 3, …: not run top to bottom in one kernel ({HOW_TO_EXECUTE})"
    )
    outputs = [(i, o) for i, c in enumerate(code) for o in c.get("outputs", [])]
    errors = [f"code cell {i}: {o.get('ename')}: {o.get('evalue')}" for i, o in outputs if o.output_type == "error"]
    assert not errors, f"{path.name} was stored with errors: {errors}"
    images = [i for i, o in outputs if "image/png" in o.get("data", {})]
    assert images, f"{path.name} holds no image/png output: its figures were not stored ({HOW_TO_EXECUTE})"
    local = [f"code cell {i}: {m.group(0)}…" for i, o in outputs for m in [MACHINE_PATH.search(_text(o))] if m]
    assert not local, f"{path.name}: outputs name folders of the machine that ran it: {local}"
