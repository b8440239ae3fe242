"""Execute the notebooks of ``notebooks/`` in place, so that they are committed with their outputs.

The documentation shows the notebooks with the outputs stored in them (myst-nb with execution
off), so after a change to a notebook, or to what it calls, run::

    JAXNAV_DATA=<data folder> python docs/execute_notebooks.py                 # every notebook
    JAXNAV_DATA=<data folder> python docs/execute_notebooks.py ir_positioning  # some of them

Each notebook runs top to bottom in a fresh ``python3`` kernel whose working directory is a
temporary folder (so the files it writes stay out of the repository), with matplotlib's inline
backend, so each figure is stored in the notebook as an ``image/png`` output. The notebook is then
written back with its outputs and execution counts, without the volatile metadata (execution
timing, widget state).

A notebook whose metadata names a dataset it cannot run without
(``"jaxnav": {"requires_data": "<folder>"}``) is left as it is, with a message, when that folder is
not in the data folder (``$JAXNAV_DATA``, else ``../shared/data`` relative to the repository, see
:mod:`jaxnav.io`). A notebook that uses a dataset in one section only (``"jaxnav": {"uses_data":
"<folder>"}``) is left as it is too when the folder is absent, unless ``--without-data`` is given: its
real-data section then holds a one-line message instead of results.

Exit status: 0 when every notebook named ran without error (or was left for want of its data),
1 otherwise. A notebook that raises is not written back.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import re
import sys
import tempfile
import time

REPO = pathlib.Path(__file__).resolve().parents[1]
NOTEBOOKS = REPO / "notebooks"
INLINE_BACKEND = "module://matplotlib_inline.backend_inline"

# Cell metadata written by the execution that changes on every run.
VOLATILE_CELL_METADATA = ("execution", "ExecuteTime", "papermill", "collapsed", "scrolled")
VOLATILE_NOTEBOOK_METADATA = ("widgets", "papermill", "toc-autonumbering")


def data_folders() -> list[pathlib.Path]:
    """The data folders jaxnav's loaders try, in order."""
    if str(REPO) not in sys.path:
        sys.path.insert(0, str(REPO))
    from jaxnav.io._data import data_candidates

    return data_candidates(None)


def dataset_present(folder: str) -> bool:
    """Whether ``<data>/<folder>`` exists in one of the data folders; if so, the kernels are pointed at it.

    The kernels run in a temporary folder and may import an installed jaxnav, whose default data folder
    is the user's, not this checkout's: ``$JAXNAV_DATA`` is set to the data folder found here.
    """
    base = next((base for base in data_folders() if (base / folder).is_dir()), None)
    if base is not None:
        os.environ.setdefault("JAXNAV_DATA", str(base))
    return base is not None


def resolve(names: list[str]) -> list[pathlib.Path]:
    """The notebooks named (a path, a file name or a stem), or every notebook of ``notebooks/``."""
    if not names:
        return sorted(NOTEBOOKS.glob("*.ipynb"))
    out = []
    for name in names:
        path = pathlib.Path(name)
        for candidate in (path, NOTEBOOKS / path.name, NOTEBOOKS / f"{path.name}.ipynb"):
            if candidate.is_file() and candidate.suffix == ".ipynb":
                out.append(candidate.resolve())
                break
        else:
            raise SystemExit(f"no notebook {name!r} (in {NOTEBOOKS})")
    return out


def strip_volatile(nb) -> None:
    """Remove the metadata that changes from one execution to the next."""
    for key in VOLATILE_NOTEBOOK_METADATA:
        nb.metadata.pop(key, None)
    for cell in nb.cells:
        for key in VOLATILE_CELL_METADATA:
            cell.metadata.pop(key, None)


def machine_paths() -> list[str]:
    """Folders of this machine that no stored output should name (the repository, its parent, temp, home)."""
    places = [REPO, pathlib.Path(tempfile.gettempdir()), pathlib.Path.home()]
    if REPO.parent != REPO.parent.parent:
        places.append(REPO.parent)
    return [str(p) + os.sep for p in places if p != p.parent]


