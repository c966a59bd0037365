"""What the progress displays share: a phase's count and rate as text, and the bookkeeping of the open
phase (with ``-v``, one log line when it ends). Used by :mod:`rmbuild.cli.progress` (log lines) and
:mod:`rmbuild.cli.progress_bars` (bars on a terminal)."""

from __future__ import annotations

import logging
import time

log = logging.getLogger("rmbuild.progress")


def count_text(done: float, total: float | None, unit: str) -> str:
    if total is None:
        return f"{done:,.0f} {unit}".strip() if done else ""
    return f"{done:,.0f}/{total:,.0f} {unit}".strip()


def rate_text(done: float, seconds: float, unit: str) -> str:
    if done <= 0 or seconds <= 0:
        return ""
    r = done / seconds
    return f"{r:,.1f} {unit}/s" if r < 100 else f"{r:,.0f} {unit}/s"


class Phases:
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
            parts.append(f"{count_text(self.done, self.total, self.unit)} ({rate_text(self.done, dt, self.unit)})")
        if self.status:
            parts.append(self.status)
        log.info("; ".join(parts))
        self.name = ""
