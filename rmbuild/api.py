"""rmbuild from Python (notebooks, scripts): read a finished workspace and use its radio map.

Everything here reads; nothing writes into the workspace. Each call takes the workspace's shared lock
for its reads, so it never sees a stage half replaced, and checks every file against the checksums its
stage recorded. docs/api.md walks through an example (the tests run it)::

    from rmbuild import api

    ws = api.open_workspace("ws")
    rm = ws.radio_map()                       # RadioMap: cells x APs, reference nodes, histograms
    walks = ws.walks()                        # optimised poses, one row per step, tidy
    new = api.read_walks(["new_walks/"], ws)  # new data in memory, read like ingest reads
    table = api.localize(rm, new, "knn")      # one row per scan: x_m, y_m, uncertainty_m (+ error_m)

Lower-level pieces are public too: :func:`fit_localizer` returns a fitted localizer of the registry
(``.predict(query)``), :func:`scans` builds the :class:`~rmbuild.localize.base.Query` it takes.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pandas as pd

from rmbuild.config import EvaluateConfig, IngestConfig, MapConfig, PdrConfig
from rmbuild.errors import WorkspaceError
from rmbuild.io.lock import workspace_lock
from rmbuild.io.workspace import Workspace
from rmbuild.localize.base import Localizer, Query
from rmbuild.radiomap.build import RadioMap
from rmbuild.types import Dataset

__all__ = [
    "MapWorkspace", "RadioMap", "Query", "Dataset", "open_workspace", "read_walks", "scans", "fit_localizer",
    "localize", "localizer_names",
]


class MapWorkspace:
    """A workspace opened for reading (:func:`open_workspace`)."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)

    @contextmanager
    def _reading(self) -> Iterator[Workspace]:
        if not self.root.is_dir():
            raise WorkspaceError(f"{self.root} is not an rmbuild workspace (no such directory)")
        with workspace_lock(self.root, "api", exclusive=False):
            yield Workspace.open(self.root)

    def stages(self) -> dict[str, bool]:
        """Which stages have outputs here: {"ingest": True, "optimize": True, "map": False, ...}."""
        from rmbuild.io.workspace import STAGE_DIRS

        with self._reading() as ws:
            return {s: ws.has(s) for s in STAGE_DIRS}

    def report(self, stage: str) -> dict | None:
        """A stage's report.json ("ingest", "optimize", "map", "evaluate"); None when it has not run."""
        with self._reading() as ws:
            return ws.read_report(stage)

    def dataset(self) -> Dataset:
        """What ingest stored: walks, per-step poses (each walk in its own frame), Wi-Fi readings, fixes, truth."""
        with self._reading() as ws:
            return ws.read_dataset()

    def radio_map(self) -> RadioMap:
        """The radio map export-map wrote, as one in-memory :class:`RadioMap`."""
        from rmbuild.io.map_store import read_radio_map

        with self._reading() as ws:
            return read_radio_map(ws)

    def map_config(self) -> MapConfig:
        """The [map] config export-map ran with."""
        from rmbuild.io.map_store import read_map_config

        with self._reading() as ws:
            return read_map_config(ws)

    def walks(self) -> pd.DataFrame:
        """The optimised walks, one row per step: walk_id, step, node, t_s, x_m, y_m, heading_rad (the
        optimised frame: the map's unless export-map was given --anchors), linked (placed by Wi-Fi), the
        walk's device_id, user_id and role, and x_true_m, y_true_m where the input had true poses."""
        with self._reading() as ws:
            ws.require("optimize")
            poses = ws.read_table("optimize.poses")
            meta = ws.read_table("data.walks")
            truth = ws.read_table("data.truth_poses") if ws.exists("data.truth_poses") else None
        out = poses.copy()
        out.insert(2, "node", np.arange(len(out), dtype=np.int64))
        cols = [c for c in ("walk_id", "device_id", "user_id", "role") if c in meta]
        out = out.merge(meta[cols].astype({"walk_id": str}), on="walk_id", how="left", validate="many_to_one")
        if truth is not None and len(truth) == len(out):
            out["x_true_m"] = truth["x_m"].to_numpy(dtype=float)
            out["y_true_m"] = truth["y_m"].to_numpy(dtype=float)
        return out

    def scans(self, walk_ids: Sequence[str], radio_map: RadioMap | None = None) -> Query:
        """The scans of workspace walks ``walk_ids`` as a Query (columns in ``radio_map``'s AP order)."""
        ds = self.dataset()
        known = set(ds.walks["walk_id"].astype(str))
        unknown = [w for w in walk_ids if str(w) not in known]
        if unknown:
            from rmbuild.errors import InputError

            raise InputError(f"unknown walk {unknown[0]!r}", str(self.root))
        return scans(ds, radio_map, [str(w) for w in walk_ids])


