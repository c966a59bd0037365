"""Progress display for the CLI (rich): the only place that draws bars.

A stage reports phases (``phase(name, total, unit)``), moves them on (``advance(n)``) and sets a status
(``message(text)``). On a terminal each phase is a bar with ``done/total unit`` and a rate; warnings go
through rich's logging handler on the same console, so they print above the live bars instead of inside
them. With ``-v`` every finished phase also leaves a log line (count, time, rate) — on a terminal and in
a log file alike; ``-q`` draws nothing.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from contextlib import contextmanager

from rich.console import Console
from rich.progress import (
    BarColumn,
    Progress,
    ProgressColumn,
    SpinnerColumn,
    Task,
    TaskID,
    TextColumn,
    TimeElapsedColumn,
)
from rich.text import Text

console = Console(stderr=True)
log = logging.getLogger("rmbuild.progress")


def _count(done: float, total: float | None, unit: str) -> str:
    if total is None:
        return f"{done:,.0f} {unit}".strip() if done else ""
    return f"{done:,.0f}/{total:,.0f} {unit}".strip()


def _rate(done: float, seconds: float, unit: str) -> str:
    if done <= 0 or seconds <= 0:
        return ""
    r = done / seconds
    return f"{r:,.1f} {unit}/s" if r < 100 else f"{r:,.0f} {unit}/s"


class CountRateColumn(ProgressColumn):
    """``done/total unit (rate unit/s)`` of a task; nothing for a phase without counts."""

    def render(self, task: Task) -> Text:
        unit = str(task.fields.get("unit", ""))
        if not unit:
            return Text("")
        speed = task.finished_speed or task.speed
        rate = f" ({_rate(speed, 1.0, unit)})" if speed else ""
        return Text(_count(task.completed, task.total, unit) + rate, style="progress.download")


class _Phases:
    """Bookkeeping shared by the bar and the log-only display: the open phase, its count and start."""

    def __init__(self, verbose: bool) -> None:
        self.verbose = verbose
        self.name = ""
        self.unit = ""
        self.total: float | None = None
        self.done = 0.0
        self.t0 = 0.0
        self.status = ""

    def start(self, name: str, total: float | None, unit: str) -> None:
        self.end()
        self.name, self.total, self.unit, self.done, self.t0, self.status = (
            name, total, unit, 0.0, time.perf_counter(), "")

    def end(self) -> None:
        if not self.name or not self.verbose:
            self.name = ""
            return
        dt = time.perf_counter() - self.t0
        parts = [f"{self.name}: done in {dt:.1f} s"]
        if self.unit and self.done:
            parts.append(f"{_count(self.done, self.total, self.unit)} ({_rate(self.done, dt, self.unit)})")
        if self.status:
            parts.append(self.status)
        log.info("; ".join(parts))
        self.name = ""


class RichProgress:
    """Bars on a terminal (one per phase, kept when done)."""

    def __init__(self, bar: Progress, verbose: bool = False) -> None:
        self._bar = bar
        self._task: TaskID | None = None
        self._p = _Phases(verbose)

    def phase(self, name: str, total: float | None = None, unit: str = "") -> None:
        self._finish()
        self._p.start(name, total, unit)
        self._task = self._bar.add_task(name, total=total, unit=unit)

    def advance(self, n: float = 1.0) -> None:
        if self._task is not None:
            self._p.done += n
            self._bar.advance(self._task, n)

    def message(self, text: str) -> None:
        """A status shown beside the open phase (the latest replaces the previous)."""
        self._p.status = text
        if self._task is not None:
            self._bar.update(self._task, description=f"{self._p.name}: {text}")

    def close(self) -> None:
        self._finish()

    def _finish(self) -> None:
        if self._task is not None:
            t = self._bar.tasks[-1]
            done = t.total if t.total is not None else max(t.completed, 1)
            self._bar.update(self._task, total=done, completed=done)
        self._p.end()
        self._task = None


class LogProgress:
    """No terminal, ``-v``: no bars, one log line per finished phase (count, time, rate, last status)."""

    def __init__(self) -> None:
        self._p = _Phases(verbose=True)

    def phase(self, name: str, total: float | None = None, unit: str = "") -> None:
        self._p.start(name, total, unit)

    def advance(self, n: float = 1.0) -> None:
        self._p.done += n

    def message(self, text: str) -> None:
        self._p.status = text

    def close(self) -> None:
        self._p.end()


@contextmanager
def progress_display(quiet: bool, verbose: int = 0) -> Iterator[RichProgress | LogProgress | None]:
    """Bars on a terminal; without one, log lines with ``-v`` and nothing otherwise; nothing with ``-q``."""
    if quiet:
        yield None
        return
    if not console.is_terminal:
        if not verbose:
            yield None
            return
        lp = LogProgress()
        try:
            yield lp
        finally:
            lp.close()
        return
    from rich.table import Column

    # the description takes what the counts, bar and clock leave, cut with an ellipsis (no wrapped rows)
    bar = Progress(SpinnerColumn(), TextColumn("{task.description}", table_column=Column(
                       ratio=1, no_wrap=True, overflow="ellipsis")),
                   BarColumn(bar_width=12), CountRateColumn(table_column=Column(no_wrap=True)),
                   TimeElapsedColumn(), console=console, transient=False, expand=True)
    with bar:
        rp = RichProgress(bar, verbose=bool(verbose))
        try:
            yield rp
        finally:
            rp.close()


def log_handler() -> logging.Handler:
    """The CLI's log handler: rich's on a terminal (lines print above live bars, on the bars' console);
    elsewhere one plain ``LEVEL: message`` line per record (log files and pipes are never wrapped)."""
    if console.is_terminal:
        from rich.logging import RichHandler

        return RichHandler(console=console, show_time=False, show_path=False, markup=False,
                           rich_tracebacks=False, keywords=[])
    handler = logging.StreamHandler()  # sys.stderr at emit time
    handler.setFormatter(logging.Formatter("%(levelname)s: %(message)s"))
    return handler
