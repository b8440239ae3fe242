"""The README and the documentation: their code runs, their links resolve, they speak of the library only.

The site itself is built by ``.ci/run`` (``sphinx-build -W -n``, then ``docs/check_links.py``); these
tests cover what that build cannot see: that the Python examples run as written, that the README stays
a front page, and the helpers the build relies on.
"""

from __future__ import annotations

import json
import pathlib
import re

import pytest

from tests import doc_examples

ROOT = pathlib.Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def _hand_written_pages() -> list[pathlib.Path]:
    pages = [ROOT / "README.md", ROOT / "benchmarks" / "README.md"]
    pages += [p for p in DOCS.rglob("*.md") if "_generated" not in p.parts and "_build" not in p.parts]
    return sorted(pages)


# Pages whose examples run more than they compile (the README's study is 100 runs of 120 steps): run with
# XLA's default flags. The pages whose examples compile more than they run are in tests/test_docs_guides.py
# (each page's blocks timed under both flags: these four take 24 s with the defaults against 40 s with the
# suite's, the others 43 s with the suite's against 66 s with the defaults).
EXAMPLE_PAGES = (
    "README.md",
    "docs/index.md",
    "docs/getting-started.md",
    "docs/guides/calibration.md",
)


@pytest.fixture(scope="module")
def example_outcomes(tmp_path_factory, xla_defaults_env):
    """The examples of :data:`EXAMPLE_PAGES`, run in one process with XLA's default flags
    (tests/doc_examples.py; the other pages' run in tests/test_docs_guides.py, on the other worker)."""
    return doc_examples.run_pages(EXAMPLE_PAGES, tmp_path_factory.mktemp("examples"), xla_defaults_env)


@pytest.mark.parametrize("page", EXAMPLE_PAGES)
def test_python_examples_run_as_written(page, example_outcomes):
    assert doc_examples.python_blocks(ROOT / page), f"{page} has no Python example"
    assert example_outcomes[page] is None, f"{page}:\n{example_outcomes[page]}"


def test_every_page_with_python_examples_runs_them():
    from tests.test_docs_guides import COMPILE_BOUND_PAGES

    run = set(EXAMPLE_PAGES) | set(COMPILE_BOUND_PAGES)
    assert not set(EXAMPLE_PAGES) & set(COMPILE_BOUND_PAGES)
    with_examples = {str(p.relative_to(ROOT)) for p in _hand_written_pages() if doc_examples.python_blocks(p)}
    assert with_examples <= run, f"pages whose ```python blocks no test runs: {sorted(with_examples - run)}"


def test_readme_is_a_front_page():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= 200, f"README.md has {len(lines)} lines; the details belong in docs/"
    text = "\n".join(lines)
    for needed in ('pip install ".[plot]" && jaxnav demo', 'pip install -e ".[dev]" && python -m pytest'):
        assert needed in text


# Words about how the work was organised or files a user does not have; never about the library.
_FORBIDDEN = re.compile(
    r"this round|last round|previous round|earlier rounds?|target:? met|the issue|this issue|this session|"
    r"ARCHITECTURE\.md|SPEC §|STYLE\.md|STYLE item|BENCHMARKS\.md|/work/|\.\./shared/BENCH",
    re.I,
)
_COMMIT_HASH = re.compile(r"\b(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}\b")


@pytest.mark.parametrize("page", _hand_written_pages(), ids=lambda p: str(p.relative_to(ROOT)))
def test_pages_speak_of_the_library_only(page):
    text = page.read_text()
    hits = [m.group(0) for m in _FORBIDDEN.finditer(text)] + [
        m.group(0) for m in _COMMIT_HASH.finditer(text) if not m.group(0).isdigit()
    ]
    assert not hits, f"{page.relative_to(ROOT)}: {hits}"


def test_citation_file_names_the_package_version():
    import jaxnav

    cff = (ROOT / "CITATION.cff").read_text()
    assert re.search(r'^version: "?([^"\n]+)"?$', cff, re.M).group(1) == jaxnav.__version__
    for thesis in ("Technical University of Crete", "University of Fukui", "hdl.handle.net/10098/10572"):
        assert thesis in cff


