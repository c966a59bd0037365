"""What `rmbuild build` remembers between runs, to redo only what changed (docs/scale-out.md).

The workspace's build state (``build_state.json``, :mod:`rmbuild.io.workspace` names it) holds a
fingerprint of the inputs and of the ingest configuration, and per floor the stage configs its outputs were
built with and the floor task's result. A re-run of `build` without ``--force``:

- skips ``ingest`` when every input file has the size and modification time it had (a file whose size or
  time changed is hashed: same content, same input) and the ingest configuration, format, floor plan and
  rmbuild version are the same;
- skips a floor whose stage configs are the same and whose outputs are complete: every stage's record
  matches its files and the records it read (:meth:`Workspace.verify`, :meth:`Workspace.stale_inputs`);
- when the inputs changed, ingests again, and keeps the outputs of every floor whose ingested data came
  out byte-identical (:func:`keeping_unchanged_floors`): a changed file of one floor re-runs that floor;
- never replaces a stage a user re-made by hand since (``export-map --cell-size 5``, ``optimize --anchors``,
  ``ingest --append``): the state holds each floor's stage records as the build left them, and a floor whose
  records differ is refused, naming what differs (:func:`hand_made`), unless ``--force``.
"""

from __future__ import annotations

import json
import os
import shutil
import tomllib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from rmbuild import __version__
from rmbuild.errors import WorkspaceError
from rmbuild.io.atomic import replacing_dir, write_json_atomic
from rmbuild.io.lock import workspace_lock
from rmbuild.io.workspace import STAGE_DIRS, Workspace, building_floors, record_digests, sha256_file

#: the floor-task stages whose records a complete floor has ("evaluate" too when its result has it)
FLOOR_STAGES = ("optimize", "map")
#: version of the build state's layout
STATE_VERSION = 1


def read_state(workspace: str | Path) -> dict | None:
    """The build state of ``workspace`` (None: none, or unreadable: as if the workspace had no build)."""
    p = Workspace(workspace).path("build.state")
    try:
        s = json.loads(p.read_text())
    except (OSError, ValueError, RecursionError):
        return None
    ok = isinstance(s, dict) and s.get("version") == STATE_VERSION and isinstance(s.get("floors"), dict)
    return s if ok else None


def write_state(workspace: str | Path, state: dict) -> None:
    write_json_atomic(Workspace(workspace).path("build.state"), state)


def input_fingerprint(inputs: list[str | Path], settings: dict[str, Any], old: dict | None) -> dict:
    """{"files": {key: [size, mtime_ns, sha256]}, "settings": ...} of every file under ``inputs`` (key: the
    input's position and the file's path in it, so that inputs moved elsewhere are the same inputs); a file
    whose size and time are those of ``old`` keeps its old hash (not read again)."""
    before = (old or {}).get("files", {})
    files: dict[str, list] = {}
    for key, f in _input_files(inputs):
        st = f.stat()
        prev = before.get(key)
        same = isinstance(prev, list) and len(prev) == 3 and prev[:2] == [st.st_size, st.st_mtime_ns]
        files[key] = [st.st_size, st.st_mtime_ns, prev[2] if same else sha256_file(f)]
    return {"files": files, "settings": settings, "rmbuild_version": __version__}


def same_inputs(a: dict | None, b: dict) -> bool:
    """Whether two fingerprints are of the same inputs (content and settings; times aside)."""
    if a is None:
        return False

    def strip(fp: dict) -> tuple:
        return {k: v[0::2] for k, v in fp.get("files", {}).items()}, fp.get("settings"), fp.get("rmbuild_version")

    return strip(a) == strip(b)


def floor_is_current(path: str | Path, configs: dict[str, str], entry: dict | None) -> bool:
    """Whether a floor's outputs are complete and were built with ``configs`` (its entry in the build
    state: {"configs", "result"})."""
    if not entry or entry.get("configs") != configs or not (entry.get("result") or {}).get("ok"):
        return False
    try:
        ws = Workspace.open(path)
        stages = FLOOR_STAGES + (("evaluate",) if "evaluate" in entry["result"].get("stages", {}) else ())
        for stage in stages:
            if not ws.has(stage) or ws.stale_inputs(stage) or ws.verify(stage):
                return False
        return ws.path("report.html").is_file()
    except (WorkspaceError, OSError):
        return False


