"""What ``jaxnav --help`` and every command's ``--help`` tell a newcomer: a description, examples that
parse with the real parser, the two theses; ``jaxnav experiments`` without an action shows its help;
``jaxnav experiments run`` says when it writes no PNG."""

from __future__ import annotations

import argparse
import os
import re
import shlex
import sys

import numpy as np
import pytest

from jaxnav import cli

COMMANDS = ("demo", "mrclam", "uwb", "hf-slam", "ir", "uhf-real", "experiments")


def _help(argv, capsys) -> str:
    with pytest.raises(SystemExit) as stop:
        cli.main([*argv, "--help"])
    assert stop.value.code == 0
    return capsys.readouterr().out


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def _examples(text: str | None) -> list[str]:
    """The command lines of the ``Examples:`` section of a help text (none without one)."""
    found = re.search(r"^Examples:\n((?:  .*\n?)+)", text or "", re.MULTILINE)
    return [line.strip() for line in found.group(1).splitlines() if line.strip().startswith("jaxnav ")] if found else []


def test_every_command_is_covered():
    assert tuple(_subparsers(cli.build_parser())) == COMMANDS


@pytest.mark.parametrize("command", COMMANDS)
def test_every_command_has_a_description_and_examples_of_itself(command, capsys):
    text = _help([command], capsys)
    description = _subparsers(cli.build_parser())[command].description
    assert description and len(description) > 200, description
    assert description.splitlines()[0] in text  # printed as written, not rewrapped
    examples = _examples(text)
    assert examples, text
    assert all(shlex.split(e)[:2] == ["jaxnav", command] for e in examples), examples
    assert all(len(line) <= 110 for line in text.splitlines()), text


def _all_examples() -> list[str]:
    parser = cli.build_parser()
    out = _examples(parser.epilog)
    for sub in _subparsers(parser).values():
        out += _examples(sub.epilog)
    return list(dict.fromkeys(out))


def test_there_are_examples_to_parse():
    assert len(_all_examples()) >= 2 * len(COMMANDS)


@pytest.mark.parametrize("example", _all_examples())
def test_every_example_parses_with_the_real_parser(example):
    from jaxnav.experiments import registry

    argv = shlex.split(example, comments=True)
    assert argv[0] == "jaxnav"
    args = cli.build_parser().parse_args(argv[1:])  # a refusal exits (SystemExit 2) and fails the test
    assert args.func is not None
    if args.command == "experiments" and args.action == "run":
        assert args.name in registry.names()


def test_the_top_level_help_names_the_theses_and_the_docs(capsys):
    text = _help([], capsys)
    assert '[A] G. Apostolakis, "Unmanned Vehicle Navigation in GPS-Denied Environments"' in text
    assert "Technical University of Crete, 2020" in text
    assert '[W] J. Wang, "SLAM Method for A RFID Positioning System' in text
    assert "University of Fukui, 2019" in text
    assert "docs/" in text and "sphinx-build docs docs/_build/html" in text
    assert len(_examples(text)) >= 2
    for command in COMMANDS:
        assert f"\n    {command}" in text


def test_no_command_prints_the_help(capsys):
    assert cli.main([]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: jaxnav") and "[A] G. Apostolakis" in out and "Examples:" in out


def test_experiments_without_an_action_prints_its_help_and_exits_2(capsys):
    assert cli.main(["experiments"]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err.startswith("usage: jaxnav experiments [-h] {list,run} [NAME]")
    assert "  list " in err and "  run NAME " in err and "Examples:" in err


def test_experiments_list_aligns_long_names(capsys):
    assert cli.main(["experiments", "list"]) == 0
    rows = capsys.readouterr().out.splitlines()
    starts = {len(row) - len(row.split("  ", 1)[1].lstrip()) for row in rows}
    assert len(starts) == 1, rows  # every title starts in the same column


# ---------------------------------------------------------------------------
# the PNG of `jaxnav experiments run`: written, or a line saying why not


@pytest.fixture
def fake_sweep(monkeypatch):
    """The sweep returns made-up errors at once (the command's own code is what is tested here)."""
    from jaxnav.experiments import registry
    from jaxnav.experiments import sweep as sw
    from jaxnav.experiments.hf_slam import ERROR_COLUMNS

    def fake(cells, runs, key, path, chunk_size, progress, **kwargs):
        rng = np.random.default_rng(0)
        return {c[0]: {col: rng.uniform(10, 50, runs) for col in ERROR_COLUMNS} for c in cells}

    monkeypatch.setattr(sw, "sweep", fake)
    return registry


ARGV = ["experiments", "run", "table-3.1", "--runs", "3", "--no-progress"]


def test_experiments_run_says_it_wrote_no_png_without_matplotlib(fake_sweep, monkeypatch, tmp_path, capsys):
    for name in [m for m in sys.modules if m == "matplotlib" or m.startswith("matplotlib.")]:
        monkeypatch.setitem(sys.modules, name, None)  # importing it raises ImportError
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    assert cli.main([*ARGV, "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "matplotlib is not installed: no plot written (pip install 'jaxnav[plot]')" in out
    assert sorted(os.listdir(tmp_path)) == ["table-3.1.json", "table-3.1.md"]


def test_experiments_run_says_where_the_png_went(fake_sweep, tmp_path, capsys):
    pytest.importorskip("matplotlib")
    assert cli.main([*ARGV, "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    png = tmp_path / "table-3.1.png"
    assert f"wrote {png}" in out and "matplotlib is not installed" not in out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
