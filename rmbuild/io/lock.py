"""The workspace lock: one command writes a workspace at a time; readers share it.

The lock is the file ``.<name>.lock`` beside the workspace directory ``<name>`` (beside, not inside:
``ingest`` replaces the whole directory). It is held with ``flock``, so the kernel releases it when the
holder dies in any way (kill -9 included): a lock file left behind by a dead process is stale by
construction and the next command simply takes it. A writer records its pid, host, command and start
time in the file, so that a second command can say who holds the workspace.

Locks are re-entrant within a process (a stage calling another stage's code on the same workspace).

A building's floors are locked with their building: a command on one floor (``-w B/floors/F1``) holds the
building's lock shared and the floor's own lock exclusively (or shared, to read), so that it excludes a
command that rewrites the whole building (``ingest --force``, a stage over every floor: the building's lock
exclusive), and the other way round, while commands on different floors run side by side.

The lock file is opened with ``O_NOFOLLOW`` and must be a regular file: a symbolic link planted in its
place is refused, never written through.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import logging
import os
import socket
import stat
import time
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path

from rmbuild.errors import RmbuildError, WorkspaceBusyError, WorkspaceError
from rmbuild.io.layout import FLOORS_DIR, building_floors

log = logging.getLogger(__name__)

#: resolved workspace root -> (file descriptor, exclusive, depth) of the locks this process holds
_HELD: dict[Path, tuple[int, bool, int]] = {}


def lock_path(root: str | Path) -> Path:
    """The lock file of the workspace at ``root``."""
    root = Path(root).resolve()
    return root.parent / f".{root.name}.lock"


def holds_lock(root: str | Path, exclusive: bool = True) -> bool:
    """True when this process holds the workspace's lock (an exclusive one when ``exclusive``)."""
    held = _HELD.get(Path(root).resolve())
    return held is not None and (held[1] or not exclusive)


@contextlib.contextmanager
def workspace_lock(root: str | Path, command: str, exclusive: bool = True) -> Iterator[None]:
    """Hold the workspace's lock for the block: exclusive for commands that write, shared for readers; a
    floor of a building holds its building's lock shared as well (module docstring).

    Raises :class:`WorkspaceBusyError` at once (no waiting) when another process holds it.
    """
    building = _building_of(Path(root))
    if building is None:
        with _lock(root, command, exclusive):
            yield
        return
    with _lock(building, command, exclusive=False), _lock(root, command, exclusive):
        yield


def _building_of(root: Path) -> Path | None:
    """The building whose floor ``root`` is (its manifest lists it), None for any other workspace."""
    r = root.resolve()
    if r.parent.name != FLOORS_DIR:
        return None
    try:
        floors = building_floors(r.parent.parent) or {}
    except RmbuildError:
        return None
    return r.parent.parent if any(p.resolve() == r for p in floors.values()) else None


@contextlib.contextmanager
def shared_while(root: str | Path) -> Iterator[None]:
    """For the block, turn this process's exclusive lock of ``root`` into a shared one, so that other
    processes may work on its floors (`build`'s floor tasks on Dask workers); exclusive again afterwards
    when nobody else holds it then (else it stays shared until released). No-op without an exclusive lock."""
    key = Path(root).resolve()
    held = _HELD.get(key)
    if held is None or not held[1]:
        yield
        return
    fcntl.flock(held[0], fcntl.LOCK_SH)
    _HELD[key] = (held[0], False, held[2])
    try:
        yield
    finally:
        fd, _, depth = _HELD[key]
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            _HELD[key] = (fd, True, depth)
        except BlockingIOError:
            pass


