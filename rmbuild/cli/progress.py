"""Progress display for the CLI (rich): the only place that draws bars."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from rich.console import Console
from rich.progress import BarColumn, Progress, SpinnerColumn, TaskID, TextColumn, TimeElapsedColumn

console = Console(stderr=True)


class RichProgress:
    def __init__(self, bar: Progress) -> None:
        self._bar = bar
        self._task: TaskID | None = None

    def phase(self, name: str, total: float | None = None) -> None:
        if self._task is not None:
            done = self._bar.tasks[-1].total or 1
            self._bar.update(self._task, total=done, completed=done)
        self._task = self._bar.add_task(name, total=total)

    def advance(self, n: float = 1.0) -> None:
        if self._task is not None:
            self._bar.advance(self._task, n)

    def message(self, text: str) -> None:
        self._bar.console.log(text)


@contextmanager
def progress_display(quiet: bool) -> Iterator[RichProgress | None]:
    if quiet or not console.is_terminal:
        yield None
        return
    bar = Progress(SpinnerColumn(), TextColumn("{task.description}"), BarColumn(), TimeElapsedColumn(),
                   console=console, transient=False)
    with bar:
        yield RichProgress(bar)
