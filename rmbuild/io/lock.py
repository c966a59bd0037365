"""The workspace lock: one command writes a workspace at a time; readers share it.

The lock is the file ``.<name>.lock`` beside the workspace directory ``<name>`` (beside, not inside:
``ingest`` replaces the whole directory). It is held with ``flock``, so the kernel releases it when the
holder dies in any way (kill -9 included): a lock file left behind by a dead process is stale by
construction and the next command simply takes it. A writer records its pid, host, command and start
time in the file, so that a second command can say who holds the workspace.

Locks are re-entrant within a process (a stage calling another stage's code on the same workspace).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import logging
import os
import socket
import time
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path

from rmbuild.errors import WorkspaceBusyError, WorkspaceError

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
    """Hold the workspace's lock for the block: exclusive for commands that write, shared for readers.

    Raises :class:`WorkspaceBusyError` at once (no waiting) when another process holds it.
    """
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
        del _HELD[key]
        _release(key, fd, exclusive)


class _NoLockFile(Exception):
    """A shared lock's file cannot be created (no write access beside the workspace)."""


def _acquire(root: Path, command: str, exclusive: bool) -> int:
    path = lock_path(root)
    if not path.parent.is_dir():
        raise WorkspaceError(f"{path.parent}: no such directory (the workspace's parent)")
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as e:
            if not exclusive and e.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
                raise _NoLockFile() from None
            raise WorkspaceError(f"{path}: cannot create the workspace lock ({e.strerror})") from None
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
    try:
        if exclusive:  # unlink while still holding it, so nobody locks a file that is about to vanish
            with contextlib.suppress(FileNotFoundError):
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
        # no writer recorded (or the recorded one is gone): the holders are readers (view, report)
        return "another rmbuild command is reading it"
    return f"`rmbuild {info.get('command', '?')}` (pid {pid} on {host}, since {info.get('since_utc', '?')}) holds it"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