@contextmanager
def keeping_unchanged_floors(workspace: str | Path, state: dict | None) -> Iterator[set[str]]:
    """Around a re-ingest of a building: set aside (hard links) every floor the state has as complete, and
    after the block put back each one whose ingested files came out identical; the yielded set then names
    them. A kill leaves ``.<name>.keep-<pid>`` beside the workspace, removed by the next run."""
    root = Path(workspace).resolve()
    for left in root.parent.glob(f".{root.name}.keep-*"):
        if left.is_symlink():  # not ours: removed, never followed
            left.unlink()
        else:
            shutil.rmtree(left, ignore_errors=True)
    kept: set[str] = set()
    old = building_floors(root) if state else None
    done = {n for n, e in (state or {}).get("floors", {}).items() if (e.get("result") or {}).get("ok")}
    aside = root.parent / f".{root.name}.keep-{os.getpid()}"
    try:
        saved = {n: _link_copy(p, aside / p.name) for n, p in (old or {}).items() if n in done and p.is_dir()}
        yield kept
        for name, new in (building_floors(root) or {}).items():
            if name in saved and new.name == saved[name].name and _same_ingest(saved[name], new):
                with workspace_lock(new, "build"), replacing_dir(new) as tmp:
                    os.rmdir(tmp)
                    os.replace(saved[name], tmp)
                kept.add(name)
    finally:
        shutil.rmtree(aside, ignore_errors=True)


def _same_ingest(a: Path, b: Path) -> bool:
    """Whether two floor workspaces hold the same ingested files (their reports aside: times)."""
    ra, rb = Workspace(a).record("ingest"), Workspace(b).record("ingest")
    if ra is None or rb is None:
        return False
    report = str(Workspace(a).report_path("ingest").relative_to(a))
    return {k: v for k, v in ra["files"].items() if k != report} == \
        {k: v for k, v in rb["files"].items() if k != report}


def _link_copy(src: Path, dst: Path) -> Path:
    """A copy of the directory ``src`` made of hard links (the workspace never rewrites a file in place;
    copies where links are not possible)."""

    def link(s: str, d: str) -> None:
        try:
            os.link(s, d)
        except OSError:
            shutil.copy2(s, d)

    shutil.copytree(src, dst, copy_function=link)
    return dst


def _input_files(inputs: list[str | Path]) -> list[tuple[str, Path]]:
    """(key, file) of every file under ``inputs``: key "<input's position>:<path under it>"."""
    out: list[tuple[str, Path]] = []
    for i, p in enumerate(map(Path, inputs)):
        if p.is_dir():
            out += sorted((f"{i}:{f.relative_to(p).as_posix()}", f) for f in p.rglob("*") if f.is_file())
        elif p.is_file():
            out.append((f"{i}:{p.name}", p))
    return out



def stage_records(path: str | Path) -> dict[str, str]:
    """{stage: sha256 of its record} of a floor's workspace, for the stages it has (what the build leaves)."""
    return record_digests(path)


#: stage -> the config section its config.toml holds that the build sets
_SECTION = {"ingest": "ingest", "optimize": "optimize", "map": "map", "evaluate": "evaluate"}


def hand_made(workspace: str | Path, state: dict) -> list[str]:
    """One line per floor of the build ``state`` whose stages were re-made since the build left them (their
    records changed): the stages and what differs from the build's config (or that the config is the same:
    other options, such as --anchors, or another input). Floors the state has no records of are skipped."""
    floors = building_floors(workspace) or {Path(workspace).name: Path(workspace)}
    out = []
    for name, entry in state.get("floors", {}).items():
        recorded = entry.get("records") if isinstance(entry, dict) else None
        if not isinstance(recorded, dict) or name not in floors:
            continue
        now = stage_records(floors[name])
        changed = [s for s in STAGE_DIRS if now.get(s) != recorded.get(s)]
        if not changed:
            continue
        build_cfg = {**(entry.get("configs") or {}),
                     "ingest": ((state.get("inputs") or {}).get("settings") or {}).get("ingest", "")}
        what = []
        for stage in changed:
            diff = _config_diff(Workspace(floors[name]).path(f"{STAGE_DIRS[stage]}.config"), build_cfg.get(
                _SECTION[stage], ""), _SECTION[stage]) if stage in now else "removed"
            what.append(f"{stage} ({diff})")
        label = f"floor {name}" if building_floors(workspace) is not None else str(workspace)
        out.append(f"{label}: {', '.join(what)} made by hand since the last build")
    return out


def _config_diff(path: Path, build_text: str, section: str) -> str:
    """What the config a stage ran with (``path``) sets otherwise than the build's (``build_text``)."""
    try:
        mine = _flat(tomllib.loads(path.read_text()).get(section, {}))
        theirs = _flat(tomllib.loads(build_text).get(section, {}))
    except (OSError, ValueError, RecursionError):
        return "its config unreadable"
    keys = [k for k in sorted(set(mine) | set(theirs)) if mine.get(k) != theirs.get(k)]
    if not keys:
        return "same config: other options or inputs"
    shown = ", ".join(f"{section}.{k} = {mine.get(k)!r} (build: {theirs.get(k)!r})" for k in keys[:3])
    return shown + (f" and {len(keys) - 3} more" if len(keys) > 3 else "")


def _flat(d: dict, prefix: str = "") -> dict:
    out: dict = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out
