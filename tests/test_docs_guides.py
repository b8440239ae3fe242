"""The family guides' Python examples run as written (tests/doc_examples.py), in a process of their own
so that they run beside the other pages' examples (tests/test_docs.py) on the suite's other worker.
A guide's blocks that need a dataset are ```{code-block} python and are not run."""

from __future__ import annotations

import pytest

from tests import doc_examples

GUIDE_PAGES = (
    "docs/guides/classical.md",
    "docs/guides/hf-rfid-slam.md",
    "docs/guides/ir.md",
    "docs/guides/uhf-rfid.md",
)


@pytest.fixture(scope="module")
def guide_outcomes(tmp_path_factory, xla_defaults_env):
    return doc_examples.run_pages(GUIDE_PAGES, tmp_path_factory.mktemp("guides"), xla_defaults_env)


@pytest.mark.parametrize("page", GUIDE_PAGES)
def test_guide_examples_run_as_written(page, guide_outcomes):
    assert doc_examples.python_blocks(doc_examples.ROOT / page), f"{page} has no Python example"
    assert guide_outcomes[page] is None, f"{page}:\n{guide_outcomes[page]}"
