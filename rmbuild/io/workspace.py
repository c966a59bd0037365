"""The on-disk workspace: the only module that knows artefact file names and formats.

Layout (one directory per project; every table is Parquet)::

    WORKSPACE/
      manifest.json            schema version, stages run, their configs and file checksums
      data/                    ingest: walks, poses, wifi (with node), fixes, fingerprints, config.toml
      truth/                   ground truth when the input had it (synthetic: true poses, APs, venue)
      optimize/                optimised poses, vicinity pairs, per-walk report, tum/*.txt, config.toml
      map/                     radio map tables, UJIIndoorLoc-style CSV, sidecar JSON, PNG pictures
      evaluate/                per-scan errors, CDF plot, config.toml
      reports/<stage>.json     machine-readable summary of each stage's last run

Each stage writes its directory as a whole (:func:`rmbuild.io.atomic.replacing_dir`): a crash leaves the
previous version or the new one. ``ingest`` creates the whole workspace the same way and refuses to
replace an existing one without ``force``.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pandas as pd

from rmbuild import __version__
from rmbuild.errors import InputError, WorkspaceError
from rmbuild.io.atomic import clean_json, recover_dir, replacing_dir, write_json_atomic
from rmbuild.types import Dataset, Fingerprints

SCHEMA_VERSION = 1
MANIFEST = "manifest.json"

#: stage -> its directory in the workspace
STAGE_DIRS = {
    "ingest": "data",
    "optimize": "optimize",
    "map": "map",
    "evaluate": "evaluate",
}
#: the command that produces each stage's outputs (for error messages)
STAGE_COMMANDS = {"ingest": "ingest", "optimize": "optimize", "map": "export-map", "evaluate": "evaluate"}

#: every artefact: key -> path relative to the workspace root
ARTEFACTS: dict[str, str] = {
    # ingest
    "data.walks": "data/walks.parquet",
    "data.poses": "data/poses.parquet",
    "data.wifi": "data/wifi.parquet",
    "data.fixes": "data/fixes.parquet",
    "data.fingerprints": "data/fingerprints.parquet",
    "data.truth_poses": "data/truth/poses.parquet",
    "data.truth_aps": "data/truth/aps.parquet",
    "data.venue": "data/truth/venue.json",
    "data.truth_walks": "data/truth/walks.parquet",
    "data.truth_devices": "data/truth/devices.parquet",
    "data.truth_users": "data/truth/users.parquet",
    "data.truth_landmarks": "data/truth/landmarks.parquet",
    # optimize
    "optimize.poses": "optimize/poses.parquet",
    "optimize.initial_poses": "optimize/initial_poses.parquet",
    "optimize.pairs": "optimize/pairs.parquet",
    "optimize.walks": "optimize/walks.parquet",
    "optimize.history": "optimize/history.parquet",
    "optimize.tum_dir": "optimize/tum",
    "optimize.anchors": "optimize/anchors.parquet",
    # map
    "map.cells": "map/radiomap.parquet",
    "map.nodes": "map/reference_nodes.parquet",
    "map.wide_csv": "map/radiomap_uji.csv",
    "map.sidecar": "map/radiomap.json",
    "map.histograms": "map/histograms.parquet",
    "map.coverage_png": "map/coverage.png",
    "map.heatmaps_png": "map/heatmaps.png",
    # evaluate
    "evaluate.errors": "evaluate/errors.parquet",
    "evaluate.tracks": "evaluate/tracks.parquet",
    "evaluate.cdf_png": "evaluate/cdf.png",
}


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _now() -> str:
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


@dataclass
class StageWriter:
    """Collects one stage's outputs in a temporary directory that becomes the stage directory on success.

    Keys are :data:`ARTEFACTS` keys of this stage; :meth:`path` gives a path for writers that need one.
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
        df.to_parquet(self.path(key), index=False)

    def json(self, key: str, obj: Any) -> None:
        self.path(key).write_text(json.dumps(clean_json(obj), indent=2) + "\n")

    def text(self, key: str, text: str) -> None:
        self.path(key).write_text(text)

    def figure(self, key: str, fig: Any, dpi: int = 110) -> None:
        fig.savefig(self.path(key), dpi=dpi, bbox_inches="tight")

    def config(self, toml_text: str) -> None:
        """The resolved config of this run, written next to the outputs."""
        self.stage_dir.mkdir(parents=True, exist_ok=True)
        (self.stage_dir / "config.toml").write_text(toml_text)