@contextlib.contextmanager
def _lock(root: str | Path, command: str, exclusive: bool) -> Iterator[None]:
    key = Path(root).resolve()
    held = _HELD.get(key)
    if held is not None:
        if exclusive and not held[1]:
            raise RuntimeError(f"{key}: cannot upgrade a shared workspace lock")  # programming error
        _HELD[key] = (held[0], held[1], held[2] + 1)
        try:
            yield
        finally:
            fd, ex, depth = _HELD[key]
            _HELD[key] = (fd, ex, depth - 1)
        return
    try:
        fd = _acquire(key, command, exclusive)
    except _NoLockFile:
        # a reader of a workspace it cannot write beside (read-only media, another user's): no writer
        # can be at work there either, so it reads without a lock
        yield
        return
    _HELD[key] = (fd, exclusive, 1)
    try:
        yield
    finally:
        still_exclusive = _HELD.pop(key)[1]
        _release(key, fd, still_exclusive)


class _NoLockFile(Exception):
    """A shared lock's file cannot be created (no write access beside the workspace)."""


def _acquire(root: Path, command: str, exclusive: bool) -> int:
    path = lock_path(root)
    if not path.parent.is_dir():
        raise WorkspaceError(f"{path.parent}: no such directory (the workspace's parent)")
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
        except OSError as e:
            if e.errno == errno.ELOOP:
                raise WorkspaceError(f"{path}: the workspace lock is a symbolic link; rmbuild never writes through "
                                     "one: remove it") from None
            if not exclusive and e.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
                raise _NoLockFile() from None
            raise WorkspaceError(f"{path}: cannot create the workspace lock ({e.strerror})") from None
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            os.close(fd)
            raise WorkspaceError(f"{path}: the workspace lock is not a regular file; remove it")
        try:
            fcntl.flock(fd, (fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH) | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            raise WorkspaceBusyError(f"workspace {root} is busy: {holder}; wait until it finishes") from None
        # the previous holder unlinks the file while holding it: make sure we locked the file at ``path``
        try:
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    if exclusive:
        old = _info(fd)
        if isinstance(old.get("pid"), int) and old["pid"] != os.getpid():
            # left by a writer that died without releasing it (kill -9, power loss): the kernel freed it
            log.info("workspace %s: took over the stale lock of `rmbuild %s` (pid %s on %s, since %s)", root,
                     old.get("command"), old.get("pid"), old.get("host"), old.get("since_utc"))
        info = {"pid": os.getpid(), "host": socket.gethostname(), "command": command,
                "since_utc": datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")}
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(info) + "\n").encode(), 0)
    return fd


def _release(root: Path, fd: int, exclusive: bool) -> None:
    """Unlink the lock file while still holding it exclusively (a shared holder first tries to become the
    only one), so that nobody locks a file about to vanish and no lock file is left behind."""
    try:
        if not exclusive:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                exclusive = True
            except BlockingIOError:  # others hold it: the last one out removes it
                pass
        if exclusive:
            with contextlib.suppress(FileNotFoundError):
                if os.stat(lock_path(root)).st_ino == os.fstat(fd).st_ino:
                    os.unlink(lock_path(root))
    finally:
        os.close(fd)


def _info(fd: int) -> dict:
    """What the last writer recorded in the lock file ({} when nothing readable)."""
    try:
        info = json.loads(os.pread(fd, 4096, 0).decode() or "{}")
    except (OSError, ValueError, RecursionError):
        return {}
    return info if isinstance(info, dict) else {}


# s; how long a refused command waits for the holder's record: a writer records itself just after locking
HOLDER_RECORD_WAIT_S = 0.2


def _holder(fd: int) -> str:
    """Who holds the lock, for the busy message (a writer that has just locked gets a moment to record
    itself; readers record nothing)."""
    info = _info(fd)
    deadline = time.monotonic() + HOLDER_RECORD_WAIT_S
    while not info and time.monotonic() < deadline:
        time.sleep(0.01)
        info = _info(fd)
    pid, host = info.get("pid"), info.get("host")
    if not isinstance(pid, int) or (host == socket.gethostname() and not _alive(pid)):
        # no writer recorded (or the recorded one is gone): the holders share it (view, report, a command on
        # one of a building's floors)
        return "another rmbuild command holds it shared (reading it, or working on one of its floors)"
    return f"`rmbuild {info.get('command', '?')}` (pid {pid} on {host}, since {info.get('since_utc', '?')}) holds it"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
