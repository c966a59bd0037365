"""Helpers shared by the stages: the progress protocol, timing and the locked workspace."""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Protocol

from rmbuild.errors import InputError, WorkspaceError
from rmbuild.io.lock import workspace_lock
from rmbuild.io.workspace import Workspace


class Progress(Protocol):
    """What a stage reports while it runs; the CLI draws it, tests pass None.

    ``phase(name, total, unit)`` starts a phase of ``total`` ``unit`` (e.g. 106 "files"; None: unknown);
    ``advance(n)`` moves it on; ``message(text)`` is a one-line status of the open phase.
    """

    def phase(self, name: str, total: float | None = None, unit: str = "") -> None: ...

    def advance(self, n: float = 1.0) -> None: ...

    def message(self, text: str) -> None: ...


class NullProgress:
    def phase(self, name: str, total: float | None = None, unit: str = "") -> None:
        pass

    def advance(self, n: float = 1.0) -> None:
        pass

    def message(self, text: str) -> None:
        pass


def ensure_progress(p: Progress | None) -> Progress:
    return NullProgress() if p is None else p


ProgressCallback = Callable[[str, dict], None]


@contextmanager
def locked_workspace(root: str | Path, command: str, exclusive: bool = True) -> Iterator[Workspace]:
    """The workspace at ``root``, opened under its lock (exclusive for commands that write) for the block. An
    input error raised in the block without a place (what the workspace's data cannot give: a map too large
    to raster, too little ground truth to score) is said of the workspace."""
    if not Path(root).is_dir():
        raise WorkspaceError(f"{root} is not an rmbuild workspace (no such directory); create one with "
                             "`rmbuild ingest`")
    with workspace_lock(root, command, exclusive):
        try:
            yield Workspace.open(root)
        except InputError as e:
            if e.where is not None:
                raise
            raise InputError(str(e), str(root)) from None


@contextmanager
def captured_warnings() -> Iterator[list[str]]:
    """The warnings rmbuild logs in the block, collected instead of shown: the caller shows them with the
    floor's name, alike whether the floor ran here or in a worker process (lesser records go on to where
    they would have gone)."""
    logger = logging.getLogger("rmbuild")
    out: list[str] = []
    shown, propagate = logger.handlers[:], logger.propagate

    class Route(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            if record.levelno >= logging.WARNING:
                out.append(record.getMessage())
                return
            for h in shown:
                if record.levelno >= h.level:
                    h.handle(record)
            if propagate:
                logging.getLogger().handle(record)

    logger.handlers[:] = [Route()]
    logger.propagate = False
    try:
        yield out
    finally:
        logger.handlers[:] = shown
        logger.propagate = propagate