# A cell that draws: pyplot, a figure's methods, a jaxnav plot function, an image shown.
PLOTTING = re.compile(r"\bplt\.|\bfig\.|\.plot\(|\bplot_\w+\(|\bImage\(")


def check_outputs(nb) -> list[str]:
    """What a reader of the stored outputs would stumble on: errors, warnings, figures not stored, local paths."""
    problems = []
    for i, cell in enumerate(nb.cells):
        if cell.cell_type != "code":
            continue
        outputs = cell.get("outputs", [])
        texts = []
        for out in outputs:
            if out.get("output_type") == "error":
                problems.append(f"cell {i}: {out.get('ename')}: {out.get('evalue')}")
            if out.get("output_type") == "stream" and out.get("name") == "stderr":
                problems.append(f"cell {i}: writes to stderr: {out.get('text', '').strip()[:200]}")
            data = out.get("data", {})
            texts.append(
                "".join(out.get("text", ""))
                + "".join(data.get("text/plain", ""))
                + "".join(data.get("text/markdown", ""))
            )
        text = "\n".join(texts)
        has_image = any("image/png" in o.get("data", {}) for o in outputs)
        skipped = "skipped" in text.lower()
        if PLOTTING.search(cell.source) and not has_image and not skipped:
            problems.append(f"cell {i}: it draws, but no image/png output was stored")
        if any(place in text for place in machine_paths()):
            problems.append(f"cell {i}: an output names a folder of this machine")
    return problems


def execute(path: pathlib.Path, timeout: int, without_data: bool = False) -> bool:
    """Execute one notebook in place; False if it failed (then it is not written back)."""
    import nbclient
    import nbformat

    nb = nbformat.read(path, as_version=4)
    meta = nb.metadata.get("jaxnav", {})
    needed = meta.get("requires_data")
    if needed and not dataset_present(needed):
        print(
            f"{path.name}: left unexecuted, it needs the dataset {needed!r}, absent from "
            f"{' and '.join(map(str, data_folders()))} (set JAXNAV_DATA)"
        )
        return True
    used = meta.get("uses_data")
    if used and not dataset_present(used):
        if not without_data:
            print(
                f"{path.name}: left unexecuted, its real-data section needs the dataset {used!r}, absent from "
                f"{' and '.join(map(str, data_folders()))} (set JAXNAV_DATA, or pass --without-data to store "
                "that section's 'skipped' messages instead of its results)"
            )
            return True
        print(f"{path.name}: the dataset {used!r} is absent: its real-data section stores a message, not results")
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="jaxnav-nb-") as work:
        client = nbclient.NotebookClient(
            nb,
            timeout=timeout,
            kernel_name="python3",
            record_timing=False,
            resources={"metadata": {"path": work}},
        )
        try:
            client.execute()
        except (
            nbclient.exceptions.CellExecutionError,
            nbclient.exceptions.CellTimeoutError,
            nbclient.exceptions.DeadKernelError,
        ) as exc:
            print(f"{path.name}: FAILED, not written back\n{exc}")
            return False
    seconds = time.perf_counter() - start
    strip_volatile(nb)
    problems = check_outputs(nb)
    images = sum("image/png" in o.get("data", {}) for c in nb.cells if c.cell_type == "code" for o in c.outputs)
    nbformat.validate(nb)
    nbformat.write(nb, path)
    print(f"{path.name}: executed in {seconds:.0f} s, {images} image(s)")
    for problem in problems:
        print(f"  warning: {problem}")
    return True


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("notebooks", nargs="*", help="notebooks to execute (default: all of notebooks/)")
    parser.add_argument("--timeout", type=int, default=1200, help="seconds allowed per cell (default 1200)")
    parser.add_argument(
        "--without-data",
        action="store_true",
        help="execute a notebook whose real-data section lacks its data (that section then stores a message)",
    )
    args = parser.parse_args(argv)
    # The kernel inherits this environment: figures go to the notebook as PNG, not to a window or nowhere.
    os.environ["MPLBACKEND"] = INLINE_BACKEND
    ok = [execute(path, args.timeout, args.without_data) for path in resolve(args.notebooks)]
    return 0 if all(ok) else 1


if __name__ == "__main__":
    sys.exit(main())
