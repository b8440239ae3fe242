"""Every notebook in notebooks/ runs top to bottom (so none can rot).

A notebook that needs a dataset from ``$JAXNAV_DATA`` names it in its
metadata (``"jaxnav": {"requires_data": "<folder>"}``) and is skipped, saying
why, only when that folder is absent.
"""

import pathlib

import pytest

NOTEBOOKS = sorted((pathlib.Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_executes(path, tmp_path, monkeypatch):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    nb = nbformat.read(path, as_version=4)
    needed = nb.metadata.get("jaxnav", {}).get("requires_data")
    if needed:
        import os

        from jaxnav.io.mrclam import ENV_VAR

        root = pathlib.Path(
            os.environ.get(ENV_VAR, pathlib.Path(__file__).resolve().parents[1] / ".." / "shared" / "data")
        )
        if not (root / needed).is_dir():
            pytest.skip(f"{path.name} needs {root / needed} (set {ENV_VAR})")
    client = nbclient.NotebookClient(
        nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}
    )
    client.execute()
    errors = [
        o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []) if o.get("output_type") == "error"
    ]
    assert not errors
