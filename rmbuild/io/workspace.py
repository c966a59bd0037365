"""The on-disk workspace: the only module that knows artefact file names and formats.

Layout (one directory per project; every table is Parquet)::

    WORKSPACE/
      manifest.json            the workspace marker: format "rmbuild-workspace", schema version, creation
      data/                    ingest: walks, poses, wifi (with node), ble (when any), fixes, fingerprints,
                               truth/
      optimize/                optimised poses, vicinity pairs, per-walk report, tum/*.txt (+ tum/walks.csv;
                               tum/truth/*.txt: the true paths, same file names, when the input had them)
      map/                     radio map tables, UJIIndoorLoc-style CSV, sidecar JSON, PNG pictures,
                               evo/: the map's walks and their truth as TUM files on one clock
      evaluate/                per-scan errors, CDF plot
      <stage dir>/report.json  the stage's machine-readable summary
      <stage dir>/config.toml  the resolved config the stage ran with
      <stage dir>/stage.json   the stage's record: completion time, version, sha256 of every file, and
                               the records of the stages it read (to tell stale outputs)
      report.html, report/     `rmbuild report` (HTML page and its PNGs)
      view.rrd, <stage>.rrd    rerun recordings (`rmbuild view`, `--rerun`)
      build_state.json         `rmbuild build`: its inputs' fingerprint, each floor's configs and result
                               (what a re-run may skip; rmbuild.stages.building.state)

A building (several floors) is a workspace whose manifest lists its floors; each floor is a whole
single-floor workspace of the layout above, and the building keeps only the totals over its floors::

    WORKSPACE/
      manifest.json            the marker, plus "floors": [{"name": "F1", "dir": "floors/F1", "level": 0}, ...]
      floors/<NAME>/           one workspace per floor (its own manifest.json, data/, optimize/, map/, ...)
      building/<command>.json  a stage's report over the building: each floor's report under "floors", totals
      report.html              `rmbuild report`: the building page linking each floor's report

Commit: each stage writes its directory in a temporary directory, report and record included, and one
rename makes it the stage directory (:func:`rmbuild.io.atomic.replacing_dir`): a kill at any point leaves
the previous version of the stage or the new one, each with its own matching report and checksums.
``ingest`` creates the whole workspace the same way. Every file a stage reads is checked against the
checksum its record holds. Commands hold the workspace lock (:mod:`rmbuild.io.lock`) while they run.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pandas as pd

from rmbuild import __version__
from rmbuild.errors import InputError, WorkspaceError
from rmbuild.io.atomic import clean_json, recover_dir, refuse_link, replacing_dir, write_json_atomic
from rmbuild.io.layout import FLOORS_DIR, MANIFEST, MAX_MARKER_BYTES, WORKSPACE_FORMAT, building_floors
from rmbuild.io.layout import is_marker as _is_marker
from rmbuild.io.layout import read_marker as _read_marker
from rmbuild.io.lock import holds_lock, workspace_lock
from rmbuild.types import OPTIMIZE_STATE_VERSION, WIFI_COLUMNS, Dataset, Fingerprints, OptimizeState

#: version of this layout; 1 kept the stage reports and checksums outside the stage directories
SCHEMA_VERSION = 2
RECORD = "stage.json"
REPORT = "report.json"
CONFIG = "config.toml"
#: bytes; a Parquet column's dictionary beyond this falls back to plain encoding. pyarrow's 1 MB default
#: builds and then drops large dictionaries of continuous columns (times, coordinates): 16 KB wrote the
#: ingest tables ~1.5x faster, and smaller (bench/bench_ingest.py)
PARQUET_DICT_PAGE_BYTES = 1 << 14

#: stage -> its directory in the workspace
STAGE_DIRS = {
    "ingest": "data",
    "optimize": "optimize",
    "map": "map",
    "evaluate": "evaluate",
}
#: the command that produces each stage's outputs (for error messages)
STAGE_COMMANDS = {"ingest": "ingest", "optimize": "optimize", "map": "export-map", "evaluate": "evaluate"}
#: the stages each stage reads (their records are noted in its own, to tell stale outputs)
STAGE_INPUTS = {"ingest": (), "optimize": ("ingest",), "map": ("ingest", "optimize"),
                "evaluate": ("ingest", "optimize", "map")}

#: every artefact: key -> path relative to the workspace root
ARTEFACTS: dict[str, str] = {
    # ingest
    "data.walks": "data/walks.parquet",
    "data.poses": "data/poses.parquet",
    "data.wifi": "data/wifi.parquet",
    "data.ble": "data/ble.parquet",
    "data.fixes": "data/fixes.parquet",
    "data.fingerprints": "data/fingerprints.parquet",
    "data.truth_poses": "data/truth/poses.parquet",
    "data.truth_aps": "data/truth/aps.parquet",
    "data.venue": "data/truth/venue.json",
    "data.truth_walks": "data/truth/walks.parquet",
    "data.truth_devices": "data/truth/devices.parquet",
    "data.truth_users": "data/truth/users.parquet",
    "data.truth_landmarks": "data/truth/landmarks.parquet",
    "data.truth_beacons": "data/truth/beacons.parquet",
    # local metres: GeoJSON-shaped but not RFC 7946 GeoJSON (whose coordinates are WGS84 lon/lat), hence .json
    "data.floorplan": "data/floorplan.local.json",
    "data.floor_image": "data/floor_image.png",
    # optimize
    "optimize.poses": "optimize/poses.parquet",
    "optimize.initial_poses": "optimize/initial_poses.parquet",
    "optimize.pairs": "optimize/pairs.parquet",
    "optimize.walks": "optimize/walks.parquet",
    "optimize.history": "optimize/history.parquet",
    "optimize.tum_dir": "optimize/tum",
    "optimize.tum_index": "optimize/tum/walks.csv",
    "optimize.tum_truth_dir": "optimize/tum/truth",
    "optimize.tum_truth_index": "optimize/tum/truth/walks.csv",
    "optimize.anchors": "optimize/anchors.parquet",
    # the typed state later stages read (rmbuild.types.OptimizeState); report.json is for people and tools
    "optimize.state": "optimize/state.json",
    # map
    "map.cells": "map/radiomap.parquet",
    "map.cell_table": "map/cells.parquet",
    "map.nodes": "map/reference_nodes.parquet",
    "map.wide_csv": "map/radiomap_uji.csv",
    "map.wide_csv_aps": "map/radiomap_uji_aps.csv",
    "map.cells_geojson": "map/cells.geojson",
    "map.sidecar": "map/radiomap.json",
    "map.histograms": "map/histograms.parquet",
    "map.ble_cells": "map/radiomap_ble.parquet",
    "map.ble_cell_table": "map/cells_ble.parquet",
    "map.ble_wide_csv": "map/radiomap_ble_uji.csv",
    "map.ble_wide_csv_aps": "map/radiomap_ble_uji_aps.csv",
    "map.ble_sidecar": "map/radiomap_ble.json",
    "map.coverage_png": "map/coverage.png",
    "map.evo_map": "map/evo/map.txt",
    "map.evo_truth": "map/evo/truth.txt",
    "map.evo_waypoints": "map/evo/waypoints.txt",
    "map.evo_map_at_waypoints": "map/evo/map_at_waypoints.txt",
    "map.evo_clock": "map/evo/clock.csv",
    "map.heatmaps_png": "map/heatmaps.png",
    # evaluate
    "evaluate.errors": "evaluate/errors.parquet",
    "evaluate.tracks": "evaluate/tracks.parquet",
    "evaluate.cdf_png": "evaluate/cdf.png",
    # outside the stage directories: `rmbuild report` and the rerun recordings
    "report.html": "report.html",
    "report.png_dir": "report",
    "view.rrd": "view.rrd",
    "build.state": "build_state.json",
}
#: artefacts an earlier rmbuild wrote under another name, read there when the new name is absent
LEGACY_ARTEFACTS = {"data.floorplan": "data/floorplan.geojson"}
for _stage, _dir in STAGE_DIRS.items():
    ARTEFACTS[f"{_dir}.report"] = f"{_dir}/{REPORT}"
    ARTEFACTS[f"{_dir}.config"] = f"{_dir}/{CONFIG}"
    ARTEFACTS[f"{_stage}.rrd"] = f"{_stage}.rrd"

#: the building-level reports, relative to a building workspace's root (its floors: FLOORS_DIR)
BUILDING_DIR = "building"

#: walk ids become file names (optimize/tum/<name>.txt): at most this many characters before the suffix
MAX_WALK_FILE_STEM = 64
#: names Windows reserves whatever the extension (a workspace may be copied there)
_RESERVED = {"con", "prn", "aux", "nul", *(f"com{i}" for i in range(1, 10)), *(f"lpt{i}" for i in range(1, 10))}



def parse_optimize_state(doc: Any, where: Path | str) -> OptimizeState:
    """optimize/state.json's document as an :class:`OptimizeState`; WorkspaceError (naming ``where``) for
    another version or a malformed document."""
    version = doc.get("version") if isinstance(doc, dict) else None
    if version != OPTIMIZE_STATE_VERSION:
        raise WorkspaceError(f"{where}: state version {version!r}, this rmbuild reads version "
                             f"{OPTIMIZE_STATE_VERSION}; re-run `rmbuild optimize --force`")
    try:
        return OptimizeState.from_json(doc)
    except (KeyError, TypeError, ValueError, AttributeError) as e:
        raise WorkspaceError(f"{where}: malformed state ({type(e).__name__}: {e}); re-run `rmbuild optimize "
                             "--force`") from None


def _sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: Path) -> str:
    """Hex SHA-256 of a file's bytes, read in 1 MiB chunks."""
    h = hashlib.sha256()
    with path.open("rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _now() -> str:
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def stage_of(key: str) -> str | None:
    """The stage whose directory holds artefact ``key`` (None for files outside the stage directories)."""
    rel = ARTEFACTS[key]
    return next((s for s, d in STAGE_DIRS.items() if rel.startswith(d + "/")), None)


def walk_file_names(walk_ids: Iterable[str]) -> dict[str, str]:
    """A file stem for every walk id: unique (also ignoring case), at most :data:`MAX_WALK_FILE_STEM`
    characters, only ``[A-Za-z0-9._-]``, never hidden (no leading "."), never a reserved device name.

    An id that is already such a name keeps it; any other (``a/b``, ``.x``, a 300-character id, ids equal
    but for case) gets a readable prefix and a hash of the id, so two ids never share a file.
    """
    ids = [str(w) for w in dict.fromkeys(walk_ids)]
    base = {w: _safe_stem(w) for w in ids}
    folded: dict[str, int] = {}
    for w in ids:
        folded[base[w].casefold()] = folded.get(base[w].casefold(), 0) + 1
    out: dict[str, str] = {}
    for w in ids:
        b = base[w]
        if b != w or folded[b.casefold()] > 1 or b.casefold().split(".")[0] in _RESERVED:
            digest = hashlib.sha1(w.encode("utf-8", "surrogatepass")).hexdigest()[:12]
            b = f"{b[:MAX_WALK_FILE_STEM - 13]}-{digest}"
        out[w] = b
    if len({v.casefold() for v in out.values()}) != len(out):  # a 48-bit hash collision between two ids
        raise WorkspaceError("two walk ids map to one file name; rename one of them")
    return out


def _safe_stem(walk_id: str) -> str:
    s = "".join(c if (c.isascii() and c.isalnum()) or c in "-_." else "_" for c in walk_id)
    s = s.lstrip(".")[:MAX_WALK_FILE_STEM]
    return s or "walk"


@dataclass
class StageWriter:
    """Collects one stage's outputs in a temporary directory that becomes the stage directory on success.

    Keys are :data:`ARTEFACTS` keys of this stage; :meth:`path` gives a path for writers that need one.
    ``report`` becomes ``report.json`` of the stage.
    """

    stage: str
    stage_dir: Path  # the temporary directory that becomes the stage's directory
    report: dict[str, Any] = field(default_factory=dict)

    def path(self, key: str) -> Path:
        rel = ARTEFACTS[key]
        prefix = STAGE_DIRS[self.stage] + "/"
        if not rel.startswith(prefix):
            raise KeyError(f"{key} is not an artefact of stage {self.stage}")  # programming error
        p = self.stage_dir / rel[len(prefix):]
        p.parent.mkdir(parents=True, exist_ok=True)
        return p

    def table(self, key: str, df: pd.DataFrame) -> None:
        df.to_parquet(self.path(key), index=False, dictionary_pagesize_limit=PARQUET_DICT_PAGE_BYTES)

    def json(self, key: str, obj: Any) -> None:
        self.path(key).write_text(json.dumps(clean_json(obj), indent=2) + "\n")

    def text(self, key: str, text: str) -> None:
        self.path(key).write_text(text)

    def optimize_state(self, state: OptimizeState) -> None:
        """optimize's typed state (:class:`rmbuild.types.OptimizeState`), versioned."""
        self.json("optimize.state", state.to_json())

    def binary(self, key: str, data: bytes) -> None:
        self.path(key).write_bytes(data)

    def figure(self, key: str, fig: Any, dpi: int = 110) -> None:
        """Save a matplotlib figure and close it (pyplot keeps open figures alive)."""
        import matplotlib.pyplot as plt

        fig.savefig(self.path(key), dpi=dpi, bbox_inches="tight")
        plt.close(fig)

    def config(self, toml_text: str) -> None:
        """The resolved config of this run, written next to the outputs."""
        self.path(f"{STAGE_DIRS[self.stage]}.config").write_text(toml_text)

    def per_walk_texts(self, dir_key: str, index_key: str, texts: dict[str, str], suffix: str,
                       columns: dict[str, dict[str, Any]] | None = None) -> None:
        """One text file per walk in directory ``dir_key``, named by :func:`walk_file_names`; the table
        ``index_key`` (walk_id, file, then each of ``columns``: name -> {walk_id: value}) writes the
        mapping down."""
        folder = self.path(dir_key)
        folder.mkdir(parents=True, exist_ok=True)
        names = walk_file_names(texts)
        for wid, text in texts.items():
            (folder / f"{names[wid]}{suffix}").write_text(text)
        index = pd.DataFrame({"walk_id": list(names), "file": [f"{n}{suffix}" for n in names.values()]})
        for col, values in (columns or {}).items():
            index[col] = [values.get(w) for w in names]
        index.to_csv(self.path(index_key), index=False)


class Workspace:
    """An rmbuild workspace directory. Open an existing one with :meth:`open`; ingest creates one.

    Opening recovers an interrupted swap only when this process holds the workspace's lock
    (:func:`rmbuild.io.lock.workspace_lock`); stages take the lock for their whole run.
    """

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self._records: dict[str, dict | None] = {}
        self._verified: set[str] = set()

    # ------------------------------------------------------------------ creation and opening
    @staticmethod
    @contextlib.contextmanager
    def create(root: str | Path, force: bool = False) -> Iterator[StageWriter]:
        """Create (or with ``force`` replace) a workspace holding the ingest stage, atomically.

        Refuses to replace an existing non-empty directory without ``force``, and never replaces a
        directory that is not an rmbuild workspace (one whose manifest.json is rmbuild's marker). A ``root``
        that is a symbolic link stands for the directory it points to, which is replaced (the link stays).
        """
        root = _resolved_root(root)
        with workspace_lock(root, "ingest"):
            recover_dir(root)
            check_replaceable(root, force)
            with replacing_dir(root) as tmp:
                writer = StageWriter("ingest", tmp / STAGE_DIRS["ingest"])
                yield writer
                _seal(writer, {})
                marker = {"format": WORKSPACE_FORMAT, "schema_version": SCHEMA_VERSION,
                          "rmbuild_version": __version__, "created_utc": _now()}
                write_json_atomic(tmp / MANIFEST, marker)

    @staticmethod
    @contextlib.contextmanager
    def create_building(root: str | Path, floors: dict[str, int | None],
                        force: bool = False) -> Iterator[dict[str, StageWriter]]:
        """Create (or with ``force`` replace) a building workspace, atomically: one ingest writer per floor
        (``floors``: name -> level, None when unknown), each floor a whole workspace under ``floors/``."""
        root = _resolved_root(root)
        dirs = walk_file_names(floors)
        with workspace_lock(root, "ingest"):
            recover_dir(root)
            check_replaceable(root, force)
            with replacing_dir(root) as tmp:
                writers = {n: StageWriter("ingest", tmp / FLOORS_DIR / dirs[n] / STAGE_DIRS["ingest"])
                           for n in floors}
                yield writers
                marker = {"format": WORKSPACE_FORMAT, "schema_version": SCHEMA_VERSION,
                          "rmbuild_version": __version__, "created_utc": _now()}
                for name, writer in writers.items():
                    _seal(writer, {})
                    write_json_atomic(tmp / FLOORS_DIR / dirs[name] / MANIFEST, {**marker, "floor": name})
                write_json_atomic(tmp / MANIFEST, {**marker, "floors": [
                    {"name": n, "dir": f"{FLOORS_DIR}/{dirs[n]}", "level": lv} for n, lv in floors.items()]})

    @classmethod
    def open(cls, root: str | Path) -> Workspace:
        root = Path(root)
        _recover(root)
        marker = _read_marker(root)
        if marker is None:
            raise WorkspaceError(
                f"{root} is not an rmbuild workspace (no {MANIFEST}); create one with `rmbuild ingest`"
            )
        if not _is_marker(marker):
            raise WorkspaceError(f"{root / MANIFEST}: not an rmbuild workspace marker")
        if marker.get("schema_version") != SCHEMA_VERSION:
            raise WorkspaceError(
                f"{root / MANIFEST}: workspace schema version {marker.get('schema_version')} is not "
                f"{SCHEMA_VERSION} (written by an older rmbuild); re-run `rmbuild ingest --force`"
            )
        return cls(root)

    @property
    def manifest(self) -> dict[str, Any]:
        """The workspace marker (format, schema version, creation)."""
        m = _read_marker(self.root)
        if m is None:
            raise WorkspaceError(f"{self.root / MANIFEST}: missing or unreadable")
        return m

    # ------------------------------------------------------------------ stage records
    def record(self, stage: str) -> dict | None:
        """The record of ``stage`` (its stage.json: completion, version, checksums), None when absent."""
        if stage not in self._records:
            self._records[stage] = _read_record(self.root / STAGE_DIRS[stage] / RECORD, stage)
        return self._records[stage]

    def has(self, stage: str) -> bool:
        return self.record(stage) is not None

    def require(self, stage: str) -> None:
        """Raise WorkspaceError naming the command to run when ``stage`` has no outputs here."""
        if not self.has(stage):
            raise WorkspaceError(
                f"workspace {self.root} has no {stage} outputs; run `rmbuild {STAGE_COMMANDS[stage]} "
                f"-w {self.root}` first"
            )

    def stale_inputs(self, stage: str) -> list[str]:
        """The stages ``stage`` read that have been re-run (or removed) since: its outputs are stale."""
        rec = self.record(stage)
        if rec is None:
            return []
        now = self._input_digests(stage)
        return [s for s, d in (rec.get("inputs") or {}).items() if now.get(s) != d]

    def _input_digests(self, stage: str) -> dict[str, str | None]:
        out: dict[str, str | None] = {}
        for s in STAGE_INPUTS[stage]:
            p = self.root / STAGE_DIRS[s] / RECORD
            out[s] = sha256_file(p) if p.is_file() else None
        return out

    def check_can_write(self, stage: str, force: bool) -> None:
        """Refuse to replace ``stage``'s existing outputs unless ``force``."""
        if not force and (self.root / STAGE_DIRS[stage]).exists():
            raise WorkspaceError(
                f"{self.root / STAGE_DIRS[stage]} already holds {STAGE_COMMANDS[stage]} outputs; "
                "pass --force to replace them"
            )

    def path(self, key: str) -> Path:
        p = self.root / ARTEFACTS[key]
        old = LEGACY_ARTEFACTS.get(key)
        if old is not None and not p.exists() and (self.root / old).exists():  # written by an earlier rmbuild
            return self.root / old
        return p

    def exists(self, key: str) -> bool:
        return self.path(key).exists()

    def report_path(self, stage: str) -> Path:
        return self.path(f"{STAGE_DIRS[stage]}.report")

    # ------------------------------------------------------------------ writing a stage
    @contextlib.contextmanager
    def replacing_ingest(self) -> Iterator[StageWriter]:
        """Hold the workspace's lock and replace its ``data/`` directory in one commit (``ingest --append``);
        the later stages' outputs stay, stale: their records name the ingest they read."""
        with workspace_lock(self.root, "ingest"):
            with replacing_dir(self.root / STAGE_DIRS["ingest"]) as tmp_dir:
                writer = StageWriter("ingest", tmp_dir)
                yield writer
                _seal(writer, {})
            self._records.clear()
            self._verified.clear()

    @contextlib.contextmanager
    def writing(self, stage: str) -> Iterator[StageWriter]:
        """Write ``stage``'s directory as a whole, its report and record included, in one commit."""
        if stage == "ingest":
            raise ValueError("ingest creates the workspace: use Workspace.create")
        with workspace_lock(self.root, STAGE_COMMANDS[stage]):
            inputs = self._input_digests(stage)
            with replacing_dir(self.root / STAGE_DIRS[stage]) as tmp_dir:
                writer = StageWriter(stage, tmp_dir)
                yield writer
                _seal(writer, inputs)
            self._records.pop(stage, None)
            self._verified = {v for v in self._verified if not v.startswith(STAGE_DIRS[stage] + "/")}

    # ------------------------------------------------------------------ reading (checksums verified)
    def read_bytes(self, key: str) -> bytes:
        """The bytes of artefact ``key``, checked against its stage's record."""
        p = self.path(key)
        stage = stage_of(key)
        if stage is not None:
            self.require(stage)
        try:
            data = p.read_bytes()
        except FileNotFoundError:
            cmd = STAGE_COMMANDS.get(stage or "", "")
            raise WorkspaceError(f"{p}: missing from the workspace" + (f"; re-run `rmbuild {cmd} --force`"
                                                                        if cmd else "")) from None
        except OSError as e:
            raise WorkspaceError(f"{p}: unreadable ({e.strerror})") from None
        if stage is not None:
            self._verify(stage, p.relative_to(self.root).as_posix(), data)
        return data

    def _verify(self, stage: str, rel: str, data: bytes) -> None:
        if rel in self._verified:
            return
        files = (self.record(stage) or {}).get("files", {})
        want = files.get(rel)
        cmd = STAGE_COMMANDS[stage]
        if want is None:
            raise WorkspaceError(f"{self.root / rel}: not among the files `rmbuild {cmd}` wrote (see "
                                 f"{STAGE_DIRS[stage]}/{RECORD}); re-run `rmbuild {cmd} --force`")
        if _sha256_bytes(data) != want:
            raise WorkspaceError(f"{self.root / rel}: checksum mismatch: the file changed after `rmbuild {cmd}` "
                                 f"wrote it; re-run `rmbuild {cmd} --force`")
        self._verified.add(rel)

    def verify(self, stage: str) -> list[str]:
        """Problems of ``stage``'s directory against its record (missing, changed or extra files)."""
        rec = self.record(stage)
        if rec is None:
            return [f"{stage}: no record"]
        d = self.root / STAGE_DIRS[stage]
        files = rec.get("files", {})
        problems = [f"{rel}: missing" for rel in files if not (self.root / rel).is_file()]
        problems += [f"{rel}: checksum mismatch" for rel, h in files.items()
                     if (self.root / rel).is_file() and sha256_file(self.root / rel) != h]
        present = {str(p.relative_to(self.root)) for p in d.rglob("*") if p.is_file() and p != d / RECORD}
        problems += [f"{rel}: not in the record" for rel in sorted(present - set(files))]
        return problems

    def read_table(self, key: str) -> pd.DataFrame:
        data = self.read_bytes(key)
        try:
            return pd.read_parquet(io.BytesIO(data))
        except Exception as e:  # pyarrow raises several types for corrupt files
            raise WorkspaceError(f"{self.path(key)}: unreadable Parquet ({type(e).__name__}: {e})") from None

    def read_json(self, key: str) -> Any:
        try:
            return json.loads(self.read_bytes(key))
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise WorkspaceError(f"{self.path(key)}: invalid JSON ({e})") from None

    def read_text(self, key: str) -> str:
        try:
            return self.read_bytes(key).decode("utf-8")
        except UnicodeDecodeError as e:
            raise WorkspaceError(f"{self.path(key)}: not UTF-8 text ({e.reason})") from None

    def read_report(self, stage: str) -> dict | None:
        """The stage's report (None when the stage has not run)."""
        return self.read_json(f"{STAGE_DIRS[stage]}.report") if self.has(stage) else None

    def read_optimize_state(self) -> OptimizeState:
        """The last optimize's typed state. Raises WorkspaceError when optimize has not run, when its state
        file is missing (written by an older rmbuild) or of another version, or malformed."""
        self.require("optimize")
        where = self.path("optimize.state")
        if not self.exists("optimize.state"):
            raise WorkspaceError(f"{where}: missing (optimize ran with an older rmbuild); re-run `rmbuild optimize "
                                 "--force`")
        return parse_optimize_state(self.read_json("optimize.state"), where)

    def read_config_text(self, stage: str) -> str | None:
        """The resolved config the stage ran with, as TOML text (None when absent)."""
        key = f"{STAGE_DIRS[stage]}.config"
        return self.read_text(key) if self.has(stage) and self.exists(key) else None

    def read_dataset(self, readings: bool = True) -> Dataset:
        """The ingested data set. ``readings=False``: ``wifi`` is left empty (its columns only) and not read,
        for the stages that work from the fingerprints alone (it is the largest table)."""
        self.require("ingest")
        truth_poses = self.read_table("data.truth_poses") if self.exists("data.truth_poses") else None
        truth_aps = self.read_table("data.truth_aps") if self.exists("data.truth_aps") else None
        venue = self.read_json("data.venue") if self.exists("data.venue") else None
        truth_extra = {
            k.removeprefix("data.truth_"): self.read_table(k)
            for k in ("data.truth_walks", "data.truth_devices", "data.truth_users", "data.truth_landmarks",
                      "data.truth_beacons")
            if self.exists(k)
        }
        return Dataset(
            walks=self.read_table("data.walks"),
            poses=self.read_table("data.poses"),
            wifi=self.read_table("data.wifi") if readings else pd.DataFrame({c: [] for c in WIFI_COLUMNS}),
            fixes=self.read_table("data.fixes"),
            truth_poses=truth_poses,
            truth_aps=truth_aps,
            venue=venue,
            extra={"truth": truth_extra},
            ble=self.read_table("data.ble") if self.exists("data.ble") else None,
        )

    def read_fingerprints(self) -> Fingerprints:
        self.require("ingest")
        return Fingerprints.from_long(self.read_table("data.fingerprints"))


def floor_levels(root: str | Path) -> dict[str, int | None]:
    """floor name -> level (0 ground floor, -1 the first basement; None unknown) of a building workspace."""
    m = _read_marker(Path(root)) or {}
    return {f["name"]: f.get("level") if isinstance(f.get("level"), int) else None for f in m.get("floors", [])}


def level_of_floor(root: str | Path) -> int | None:
    """The level of the floor whose workspace is ``root`` (a building's ``floors/<NAME>``); None for a
    single-floor workspace or an unknown level."""
    root = Path(root).resolve()
    if root.parent.name != FLOORS_DIR:
        return None
    floors = building_floors(root.parent.parent) or {}
    levels = floor_levels(root.parent.parent)
    return next((levels.get(n) for n, p in floors.items() if p.resolve() == root), None)


def record_digests(root: str | Path) -> dict[str, str]:
    """{stage: sha256 of its record} of the stages the workspace at ``root`` has (records that are links or
    not files are left out)."""
    out = {}
    for stage, d in STAGE_DIRS.items():
        p = Path(root) / d / RECORD
        if p.is_file() and not p.is_symlink():
            out[stage] = _sha256_bytes(p.read_bytes())
    return out


def building_report_path(root: str | Path, command: str) -> Path:
    """Where a stage's building-level report goes (``building/<command>.json``); LinkError when its folder
    is a symbolic link (never written through)."""
    refuse_link(Path(root) / BUILDING_DIR)
    return Path(root) / BUILDING_DIR / f"{command}.json"


def _resolved_root(root: str | Path) -> Path:
    """``root`` with a symbolic link at its last component resolved (the workspace it points to)."""
    p = Path(root)
    return p.resolve() if p.is_symlink() else p


#: what commands write inside a workspace besides its stage directories, relative to its root: the report
#: page, and rerun recordings (``*.rrd``); and the folders of the report's figures and floor pages
OUTPUTS_IN_WORKSPACE = ("report.html",)
OUTPUT_DIRS_IN_WORKSPACE = ("report", "report_figures", "report_floors")


def check_outside_workspace(path: str | Path, what: str = "output") -> None:
    """InputError when ``path`` (an output a user names) falls among a workspace's own files: its stage
    directories, marker, build state, building reports or floors (anything but the report page, its
    figures and recordings), or is a workspace's lock file; never written, even with --force."""
    p = Path(path)
    full = p.parent.resolve() / p.name
    if full.name.startswith(".") and full.name.endswith(".lock") and \
            _is_marker(_read_marker(full.parent / full.name[1:-len(".lock")])):
        raise InputError(f"{what} {p} is the lock file of workspace {full.parent / full.name[1:-5]}; choose "
                         "another path")
    for ws in full.parents:
        if not _is_marker(_read_marker(ws)):
            continue
        parts = full.relative_to(ws).parts
        ok = (len(parts) == 1 and (parts[0] in OUTPUTS_IN_WORKSPACE or parts[0].endswith(".rrd"))) or \
            (len(parts) >= 2 and parts[0] in OUTPUT_DIRS_IN_WORKSPACE)
        if not ok:
            raise InputError(f"{what} {p} lies among the files of workspace {ws} ({parts[0]}), which only rmbuild's "
                             "stages write; write it outside the workspace (or as its report.html, report/ or "
                             "*.rrd)")
        return


def _recover(root: Path) -> None:
    """Undo swaps interrupted by a kill (see :func:`rmbuild.io.atomic.recover_dir`), which needs the
    exclusive lock: under this process' exclusive lock, or by taking it for a moment when nobody holds it."""

    def recover() -> None:
        recover_dir(root)
        for d in STAGE_DIRS.values():
            recover_dir(root / d)

    if holds_lock(root, exclusive=True):
        recover()
    elif not holds_lock(root, exclusive=False) and root.parent.is_dir():
        try:
            with workspace_lock(root, "open"):
                recover()
        except WorkspaceError:  # busy (its holder recovers), or no lock can be created here
            pass


def check_replaceable(root: Path, force: bool) -> None:
    """Refuse to (re)create a workspace at ``root`` over a non-empty directory that is not an rmbuild
    workspace (whatever ``force`` says), or over an existing workspace without ``force``."""
    if not root.exists():
        return
    if not root.is_dir():
        raise WorkspaceError(f"{root} exists and is not a directory")
    if not any(root.iterdir()):
        return
    if not _is_marker(_read_marker(root)):
        raise WorkspaceError(f"{root} exists, is not empty and is not an rmbuild workspace (no rmbuild "
                             f"{MANIFEST}); refusing to replace it, with or without --force")
    if not force:
        raise WorkspaceError(f"workspace {root} already exists; pass --force to replace it")


def _read_record(p: Path, stage: str) -> dict | None:
    try:
        if not p.is_file() or p.stat().st_size > 64 * MAX_MARKER_BYTES:
            return None
        rec = json.loads(p.read_bytes())
    except (OSError, ValueError, RecursionError):
        return None
    ok = isinstance(rec, dict) and rec.get("stage") == stage and isinstance(rec.get("files"), dict)
    return rec if ok else None


def _seal(writer: StageWriter, inputs: dict[str, str | None]) -> None:
    """Write the stage's report and its record (sha256 of every file) into the stage directory."""
    write_json_atomic(writer.path(f"{STAGE_DIRS[writer.stage]}.report"), clean_json(writer.report))
    d = writer.stage_dir
    files = {}
    for p in sorted(d.rglob("*")):
        if p.is_file() and p != d / RECORD:
            files[str(Path(STAGE_DIRS[writer.stage]) / p.relative_to(d))] = sha256_file(p)
    record = {"stage": writer.stage, "completed_utc": _now(), "rmbuild_version": __version__,
              "schema_version": SCHEMA_VERSION, "inputs": inputs, "files": files}
    write_json_atomic(d / RECORD, record)


def write_dataset(writer: StageWriter, ds: Dataset, fp: Fingerprints) -> None:
    """Write everything ingest produced (the ``data/`` directory)."""
    writer.table("data.walks", ds.walks)
    writer.table("data.poses", ds.poses)
    writer.table("data.wifi", ds.wifi)
    if ds.ble is not None:
        writer.table("data.ble", ds.ble)
    writer.table("data.fixes", ds.fixes)
    writer.table("data.fingerprints", fp.to_long())
    if ds.truth_poses is not None:
        writer.table("data.truth_poses", ds.truth_poses)
    if ds.truth_aps is not None:
        writer.table("data.truth_aps", ds.truth_aps)
    if ds.venue is not None:
        writer.json("data.venue", ds.venue)
    for name, df in ds.extra.get("truth", {}).items():
        key = f"data.truth_{name}"
        if key in ARTEFACTS:
            writer.table(key, df)


def check_output_file(path: str | Path, force: bool, what: str = "output") -> Path:
    """Refuse to replace an existing file (a report, a recording) without ``force``, to write through a
    symbolic link, or to write among a workspace's own files (:func:`check_outside_workspace`); returns the
    path."""
    p = Path(path)
    if p.is_symlink():
        raise InputError(f"{what} {p} is a symbolic link; rmbuild never writes through one: give the file it "
                         "points to, or another name")
    check_outside_workspace(p, what)
    if p.is_dir():
        raise InputError(f"{what} {p} is a directory")
    if p.exists() and not force:
        raise InputError(f"{what} {p} already exists; pass --force to replace it")
    return p


def check_output_dir(path: Path, force: bool) -> None:
    """Refuse to write into an existing non-empty directory without ``force`` (for simulate's OUT_DIR)."""
    if path.exists() and (not path.is_dir() or any(path.iterdir())) and not force:
        raise InputError(f"{path} already exists and is not empty; pass --force to replace it")
