"""The progress bars of a terminal (rich): one bar per phase, ``done/total unit`` and a rate; imported by
:mod:`rmbuild.cli.progress` only when stderr is a terminal."""

from __future__ import annotations

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
from rich.table import Column
from rich.text import Text

from rmbuild.cli.phases import Phases, count_text, rate_text


class CountRateColumn(ProgressColumn):
    """``done/total unit (rate unit/s)`` of a task; nothing for a phase without counts."""

    def render(self, task: Task) -> Text:
        unit = str(task.fields.get("unit", ""))
        if not unit:
            return Text("")
        speed = task.finished_speed or task.speed
        rate = f" ({rate_text(speed, 1.0, unit)})" if speed else ""
        return Text(count_text(task.completed, task.total, unit) + rate, style="progress.download")


class RichProgress:
    """Bars on a terminal (one per phase, kept when done)."""

    def __init__(self, bar: Progress, verbose: bool = False) -> None:
        self._bar = bar
        self._task: TaskID | None = None
        self._p = Phases(verbose)

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


@contextmanager
def bar_display(console: Console, verbose: int) -> Iterator[RichProgress]:
    """Live bars on ``console`` for the phases of one command."""
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