def open_workspace(root: str | Path, floor: str | None = None) -> MapWorkspace:
    """Open an existing workspace for reading (a building's: its floor ``floor``); WorkspaceError when
    ``root`` is not one."""
    from rmbuild.stages.localize import one_floor

    ws = MapWorkspace(one_floor(root, floor))
    with ws._reading():
        pass
    return ws


def read_walks(inputs: Sequence[str | Path], workspace: MapWorkspace | None = None, fmt: str | None = None,
               ) -> Dataset:
    """Read new walks (any ingest format) or bare scans (a wifi table without poses) into memory.

    With ``workspace``, walks go through the [ingest] and [pdr] config its own walks were read with;
    otherwise the defaults. Bare scans come back with an empty ``poses`` table (readings' node -1).
    """
    from rmbuild.stages.localize import ingest_configs, read_input

    if workspace is not None:
        with workspace._reading() as ws:
            ingest_cfg, pdr_cfg = ingest_configs(ws)
    else:
        ingest_cfg, pdr_cfg = IngestConfig(), PdrConfig()
    return read_input(list(inputs), fmt, ingest_cfg, pdr_cfg).dataset


def scans(dataset: Dataset, radio_map: RadioMap | None = None, walk_ids: Sequence[str] | None = None) -> Query:
    """Every Wi-Fi scan (readings sharing walk and time) of ``dataset`` as a Query, columns in the map's AP
    order, the scans of a phone the map lists in ``device_offsets_db`` in the map's scale (its offset taken
    off); walks with poses carry their PDR steps (for SLAC, PFL and the *_kf localizers)."""
    from rmbuild.radiomap import devices

    ids = [str(w) for w in (walk_ids if walk_ids is not None else dataset.walk_ids())]
    bssids = None if radio_map is None else radio_map.bssids
    if radio_map is not None:
        dataset = devices.corrected(dataset, radio_map.device_offsets_db)
    q = Query.from_dataset(dataset, ids, bssids, unit="scan")
    if len(dataset.poses) == 0:
        q.steps = None
    return q


def fit_localizer(name: str, radio_map: RadioMap, config: EvaluateConfig | None = None) -> Localizer:
    """A registered localizer (:func:`localizer_names`) configured by ``config`` (its [evaluate] settings;
    defaults when None) and fitted on ``radio_map``: call ``.predict(query)`` -> (n, 2) metres."""
    from rmbuild.localize.base import make_localizer

    return make_localizer(name, config).fit(radio_map)


def localize(radio_map: RadioMap, data: Dataset | Query, localizer: str = "knn",
             config: EvaluateConfig | None = None, workspace: MapWorkspace | None = None) -> pd.DataFrame:
    """Localize every scan of ``data`` (a Dataset from :func:`read_walks`, or a Query) against the map.

    One row per scan: walk_id, t_s, x_m, y_m (map frame), uncertainty_m (the spread of the scan's
    signal-space neighbours around the estimate), n_aps (map APs heard). For a Dataset with ground truth
    (truth poses or fixes, building frame) also x_true_m, y_true_m, error_m, in the map's frame: as they
    are when the map is in the building frame, else through ``workspace`` (the map's workspace: the SE(2)
    from its optimised positions to its own ground truth, as `rmbuild localize` does); without it, a map
    in a walk's frame gets no error columns.
    """
    from rmbuild.localize.apply import localize_query, positions_table

    query = data if isinstance(data, Query) else scans(data, radio_map)
    res = localize_query(radio_map, query, localizer, config)
    ref = None
    if isinstance(data, Dataset):
        from rmbuild.evaluate.localization import query_reference_xy

        ref = query_reference_xy(data, query)
        to_map = (lambda xy: xy) if radio_map.frame == "building" else None
        if to_map is None and workspace is not None:
            from rmbuild.stages.localize import truth_to_map_frame

            with workspace._reading() as ws:
                to_map, _ = truth_to_map_frame(ws, radio_map)
        ref = to_map(ref) if (to_map is not None and np.isfinite(ref).any()) else None
    return positions_table(query, res, ref)


def localizer_names() -> list[str]:
    """The registered localizers (rmbuild.localize.registry)."""
    from rmbuild.localize.registry import localizer_names as names

    return names()
