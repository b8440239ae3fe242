"""The Python examples of the family guides, the interface page and the scaling-out page run as written
(tests/doc_examples.py), in a process of their own so that they run beside the README's and the other
pages' examples (tests/test_docs.py) on the suite's other worker. These examples compile more than they
run, so the process keeps the suite's compile-fast XLA flags (tests/conftest.py). A page's blocks that
need a dataset are ```{code-block} python and are not run.

The family guides are executed pages: the documentation build runs their ```{code-cell} python cells
and shows what they print and draw. This file runs the same cells, so that the suite fails first."""

from __future__ import annotations

import os
import re

import pytest

from tests import doc_examples

COMPILE_BOUND_PAGES = (
    "docs/guides/classical.md",
    "docs/guides/hf-rfid-slam.md",
    "docs/guides/ir.md",
    "docs/guides/uhf-rfid.md",
    "docs/interface.md",
    "docs/guides/scaling-out.md",
)


@pytest.fixture(scope="module")
def page_outcomes(tmp_path_factory):
    return doc_examples.run_pages(COMPILE_BOUND_PAGES, tmp_path_factory.mktemp("pages"), dict(os.environ))


@pytest.mark.parametrize("page", COMPILE_BOUND_PAGES)
def test_page_examples_run_as_written(page, page_outcomes):
    assert doc_examples.python_blocks(doc_examples.ROOT / page), f"{page} has no Python example"
    assert page_outcomes[page] is None, f"{page}:\n{page_outcomes[page]}"


# The family guides: executed pages (MyST notebooks run by the documentation build) that open with an
# example drawing its figure, and link the notebooks of their family from that first section.
EXECUTED_GUIDES = {
    "docs/guides/classical.md": ("mcl_quickstart", "mrclam_real_data"),
    "docs/guides/hf-rfid-slam.md": ("hf_rfid_slam",),
    "docs/guides/ir.md": ("ir_positioning",),
    "docs/guides/uhf-rfid.md": ("uhf_rfid_localization",),
    "docs/guides/calibration.md": ("uhf_calibration",),
}


def _front_matter(text: str) -> str:
    assert text.startswith("---\n"), "no front matter"
    return text[4 : text.index("\n---\n", 4)]


def _first_section(text: str) -> str:
    """The page's first ``##`` section, up to the next one."""
    start = text.index("\n## ")
    return text[start : text.index("\n## ", start + 1)]


def _first_screen(text: str) -> str:
    """The page's first ``##`` section up to the end of its first code cell."""
    start = text.index("\n## ")
    cell = text.index("```{code-cell} python\n", start)
    return text[start : text.index("\n```\n", cell) + 4]


@pytest.mark.parametrize("page", sorted(EXECUTED_GUIDES))
def test_family_guides_are_executed_pages_that_open_with_a_figure(page):
    """Each family's guide is run by the documentation build and shows, on its first screen, the
    notebooks that go further and an example, which draws its figure within the first section."""
    text = (doc_examples.ROOT / page).read_text()
    front = _front_matter(text)
    assert "file_format: mystnb" in front and "name: python3" in front, front
    assert "execution_mode: cache" in front, f"{page} is not executed by the build"
    first = _first_screen(text)
    assert len(re.findall(doc_examples.PYTHON_BLOCK, first, flags=re.S | re.M)) == 1
    cells = re.findall(doc_examples.PYTHON_BLOCK, _first_section(text), flags=re.S | re.M)
    assert any("plt.subplots" in cell for cell in cells), f"{page}: its first example draws no figure"
    for notebook in EXECUTED_GUIDES[page]:
        assert f"{{doc}}`/notebooks/{notebook}`" in first, f"{page}: {notebook} is not linked on its first screen"


def test_every_notebook_is_linked_from_a_guide():
    linked = {nb for notebooks in EXECUTED_GUIDES.values() for nb in notebooks}
    notebooks = {p.stem for p in (doc_examples.ROOT / "notebooks").glob("*.ipynb")}
    assert notebooks == linked, f"notebooks no guide opens with: {sorted(notebooks - linked)}"


def test_the_documentation_build_executes_the_guides_and_fails_on_an_error():
    conf = (doc_examples.DOCS / "conf.py").read_text()
    assert 'nb_execution_mode = "off"' in conf  # the notebooks keep their committed outputs
    assert "nb_execution_raise_on_error = True" in conf
