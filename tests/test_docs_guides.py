"""The Python examples of the family guides, the interface page and the scaling-out page run as written
(tests/doc_examples.py), in a process of their own so that they run beside the README's and the other
pages' examples (tests/test_docs.py) on the suite's other worker. These examples compile more than they
run, so the process keeps the suite's compile-fast XLA flags (tests/conftest.py). A page's blocks that
need a dataset are ```{code-block} python and are not run."""

from __future__ import annotations

import os

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
