"""Progress display for the CLI (rich): the only place that draws bars.

A stage reports phases (``phase(name, total, unit)``), moves them on (``advance(n)``) and sets a status
(``message(text)``). On a terminal each phase is a bar with ``done/total unit`` and a rate
(:mod:`rmbuild.cli.progress_bars`); warnings go through rich's logging handler on the same console, so
they print above the live bars instead of inside them. With ``-v`` every finished phase also leaves a log
line (count, time, rate) — on a terminal and in a log file alike; ``-q`` draws nothing. rich is imported
only when stderr may be a terminal (a command in a pipe or a script does not pay for it).
"""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from functools import cache
from typing import TYPE_CHECKING, Any

from rmbuild.cli.phases import Phases

if TYPE_CHECKING:
    from rmbuild.cli.progress_bars import RichProgress



@cache
def console() -> Any:
    """The rich console on stderr that bars and log lines share."""
    from rich.console import Console

    return Console(stderr=True)


def on_terminal() -> bool:
    """Whether rich treats stderr as a terminal. It does only when stderr is a TTY or the environment
    forces it (TTY_COMPATIBLE=1, a non-empty FORCE_COLOR); otherwise this answers without importing rich."""
    try:
        tty = sys.stderr.isatty()
    except (AttributeError, ValueError):  # no stderr, or a closed one
        tty = False
    if not (tty or os.environ.get("TTY_COMPATIBLE") == "1" or os.environ.get("FORCE_COLOR")):
        return False
    return bool(console().is_terminal)


class LogProgress:
    """No terminal, ``-v``: no bars, one log line per finished phase (count, time, rate, last status)."""

    def __init__(self) -> None:
        self._p = Phases(verbose=True)

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
    """Bars on a terminal (a :class:`rmbuild.cli.progress_bars.RichProgress`); without one, log lines with
    ``-v`` (:class:`LogProgress`) and nothing otherwise; nothing with ``-q``."""
    if quiet:
        yield None
        return
    if not on_terminal():
        if not verbose:
            yield None
            return
        lp = LogProgress()
        try:
            yield lp
        finally:
            lp.close()
        return
    from rmbuild.cli.progress_bars import bar_display

    with bar_display(console(), verbose) as rp:
        yield rp


def log_handler() -> logging.Handler:
    """The CLI's log handler: rich's on a terminal (lines print above live bars, on the bars' console);
    elsewhere one plain ``LEVEL: message`` line per record (log files and pipes are never wrapped)."""
    if on_terminal():
        from rich.logging import RichHandler

        return RichHandler(console=console(), show_time=False, show_path=False, markup=False,
                           rich_tracebacks=False, keywords=[])
    handler = logging.StreamHandler()  # sys.stderr at emit time
    handler.setFormatter(logging.Formatter("%(levelname)s: %(message)s"))
    return handler