def test_link_checker_finds_missing_files_fragments_and_remote_assets(tmp_path):
    check = doc_examples.load_docs_script("check_links")
    (tmp_path / "sub").mkdir()
    (tmp_path / "index.html").write_text(
        '<a href="sub/page.html#here">ok</a><a href="sub/page.html#gone">bad id</a>'
        '<a href="missing.html">bad file</a><a href="https://example.org/x">external</a>'
        '<img src="sub/pic.png?v=3"><a href="#top">self</a><p id="top"></p>'
    )
    (tmp_path / "sub" / "page.html").write_text(
        '<h1 id="here">x</h1><a href="../index.html">up</a><script src="../mathjax/tex.js"></script>'
        '<script src="https://cdn.example.org/mathjax/tex.js"></script>'
        '<link rel="stylesheet" href="//cdn.example.org/x.css"><link rel="canonical" href="https://example.org/">'
    )
    (tmp_path / "sub" / "pic.png").write_bytes(b"")
    (tmp_path / "mathjax").mkdir()
    (tmp_path / "mathjax" / "tex.js").write_text("")
    bad = check.broken_links(str(tmp_path))
    assert sorted(bad) == [
        "index.html: missing.html (no such file)",
        "index.html: sub/page.html#gone (no id 'gone' there)",
        "sub/page.html: //cdn.example.org/x.css (loaded from the network)",
        "sub/page.html: https://cdn.example.org/mathjax/tex.js (loaded from the network)",
    ]


def test_thesis_summary_counts_values_against_intervals():
    generate = doc_examples.load_docs_script("generate")
    result = {
        "rows": [
            {"x_mm": {"mean": 10.0, "ci95": [8.0, 12.0], "paper": 11.0}},  # inside
            {"x_mm": {"mean": 10.0, "ci95": [8.0, 12.0], "paper": 20.0}},  # above
            {
                "x_mm": {"mean": 10.0, "ci95": [8.0, 12.0], "paper": 5.0},
                "y": {"mean": 1.0, "ci95": [0.5, 1.5], "paper": None},
            },
        ]
    }
    text = generate.thesis_summary(result)
    assert text.startswith("Of the 3 values the thesis reports, 1 lie inside our 95 % interval, 1 above it")
    assert "and 1 below it" in text
    assert generate.thesis_summary({"rows": [{"x": {"mean": 1.0, "ci95": [0.0, 2.0], "paper": None}}]}) == ""


def test_benchmark_headers_name_the_machine_but_no_revision_or_local_path():
    generate = doc_examples.load_docs_script("generate")
    header = (
        "Measured on AMD EPYC, 2 cores, copy bandwidth 24.9 GB/s; jaxnav 74a1c12+dirty, jax 0.10.2. "
        "Command: `python -m benchmarks.run --only W2 --out /tmp/x/after.json`."
    )
    text = generate._without_provenance(header, "speed/after_main.json")
    assert text == (
        "Measured on AMD EPYC, 2 cores, copy bandwidth 24.9 GB/s; jax 0.10.2. "
        "Command: `python -m benchmarks.run --only W2 --out benchmarks/results/speed/after_main.json`."
    )


def test_every_public_module_gets_an_api_page():
    generate = doc_examples.load_docs_script("generate")
    modules = generate.public_modules()
    for name in ("jaxnav.core.resampling", "jaxnav.slam.ps_slam", "jaxnav.localization.rfid_tag", "jaxnav.cli"):
        assert name in modules
    assert not [m for m in modules if any(part.startswith("_") for part in m.split("."))]


def test_every_registered_experiment_has_a_committed_full_result():
    """The reproduction pages are generated from these files; a page below its run count says so."""
    from jaxnav.experiments import registry

    generate = doc_examples.load_docs_script("generate")
    for name in registry.names():
        result = json.loads((ROOT / "benchmarks" / "results" / "experiments" / f"{name}.json").read_text())
        assert result["experiment"] == name and result["quick"] is False and result["runs"] >= 1
        assert generate.runs_needed(name, result) in (50, 100)


def test_committed_results_have_the_runs_their_pages_promise():
    """Tables rest on at least 100 runs per row, figures on at least 50 per point."""
    from jaxnav.experiments import registry

    generate = doc_examples.load_docs_script("generate")
    short = []
    for name in registry.names():
        result = json.loads((ROOT / "benchmarks" / "results" / "experiments" / f"{name}.json").read_text())
        if result["runs"] < generate.runs_needed(name, result):
            short.append(f"{name}: {result['runs']} runs, at least {generate.runs_needed(name, result)} expected")
    assert not short, short