class Workspace:
    """An rmbuild workspace directory. Open an existing one with :meth:`open`; ingest creates one."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)

    # ------------------------------------------------------------------ creation and opening
    @staticmethod
    @contextlib.contextmanager
    def create(root: str | Path, force: bool = False) -> Iterator[StageWriter]:
        """Create (or with ``force`` replace) a workspace holding the ingest stage, atomically.

        Refuses to replace an existing non-empty directory without ``force``, and never replaces a
        directory that is not an rmbuild workspace.
        """
        root = Path(root)
        recover_dir(root)
        if root.exists():
            if not root.is_dir():
                raise WorkspaceError(f"{root} exists and is not a directory")
            if any(root.iterdir()):
                if not (root / MANIFEST).exists():
                    raise WorkspaceError(
                        f"{root} exists, is not empty and is not an rmbuild workspace; refusing to touch it"
                    )
                if not force:
                    raise WorkspaceError(f"workspace {root} already exists; pass --force to replace it")
        with replacing_dir(root) as tmp:
            writer = StageWriter("ingest", tmp / STAGE_DIRS["ingest"])
            yield writer
            manifest = {
                "schema_version": SCHEMA_VERSION,
                "rmbuild_version": __version__,
                "created_utc": _now(),
                "stages": {},
            }
            _record_stage(tmp, manifest, writer)
            write_json_atomic(tmp / MANIFEST, manifest)

    @classmethod
    def open(cls, root: str | Path) -> Workspace:
        root = Path(root)
        recover_dir(root)
        for d in STAGE_DIRS.values():
            recover_dir(root / d)
        if not (root / MANIFEST).is_file():
            raise WorkspaceError(
                f"{root} is not an rmbuild workspace (no {MANIFEST}); create one with `rmbuild ingest`"
            )
        ws = cls(root)
        m = ws.manifest
        if m.get("schema_version") != SCHEMA_VERSION:
            raise WorkspaceError(
                f"{root / MANIFEST}: workspace schema version {m.get('schema_version')} is not "
                f"{SCHEMA_VERSION}; re-run `rmbuild ingest --force`"
            )
        return ws

    @property
    def manifest(self) -> dict[str, Any]:
        try:
            return json.loads((self.root / MANIFEST).read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise WorkspaceError(f"{self.root / MANIFEST}: unreadable manifest ({e})") from None

    def has(self, stage: str) -> bool:
        return stage in self.manifest.get("stages", {}) and (self.root / STAGE_DIRS[stage]).is_dir()

    def require(self, stage: str) -> None:
        """Raise WorkspaceError naming the command to run when ``stage`` has no outputs here."""
        if not self.has(stage):
            raise WorkspaceError(
                f"workspace {self.root} has no {stage} outputs; run `rmbuild {STAGE_COMMANDS[stage]} "
                f"-w {self.root}` first"
            )

    def check_can_write(self, stage: str, force: bool) -> None:
        """Refuse to replace ``stage``'s existing outputs unless ``force``."""
        if not force and (self.root / STAGE_DIRS[stage]).exists():
            raise WorkspaceError(
                f"{self.root / STAGE_DIRS[stage]} already holds {STAGE_COMMANDS[stage]} outputs; "
                "pass --force to replace them"
            )

    def path(self, key: str) -> Path:
        return self.root / ARTEFACTS[key]

    def exists(self, key: str) -> bool:
        return self.path(key).exists()

    def report_path(self, stage: str) -> Path:
        return self.root / "reports" / f"{stage}.json"

    # ------------------------------------------------------------------ writing a stage
    @contextlib.contextmanager
    def writing(self, stage: str) -> Iterator[StageWriter]:
        """Write ``stage``'s directory as a whole; the report and manifest are updated afterwards."""
        if stage == "ingest":
            raise ValueError("ingest creates the workspace: use Workspace.create")
        target = self.root / STAGE_DIRS[stage]
        with replacing_dir(target) as tmp_dir:
            writer = StageWriter(stage, tmp_dir)
            yield writer
        writer.stage_dir = target
        manifest = self.manifest
        _record_stage(self.root, manifest, writer)
        write_json_atomic(self.root / MANIFEST, manifest)

    # ------------------------------------------------------------------ reading
    def read_table(self, key: str) -> pd.DataFrame:
        p = self.path(key)
        try:
            return pd.read_parquet(p)
        except FileNotFoundError:
            stage = next(s for s, d in STAGE_DIRS.items() if ARTEFACTS[key].startswith(d + "/"))
            self.require(stage)
            raise WorkspaceError(
                f"{p}: missing from the workspace; re-run `rmbuild {STAGE_COMMANDS[stage]}`"
            ) from None
        except Exception as e:  # pyarrow raises several types for corrupt files
            raise WorkspaceError(f"{p}: unreadable Parquet ({type(e).__name__}: {e})") from None

    def read_json(self, key: str) -> Any:
        p = self.path(key)
        try:
            return json.loads(p.read_text())
        except FileNotFoundError:
            raise WorkspaceError(f"{p}: missing from the workspace") from None
        except json.JSONDecodeError as e:
            raise WorkspaceError(f"{p}: invalid JSON ({e})") from None

    def read_report(self, stage: str) -> dict | None:
        p = self.report_path(stage)
        return json.loads(p.read_text()) if p.is_file() else None

    def read_dataset(self) -> Dataset:
        self.require("ingest")
        truth_poses = self.read_table("data.truth_poses") if self.exists("data.truth_poses") else None
        truth_aps = self.read_table("data.truth_aps") if self.exists("data.truth_aps") else None
        venue = self.read_json("data.venue") if self.exists("data.venue") else None
        truth_extra = {
            k.removeprefix("data.truth_"): self.read_table(k)
            for k in ("data.truth_walks", "data.truth_devices", "data.truth_users", "data.truth_landmarks")
            if self.exists(k)
        }
        return Dataset(
            walks=self.read_table("data.walks"),
            poses=self.read_table("data.poses"),
            wifi=self.read_table("data.wifi"),
            fixes=self.read_table("data.fixes"),
            truth_poses=truth_poses,
            truth_aps=truth_aps,
            venue=venue,
            extra={"truth": truth_extra},
        )

    def read_fingerprints(self) -> Fingerprints:
        self.require("ingest")
        return Fingerprints.from_long(self.read_table("data.fingerprints"))


