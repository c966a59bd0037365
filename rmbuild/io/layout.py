"""The workspace marker and a building's floors: the part of the layout (:mod:`rmbuild.io.workspace`) that the
workspace lock (:mod:`rmbuild.io.lock`) needs too, to lock a floor with its building. The workspace module
re-exports every name here; use it."""

from __future__ import annotations

import json
from pathlib import Path

from rmbuild.errors import WorkspaceError

#: the marker's "format": a manifest.json without it is not an rmbuild workspace
WORKSPACE_FORMAT = "rmbuild-workspace"
MANIFEST = "manifest.json"
#: a marker or record larger than this is not one of ours (never read a huge file to find out)
MAX_MARKER_BYTES = 1 << 20
#: the floors' workspaces, relative to a building workspace's root
FLOORS_DIR = "floors"


def read_marker(root: Path) -> dict | None:
    """The parsed manifest.json of ``root`` (None when absent, unreadable, huge or not a JSON object)."""
    p = root / MANIFEST
    try:
        if not p.is_file() or p.stat().st_size > MAX_MARKER_BYTES:
            return None
        m = json.loads(p.read_bytes())
    except (OSError, ValueError, RecursionError):
        return None
    return m if isinstance(m, dict) else None


def is_marker(m: dict | None) -> bool:
    """rmbuild's workspace marker, this layout's or the first one (schema 1, no "format" key)."""
    if m is None:
        return False
    if m.get("format") == WORKSPACE_FORMAT:
        return True
    return m.get("schema_version") == 1 and "rmbuild_version" in m and isinstance(m.get("stages"), dict)


def building_floors(root: str | Path) -> dict[str, Path] | None:
    """floor name -> the floor's workspace directory, for a building workspace; None for a single floor
    (or no workspace at all: opening it reports that)."""
    root = Path(root)
    m = read_marker(root)
    if not is_marker(m) or not isinstance((m or {}).get("floors"), list):
        return None
    out: dict[str, Path] = {}
    for f in (m or {})["floors"]:
        if not (isinstance(f, dict) and isinstance(f.get("name"), str) and isinstance(f.get("dir"), str)
                and f["dir"].startswith(FLOORS_DIR + "/") and "/" not in f["dir"][len(FLOORS_DIR) + 1:]
                and f["dir"][len(FLOORS_DIR) + 1:] not in ("", ".", "..")):
            raise WorkspaceError(f"{root / MANIFEST}: malformed floor entry {str(f)[:120]}")
        out[f["name"]] = root / f["dir"]
    return out
