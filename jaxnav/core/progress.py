"""A progress display on stderr, shared by the sweeps (runs) and the fits (optimiser steps)."""

from __future__ import annotations

import sys
import time
from typing import Any

__all__ = ["Progress"]


def _clock(seconds: float) -> str:
    """A duration as ``m:ss``, or ``h:mm:ss`` from an hour on."""
    minutes, secs = divmod(int(max(seconds, 0.0)), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


class Progress:
    """A progress display over runs (or any ``unit``) on stderr: tqdm when installed, a line of its own otherwise.

    ``note`` (such as ``"compiling …"``) is printed on a line of its own before the first count,
    so that a display sitting at 0 while XLA compiles says why. ``initial`` runs are done already
    (resumed from a checkpoint): counted at once, and left out of the rate that the time left
    is estimated from. Without tqdm, a terminal gets one line redrawn in place (``\\r``) with
    the runs done, the percentage, the time elapsed and, once runs have finished here, the time
    left; any other stream (a log file, a pipe) gets that line each time another tenth of the
    runs is done, eleven lines at most. ``file`` is where it all goes (default: ``sys.stderr``
    when the display is made); ``unit`` names what is counted (``"run"``; the optimiser's ``"step"``).
    Nothing is printed when ``enabled`` is false.
    """

    def __init__(
        self,
        total: int,
        desc: str,
        enabled: bool = True,
        *,
        note: str | None = None,
        initial: int = 0,
        file: Any = None,
        unit: str = "run",
    ):
        self.total, self.desc, self.enabled, self.done = total, desc, enabled, initial
        self.unit = unit
        self._bar = None
        self._file = sys.stderr if file is None else file
        self._start, self._initial = time.monotonic(), initial
        self._tty, self._width, self._tenths = False, 0, 0
        if not enabled:
            return
        if note:
            print(note, file=self._file, flush=True)
        try:
            from tqdm.auto import tqdm
        except ImportError:
            tqdm = None
        if tqdm is not None:
            self._bar = tqdm(total=total, initial=initial, desc=desc, unit=unit, leave=False, file=self._file)
            return
        try:
            self._tty = bool(self._file.isatty())
        except (AttributeError, ValueError):  # no isatty, or a closed stream
            self._tty = False
        self._show()

    def update(self, n: int) -> None:
        self.done += n
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.update(n)
        else:
            self._show()

    def _show(self) -> None:
        """Redraw the terminal's line, or print a line if another tenth of the runs is done."""
        percent = 100 * self.done // self.total if self.total > 0 else 100
        elapsed = time.monotonic() - self._start
        line = f"{self.desc}: {self.done}/{self.total} {self.unit}s ({percent}%), {_clock(elapsed)} elapsed"
        counted = self.done - self._initial
        if counted > 0 and self.done < self.total:
            line += f", ~{_clock(elapsed / counted * (self.total - self.done))} left"
        if self._tty:
            padding = " " * max(self._width - len(line), 0)  # blank out the end of a longer line before
            self._width = len(line)
            print(f"\r{line}{padding}", end="", file=self._file, flush=True)
        elif percent // 10 > self._tenths:
            self._tenths = percent // 10
            print(line, file=self._file, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
        elif self.enabled and self._tty:
            print(file=self._file, flush=True)