def _record_stage(root: Path, manifest: dict, writer: StageWriter) -> None:
    """Write the stage's report and record its files with checksums in ``manifest``."""
    files = {}
    if writer.stage_dir.is_dir():
        for p in sorted(writer.stage_dir.rglob("*")):
            if p.is_file():
                rel = Path(STAGE_DIRS[writer.stage]) / p.relative_to(writer.stage_dir)
                files[str(rel)] = _sha256(p)
    report_rel = f"reports/{writer.stage}.json"
    write_json_atomic(root / report_rel, clean_json(writer.report))
    manifest.setdefault("stages", {})[writer.stage] = {
        "completed_utc": _now(),
        "rmbuild_version": __version__,
        "report": report_rel,
        "files": files,
    }


def write_dataset(writer: StageWriter, ds: Dataset, fp: Fingerprints) -> None:
    """Write everything ingest produced (the ``data/`` directory)."""
    writer.table("data.walks", ds.walks)
    writer.table("data.poses", ds.poses)
    writer.table("data.wifi", ds.wifi)
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


def check_output_dir(path: Path, force: bool) -> None:
    """Refuse to write into an existing non-empty directory without ``force`` (for simulate's OUT_DIR)."""
    if path.exists() and (not path.is_dir() or any(path.iterdir())) and not force:
        raise InputError(f"{path} already exists and is not empty; pass --force to replace it")
