"""The API reference's index: every public module in exactly one group, the internals marked as such.

These tests write the API pages with ``docs/generate.py`` into a temporary folder and read the
generated Markdown; they do not run Sphinx (the site is built by ``.ci/run``).
"""

from __future__ import annotations

import pathlib
import re

import pytest

from tests import doc_examples

ROOT = pathlib.Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


@pytest.fixture(scope="module")
def generate():
    return doc_examples.load_docs_script("generate", "generate_api")


@pytest.fixture(scope="module")
def api(generate, tmp_path_factory) -> pathlib.Path:
    """The folder of the generated API pages."""
    out = tmp_path_factory.mktemp("generated")
    generate.write_api(str(out))
    return out / "api"


def _toctree(page: pathlib.Path) -> list[tuple[str, str]]:
    """``(title, document)`` of every entry of the toctrees of a generated page."""
    entries = []
    for block in re.findall(r"^```\{toctree\}\n(.*?)^```", page.read_text(), flags=re.S | re.M):
        for line in block.splitlines():
            if not line.strip() or line.startswith(":"):
                continue
            m = re.fullmatch(r"(.*) <(.*)>", line.strip())
            entries.append((m.group(1), m.group(2)) if m else (line.strip(), line.strip()))
    return entries


def test_every_public_module_is_in_exactly_one_group(generate, api):
    modules = generate.public_modules()
    groups = [doc for _, doc in _toctree(api / "index.md")]
    assert groups and all(doc.startswith("group-") for doc in groups)
    listed = [doc for group in groups for _, doc in _toctree(api / f"{group}.md")]
    assert sorted(listed) == sorted(modules)  # none left out, none twice
    for name in modules:
        assert (api / f"{name}.md").exists()
    # and the index lists each module once, under its group's heading
    index = (api / "index.md").read_text()
    for name in modules:
        assert index.count(f"[`{name}`]({name}.md)") == 1


def test_groups_follow_the_package_layout(generate, api):
    titles = [title for _, title, _, _ in generate.api_groups(generate.public_modules())]
    assert titles[:7] == ["Core", "Models", "Simulators", "Localization", "SLAM", "Experiments", "IO"]
    assert titles[-1] == "Internals"
    group_of = {
        doc: group for group in (d for _, d in _toctree(api / "index.md")) for _, doc in _toctree(api / f"{group}.md")
    }
    assert group_of["jaxnav.localization.mcl"] == "group-localization"
    assert group_of["jaxnav.slam.fastslam"] == "group-slam"
    assert group_of["jaxnav.sim.tag_carpet"] == "group-sim"
    assert group_of["jaxnav.io.mrclam"] == "group-io"
    assert group_of["jaxnav.core.resampling"] == "group-core"
    assert group_of["jaxnav.calibration"] == group_of["jaxnav.metrics"] == group_of["jaxnav.demo"] == "group-tools"


def test_a_new_module_gets_a_group_by_its_package(generate):
    modules = ["jaxnav", "jaxnav.core", "jaxnav.planning", "jaxnav.planning.rrt", "jaxnav.slam.graph", "jaxnav.extra"]
    groups = {key: names for key, _, _, names in generate.api_groups(modules)}
    assert groups["planning"] == ["jaxnav.planning", "jaxnav.planning.rrt"]
    assert "jaxnav.slam.graph" in groups["slam"]
    assert groups["tools"] == ["jaxnav.extra"]
    assert sorted(n for names in groups.values() for n in names) == sorted(modules)


def test_internals_are_marked(generate, api):
    internals = {"jaxnav.cli", "jaxnav.core.u64", "jaxnav.core.fastmath"}
    internals |= {
        m for m in generate.public_modules() if m.startswith("jaxnav.experiments.") and m.endswith(".figures")
    }
    assert len(internals) > 3
    entries = dict((doc, title) for title, doc in _toctree(api / "group-internals.md"))
    assert internals <= entries.keys()
    assert (api / "group-internals.md").read_text().startswith("# Internals\n")
    index = (api / "index.md").read_text()
    assert "## [Internals](group-internals.md)" in index
    for name in entries:
        assert generate.is_internal(name)
        assert "An internal module" in (api / f"{name}.md").read_text()  # the page says so too
    public = [m for m in generate.public_modules() if m not in entries]
    assert "jaxnav.localization.mcl" in public and "jaxnav.core.resampling" in public
    for name in public:
        assert "An internal module" not in (api / f"{name}.md").read_text()


def test_sidebar_titles_are_short(generate, api):
    """A module's title in the sidebar is its name inside its group, short enough not to be broken."""
    for _, group in _toctree(api / "index.md"):
        for title, doc in _toctree(api / f"{group}.md"):
            assert doc.endswith(title) or doc == "jaxnav"
            assert len(title) <= 24, title
    titles = dict((doc, title) for title, doc in _toctree(api / "group-localization.md"))
    assert titles["jaxnav.localization.mcl"] == "mcl"


def test_a_re_exported_alias_is_documented_where_it_is_defined(generate, api):
    """``ukf.KalmanParams`` is ``ekf.KalmanParams`` (an alias of ``LandmarkMapParams``): its page links to
    the documented alias rather than showing a bare "alias of"."""
    page = (api / "jaxnav.localization.ukf.md").read_text()
    assert ":exclude-members: KalmanParams" in page
    assert "{py:obj}`~jaxnav.localization.ekf.KalmanParams`" in page
