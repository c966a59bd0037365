"""`rmbuild ingest --append`: add new walks to an existing workspace's data without touching its walks.

The new input is read with the [ingest] and [pdr] config the workspace was ingested with (so old and new
walks are treated alike), validated the same way, and its walks follow the old ones: old node ids stay what
they were, new ones continue after them. A walk id already in the workspace is an error. The data directory
is replaced in one commit; the outputs of later stages stay on disk but are stale (their records name the
ingest they read), so the stages after ingest refuse or warn until they are re-run.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import pandas as pd

from rmbuild.errors import InputError
from rmbuild.io.workspace import Workspace, building_floors, write_dataset
from rmbuild.stages.common import Progress, ensure_progress
from rmbuild.types import Dataset, Fingerprints

log = logging.getLogger(__name__)

#: a new walk whose Wi-Fi readings are less than this share of access points the workspace's walks have seen
#: looks foreign (another venue, another floor): ingest --append warns
FOREIGN_KNOWN_SHARE = 0.3
#: report keys that are counts over the walks (summed over the old and the new part)
COUNT_KEYS = ("walks", "poses", "readings", "readings_dropped_outside_walk", "scans", "fixes")


def run(inputs: list[str | Path], workspace: str | Path, fmt: str | None = None,
        progress: Progress | None = None) -> dict:
    """Append the walks of ``inputs`` to ``workspace``; returns the new ingest report."""
    from rmbuild.stages.ingest import plan_summary
    from rmbuild.stages.localize import ingest_configs, read_input, unpinned_origin_warning

    if building_floors(workspace) is not None:
        raise InputError("--append adds walks to one floor: ingest --append into the floor's workspace "
                         "(WORKSPACE/floors/NAME)", str(workspace))
    progress = ensure_progress(progress)
    t0 = time.perf_counter()
    ws = Workspace.open(workspace)
    icfg, pcfg = ingest_configs(ws)
    progress.phase("reading the new input")
    new = read_input(inputs, fmt, icfg, pcfg)
    unpinned = unpinned_origin_warning(icfg, new)
    if unpinned:
        log.warning(unpinned)
    if new.kind != "walks":
        raise InputError("--append needs walks (poses), not bare scans", ", ".join(map(str, inputs)))
    with ws.replacing_ingest() as w:
        old = ws.read_dataset()
        _check_new_ids(old, new.dataset, inputs)
        progress.phase("merging")
        ds = merge(old, new.dataset)
        fp = Fingerprints.from_readings(ds.wifi)
        write_dataset(w, ds, fp)
        plan = ws.read_json("data.floorplan") if ws.exists("data.floorplan") else None
        if plan is not None:  # the floor's plan stays with it, checked again against all the fixes
            w.json("data.floorplan", plan)
            if ws.exists("data.floor_image"):
                w.binary("data.floor_image", ws.read_bytes("data.floor_image"))
        w.config(ws.read_config_text("ingest") or "")
        report = _report(ws.read_report("ingest") or {}, ds, fp, new.dataset, inputs, new.reader)
        report["appended"][-1]["shared_aps"], foreign = shared_aps(old, new.dataset)
        if foreign:
            log.warning(foreign)
            report.setdefault("warnings", []).append(foreign)
        if plan is not None:
            said: list[str] = []
            report["floorplan"] = plan_summary(plan, ds, said)
            known = report.setdefault("warnings", [])
            known += [x for x in said if x not in known]
        report["time_s"] = {"total": round(time.perf_counter() - t0, 3)}
        w.report = report
    return report


def shared_aps(old: Dataset, new: Dataset) -> tuple[dict, str | None]:
    """How much the new walks' Wi-Fi has in common with the workspace's: per new walk, the share of its
    readings of access points (BSSIDs) the old walks have seen; and a warning naming the new walks below
    FOREIGN_KNOWN_SHARE (another venue or floor?), None when there is none or either side has no Wi-Fi."""
    known = set(old.wifi["bssid"].astype(str))
    if not known or not len(new.wifi):
        return {"compared": False}, None
    seen = new.wifi["bssid"].astype(str).isin(known)
    per_walk = seen.groupby(new.wifi["walk_id"].astype(str), sort=False).mean()
    low = per_walk[per_walk < FOREIGN_KNOWN_SHARE]
    figures = {"compared": True, "new_aps": int(new.wifi["bssid"].nunique()),
               "new_aps_known": int(new.wifi.loc[seen, "bssid"].nunique()), "readings_known_share":
               round(float(seen.mean()), 3), "walks_below_share": len(low)}
    if not len(low):
        return figures, None
    names = ", ".join(low.index[:3]) + (", ..." if len(low) > 3 else "")
    return figures, (f"{len(low)} of {len(per_walk)} new walk(s) ({names}) hear mostly access points this workspace "
                     f"has never seen (under {FOREIGN_KNOWN_SHARE:.0%} of their Wi-Fi readings; all new walks: "
                     f"{seen.mean():.0%}, {figures['new_aps_known']} of {figures['new_aps']} access points known): "
                     "another venue or floor? (compared: the BSSIDs of the new walks' readings against the "
                     "workspace's)")


def _check_new_ids(old: Dataset, new: Dataset, inputs: list[str | Path]) -> None:
    dup = sorted(set(old.walks["walk_id"].astype(str)) & set(new.walks["walk_id"].astype(str)))
    if dup:
        raise InputError(f"walk {dup[0]!r} is already in the workspace ({len(dup)} duplicate walk id(s)); "
                         "--append only adds new walks", ", ".join(map(str, inputs)))
    if not len(new.walks):
        raise InputError("no walks with poses in the new input", ", ".join(map(str, inputs)))


def merge(old: Dataset, new: Dataset) -> Dataset:
    """``old`` then ``new``: poses (node ids) of the new walks continue after the old ones."""
    off = len(old.poses)
    wifi = new.wifi.copy()
    wifi["node"] = wifi["node"] + off
    truth = None
    if old.truth_poses is not None and new.truth_poses is not None:
        truth = _cat(old.truth_poses, new.truth_poses)
    elif old.truth_poses is not None or new.truth_poses is not None:
        log.warning("--append: only one of the old and new parts has true poses; the merged data keeps none")
    aps = old.truth_aps if old.truth_aps is not None else new.truth_aps
    a, b = old.extra.get("truth", {}), new.extra.get("truth", {})
    extra = {k: _cat(a[k], b[k]).drop_duplicates(ignore_index=True) if k in a and k in b else a.get(k, b.get(k))
             for k in dict.fromkeys([*a, *b])}
    ble = old.ble
    if new.ble is not None:
        nb = new.ble.assign(node=new.ble["node"] + off)
        ble = nb.reset_index(drop=True) if old.ble is None else _cat(old.ble, nb)
    return Dataset(walks=_cat(old.walks, new.walks), poses=_cat(old.poses, new.poses),
                   wifi=_cat(old.wifi, wifi), fixes=_cat(old.fixes, new.fixes), truth_poses=truth,
                   truth_aps=aps, venue=old.venue if old.venue is not None else new.venue,
                   extra={"truth": extra}, ble=ble)


def _cat(a: pd.DataFrame, b: pd.DataFrame) -> pd.DataFrame:
    """Rows of ``a`` then ``b`` with ``a``'s columns first (a column one side lacks is left empty)."""
    if not len(b):
        return a.reset_index(drop=True)
    if not len(a):
        return b.reset_index(drop=True)
    return pd.concat([a, b], ignore_index=True)[list(dict.fromkeys([*a.columns, *b.columns]))]


def _report(old: dict[str, Any], ds: Dataset, fp: Fingerprints, new: Dataset, inputs: list[str | Path],
            reader: str) -> dict:
    rep = dict(old)
    rep.update({
        "walks": len(ds.walks), "poses": len(ds.poses), "readings": len(ds.wifi),
        "scans": int(ds.wifi.groupby(["walk_id", "t_s"], sort=False).ngroups),
        "nodes_with_fingerprint": len(fp), "aps": len(fp.bssids), "fixes": len(ds.fixes),
        "has_truth_poses": ds.truth_poses is not None,
    })
    if ds.ble is not None:
        rep["ble"] = {**rep.get("ble", {}), "readings": len(ds.ble), "beacons": int(ds.ble["bssid"].nunique())}
    appended = list(old.get("appended", []))
    appended.append({"inputs": [str(p) for p in inputs], "format": reader, "walks": len(new.walks),
                     "poses": len(new.poses), "walk_ids": [str(w) for w in new.walks["walk_id"]]})
    rep["appended"] = appended
    return rep
