"""The progress display of a sweep (jaxnav.experiments.sweep.Progress): a "compiling" line before the
first count; without tqdm, one line redrawn in place on a terminal and a line per tenth of the runs
anywhere else (a log is never flooded)."""

from __future__ import annotations

import io
import sys
import time

import jax
import pytest

from jaxnav.experiments import sweep as sw


class Terminal(io.StringIO):
    """A stream that says it is a terminal."""

    def isatty(self) -> bool:
        return True


class Clock:
    """``time.monotonic`` that moves only when told to."""

    def __init__(self):
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def no_tqdm(monkeypatch):
    """``from tqdm.auto import tqdm`` fails, as in an install without the extras that bring tqdm."""
    monkeypatch.setitem(sys.modules, "tqdm", None)
    monkeypatch.setitem(sys.modules, "tqdm.auto", None)


@pytest.fixture
def clock(monkeypatch):
    clock = Clock()
    monkeypatch.setattr(time, "monotonic", clock)
    return clock


def test_a_terminal_gets_a_compiling_line_then_one_line_redrawn_with_the_time_left(no_tqdm, clock):
    out = Terminal()
    bar = sw.Progress(40, "Monte Carlo", note="compiling the runs of 4 settings…", file=out)
    note, _, rest = out.getvalue().partition("\n")
    assert note == "compiling the runs of 4 settings…"
    assert rest == "\rMonte Carlo: 0/40 runs (0%), 0:00 elapsed"  # no time left before a chunk is done
    clock.now += 30.0  # compilation and the first chunk
    bar.update(10)
    assert out.getvalue().endswith("\rMonte Carlo: 10/40 runs (25%), 0:30 elapsed, ~1:30 left")
    clock.now += 3600.0
    bar.update(10)
    assert out.getvalue().endswith("\rMonte Carlo: 20/40 runs (50%), 1:00:30 elapsed, ~1:00:30 left")
    before = out.getvalue().split("\r")[-1]
    clock.now += 10.0
    bar.update(20)
    last = out.getvalue().split("\r")[-1]
    assert last.rstrip() == "Monte Carlo: 40/40 runs (100%), 1:00:40 elapsed"
    assert len(last) == len(before)  # spaces blank out the end of the longer line before
    bar.close()
    assert out.getvalue().endswith("\n") and out.getvalue().count("\n") == 2


def test_a_log_gets_a_compiling_line_then_a_line_per_tenth_never_a_flood(no_tqdm, clock):
    out = io.StringIO()
    bar = sw.Progress(1000, "Monte Carlo", note="compiling …", file=out)
    assert out.getvalue() == "compiling …\n"  # nothing at 0 runs
    for _ in range(1000):
        clock.now += 1.0
        bar.update(1)
    bar.close()
    lines = out.getvalue().splitlines()
    assert "\r" not in out.getvalue()
    assert lines[0] == "compiling …"
    assert len(lines) == 11, lines
    assert lines[1] == "Monte Carlo: 100/1000 runs (10%), 1:40 elapsed, ~15:00 left"
    assert [line.split()[2] for line in lines[1:]] == [f"{100 * k}/1000" for k in range(1, 11)]
    assert lines[-1] == "Monte Carlo: 1000/1000 runs (100%), 16:40 elapsed"


def test_resumed_runs_are_counted_at_once_but_not_in_the_rate(no_tqdm, clock):
    out = io.StringIO()
    bar = sw.Progress(40, "Monte Carlo", initial=20, file=out)
    assert out.getvalue() == "Monte Carlo: 20/40 runs (50%), 0:00 elapsed\n"
    clock.now += 10.0
    bar.update(10)  # 10 runs in 10 s here: 10 s left for the last 10, whatever was resumed
    assert out.getvalue().splitlines()[-1] == "Monte Carlo: 30/40 runs (75%), 0:10 elapsed, ~0:10 left"


def test_a_disabled_display_prints_nothing(no_tqdm):
    out = Terminal()
    bar = sw.Progress(10, "Monte Carlo", enabled=False, note="compiling …", file=out)
    bar.update(10)
    bar.close()
    assert out.getvalue() == "" and bar.done == 10


def test_tqdm_when_installed_comes_after_the_compiling_line():
    pytest.importorskip("tqdm")
    out = io.StringIO()
    bar = sw.Progress(10, "Monte Carlo", note="compiling …", file=out)
    bar.update(10)
    bar.close()
    assert bar._bar is not None
    assert out.getvalue().startswith("compiling …\n\rMonte Carlo:") and "0/10" in out.getvalue()


def _cells():
    return [("a", lambda key: {"x": jax.random.normal(key)}), ("b", lambda key: {"x": jax.random.uniform(key)})]


def test_a_sweep_says_it_compiles_before_counting_and_not_when_nothing_is_left(no_tqdm, capsys, tmp_path):
    path = str(tmp_path / "runs.json")
    sw.sweep(_cells(), 4, jax.random.PRNGKey(0), path, chunk_size=2, workers=1)
    lines = capsys.readouterr().err.splitlines()
    assert lines[0] == (
        "compiling the runs of 2 settings, one after the other, with XLA (the count starts once the first is compiled)…"
    )
    counts = [line.split()[2] for line in lines[1:]]
    assert counts == ["2/8", "4/8", "6/8", "8/8"]  # a line per chunk: each is a quarter of the runs
    sw.sweep(_cells(), 4, jax.random.PRNGKey(0), path, chunk_size=2, workers=1)  # all resumed: nothing compiles
    assert capsys.readouterr().err.splitlines() == ["Monte Carlo: 8/8 runs (100%), 0:00 elapsed"]
    sw.sweep(_cells(), 4, jax.random.PRNGKey(0), path, chunk_size=2, progress=False, fresh=True)
    assert capsys.readouterr().err == ""
