"""Atomic file and directory replacement: a crash or Ctrl-C leaves the old version or the new one."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from rmbuild.errors import WorkspaceError


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def new_file_mode() -> int:
    """The mode a newly created file gets under the process's umask (0666 less the umask)."""
    return 0o666 & ~_umask()


def write_bytes_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file in the same directory and ``os.replace``; the
    file gets the mode of any new file (0666 less the umask), not mkstemp's 0600."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, new_file_mode())
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def write_text_atomic(path: Path, text: str) -> None:
    write_bytes_atomic(path, text.encode("utf-8"))


def write_json_atomic(path: Path, obj: Any) -> None:
    write_text_atomic(path, json.dumps(obj, indent=2, sort_keys=False, default=_json_default) + "\n")


def _json_default(o: Any) -> Any:
    import numpy as np

    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return None if not np.isfinite(o) else float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.bool_):
        return bool(o)
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def clean_json(obj: Any) -> Any:
    """Replace NaN/inf floats by None recursively (JSON has no NaN)."""
    import math

    if isinstance(obj, dict):
        return {str(k): clean_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [clean_json(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    try:
        import numpy as np

        if isinstance(obj, np.floating):
            return None if not np.isfinite(obj) else float(obj)
        if isinstance(obj, np.integer):
            return int(obj)
        if isinstance(obj, np.bool_):
            return bool(obj)
        if isinstance(obj, np.ndarray):
            return clean_json(obj.tolist())
    except ImportError:  # pragma: no cover
        pass
    return obj


@contextlib.contextmanager
def replacing_dir(target: Path) -> Iterator[Path]:
    """Yield a fresh temporary directory beside ``target``; on normal exit it replaces ``target``.

    The swap is two renames (old -> backup, new -> target) followed by deleting the backup; if the
    process dies between them, :func:`recover_dir` puts the backup back. On an exception the temporary
    directory is removed and ``target`` is untouched. A ``target`` that is a symbolic link is refused
    (:class:`LinkError`): the directories rmbuild replaces are its own, never reached through a link.
    """
    target = Path(target)
    refuse_link(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.new-", dir=target.parent))
    os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp makes 0700; the result should look like any new directory
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    fsync_tree(tmp)  # the new files on disk before the renames make them the stage: a power cut too
    backup = target.parent / f".{target.name}.old-{os.getpid()}"
    if target.exists():
        os.replace(target, backup)
    try:
        os.replace(tmp, target)
    except BaseException:
        if backup.exists() and not target.exists():
            os.replace(backup, target)
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    _fsync_path(target.parent)  # the renames themselves
    shutil.rmtree(backup, ignore_errors=True)


def fsync_tree(root: Path) -> None:
    """Flush every file and directory under ``root`` (and ``root``) to disk."""
    for dirpath, _, filenames in os.walk(root):
        for name in filenames:
            _fsync_path(Path(dirpath) / name)
        _fsync_path(Path(dirpath))


def _fsync_path(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def recover_dir(target: Path) -> None:
    """Undo a swap interrupted between its two renames; drop leftovers of interrupted writes (a symbolic
    link named like one is not rmbuild's: it is removed, never followed or put in place)."""
    target = Path(target)
    parent = target.parent
    if not parent.exists():
        return
    for p in parent.glob(f".{target.name}.old-*"):
        if p.is_symlink():
            p.unlink()
        elif not target.exists() and not target.is_symlink():
            os.replace(p, target)
        else:
            shutil.rmtree(p, ignore_errors=True)
    for p in parent.glob(f".{target.name}.new-*"):
        if p.is_symlink():
            p.unlink()
        else:
            shutil.rmtree(p, ignore_errors=True)


class LinkError(WorkspaceError):
    """A path rmbuild would write (a stage directory, a workspace file, an output) is a symbolic link."""


def refuse_link(path: Path) -> None:
    """Raise :class:`LinkError` when ``path`` itself is a symbolic link."""
    if Path(path).is_symlink():
        raise LinkError(f"{path} is a symbolic link: rmbuild never writes through one; remove it (or give the "
                        "path it points to)")
