"""`rmbuild evaluate` on a building: every floor as on its own, then which floor each test scan is on.

The floor of each test scan is classified against the fingerprints of every floor's map walks
(:mod:`rmbuild.localize.floor`); the building report gives the floor hit rate, the x, y errors of the
correctly classified scans, and the combined error of the IPIN competition and the Kaggle Indoor Location &
Navigation challenge: x, y error + ``floor_penalty_m`` per floor off. The x, y part of a scan classified on
the wrong floor is its estimate on its true floor's map (a lower bound of what the wrong floor's map gives).

A floor that cannot be scored (one walk, no ground truth, ...) is skipped with its reason, named in the
building report (``building`` → ``skipped_floors``) and the printed table; the others are scored. Only when
no floor can be scored is the building an error.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from rmbuild.config import EvaluateConfig
from rmbuild.errors import ConfigError, InputError, WorkspaceError
from rmbuild.evaluate.localization import error_stats, split_walks
from rmbuild.io.workspace import Workspace, building_floors, floor_levels
from rmbuild.localize.base import Query
from rmbuild.localize.floor import classify_floors
from rmbuild.stages.building import run_floors
from rmbuild.types import Dataset, Fingerprints


def run_building(workspace: str | Path, floors: dict[str, Path], cfg: EvaluateConfig,
                 fn: Callable[[Path], tuple[dict, str]]) -> tuple[dict, str]:
    """Evaluate ``floors`` with ``fn`` (the single-floor stage), then classify floors over the building; a
    floor that cannot be scored is skipped (an InputError naming the floors when none can be)."""
    tables: dict[str, str] = {}
    skipped: dict[str, str] = {}

    def one(name: str, path: Path) -> dict:
        try:
            report, tables[name] = fn(path)
        except ConfigError:
            raise
        except InputError as e:  # said of the floor's workspace: the floor's name says that here
            skipped[name] = e.problem if e.where == str(path) else str(e)
            return {}
        return report

    def totals(root: Path, reports: dict[str, dict]) -> dict:
        scored = {n: r for n, r in reports.items() if n not in skipped}
        out = floor_totals(root, scored, cfg) if scored else {}
        return {**out, "skipped_floors": dict(skipped)} if skipped else out

    report = run_floors(workspace, "evaluate", floors, one, totals=totals)
    if skipped and not tables:
        raise InputError("no floor could be evaluated: " + "; ".join(f"{n}: {why}" for n, why in skipped.items()))
    text = "\n".join(f"floor {n}:\n{t}" for n, t in tables.items())
    text += "".join(f"\nfloor {n} skipped: {why}" for n, why in skipped.items())
    return report, text + "\n" + building_table(report["building"])


def floor_totals(root: Path, reports: dict[str, dict], cfg: EvaluateConfig) -> dict:
    """The building's floor classification and combined errors over the floors in ``reports``."""
    floors = building_floors(root) or {}
    levels = floor_levels(root)
    data = {n: _floor_data(p) for n, p in floors.items()}
    bssids = np.array(sorted(set().union(*(set(map(str, fp.bssids)) for _, fp in data.values()))), dtype=object)
    refs = [_refs(ds, fp, reports[n]["map_walks"] if n in reports else _map_walks(ds, cfg), bssids)
            for n, (ds, fp) in data.items()]
    names = list(floors)
    rows = []
    for n, rep in reports.items():
        ds, _ = data[n]
        q = Query.from_dataset(ds, rep["test_walks"], bssids, unit=cfg.query)
        pred, alone = classify_floors(refs, q.rss_dbm, q.walk_id, q.t_s)
        tracks = Workspace.open(floors[n]).read_table("evaluate.tracks")
        rows.append(_scored(n, names, pred, alone, q, tracks, levels))
    if not rows:
        return {}
    scans = pd.concat(rows, ignore_index=True)
    return {"floor_classification": _classification(scans), "floor_penalty_m": cfg.floor_penalty_m,
            "maps": _combined(scans, cfg.floor_penalty_m)}


def _map_walks(ds: Dataset, cfg: EvaluateConfig) -> list[str]:
    """The walks a floor that was not evaluated offers the floor classification: its map walks, or every
    walk when it cannot be split (a single walk)."""
    try:
        return split_walks(ds, cfg)[0]
    except InputError:
        return [str(w) for w in ds.walks["walk_id"]]


def _floor_data(path: Path) -> tuple[Dataset, Fingerprints]:
    ws = Workspace.open(path)
    return ws.read_dataset(), ws.read_fingerprints()


def _refs(ds: Dataset, fp: Fingerprints, map_walks: list[str], bssids: np.ndarray) -> np.ndarray:
    """The map walks' fingerprints, columns in the order ``bssids``."""
    walk_of_node = ds.poses["walk_id"].astype(str).to_numpy()
    keep = np.isin(walk_of_node[fp.node], list(map(str, map_walks)))
    col = pd.Index(bssids).get_indexer(fp.bssids.astype(str))
    out = np.full((int(keep.sum()), len(bssids)), np.nan, dtype=np.float32)
    out[:, col] = fp.rss_dbm[keep]
    return out


def _scored(floor: str, names: list[str], pred: np.ndarray, alone: np.ndarray, q: Query, tracks: pd.DataFrame,
            levels: dict[str, int | None]) -> pd.DataFrame:
    """One row per (test scan, map, localizer): floor truth, classification, x, y error, floors off."""
    scans = pd.DataFrame({"walk_id": q.walk_id.astype(str), "t_s": q.t_s, "floor": floor,
                          "pred": [names[i] for i in pred], "pred_alone": [names[i] for i in alone]})
    tr = tracks[["map", "localizer", "walk_id", "t_s", "error_m"]].astype({"walk_id": str})
    out = tr.merge(scans, on=["walk_id", "t_s"], how="left", validate="many_to_one")
    if out["pred"].isna().any():
        raise WorkspaceError(f"floor {floor}: evaluate/tracks.parquet does not match the test scans; re-run "
                             "`rmbuild evaluate --force`")
    out["floors_off"] = [_floors_off(t, p, levels) for t, p in zip(out["floor"], out["pred"], strict=True)]
    return out


def _floors_off(true: str, pred: str, levels: dict[str, int | None]) -> int:
    """Floors between the true and the classified floor: by level when both have one, else 0 or 1."""
    a, b = levels.get(true), levels.get(pred)
    return abs(a - b) if a is not None and b is not None else int(true != pred)


def _classification(rows: pd.DataFrame) -> dict:
    """Hit rates over the test scans (each scan once), per floor and overall, and the confusion counts."""
    scans = rows.drop_duplicates(["floor", "walk_id", "t_s"])
    hit = scans["floor"] == scans["pred"]
    per = {f: {"hit_rate": float(hit[g.index].mean()), "n": len(g)} for f, g in scans.groupby("floor", sort=False)}
    conf = {f: {str(k): int(v) for k, v in g["pred"].value_counts().items()} for f, g in scans.groupby("floor")}
    alone = scans["floor"] == scans["pred_alone"]
    return {"hit_rate": float(hit.mean()), "hit_rate_single_scan": float(alone.mean()), "n": len(scans),
            "per_floor": per, "confusion": conf}


def _combined(rows: pd.DataFrame, penalty_m: float) -> dict:
    out: dict[str, dict] = {}
    for (m, loc), g in rows.groupby(["map", "localizer"], sort=False):
        err = g["error_m"].to_numpy(float)
        hit = (g["floor"] == g["pred"]).to_numpy()
        out.setdefault(str(m), {})[str(loc)] = {
            "xy_all_scans": error_stats(err),
            "xy_correct_floor": error_stats(err[hit]),
            "combined": error_stats(err + penalty_m * g["floors_off"].to_numpy(float)),
        }
    return out


def building_table(b: dict) -> str:
    """A short text table of the building's floor hit rate and combined errors."""
    fc = b.get("floor_classification")
    if not fc:
        return "building: no floor classification (no floor evaluated)"
    lines = [f"building: floor hit rate {fc['hit_rate']:.1%} of {fc['n']} test scans (single scans "
             f"{fc['hit_rate_single_scan']:.1%}); " + ", ".join(f"{f} {v['hit_rate']:.1%}"
                                                                for f, v in fc["per_floor"].items()),
             f"{'map':10s} {'localizer':10s} {'xy mean':>8s} {'xy p75':>7s} {'ok-floor mean':>13s} "
             f"{'combined mean':>13s} {'combined p75':>12s}   (m; combined: +{b['floor_penalty_m']:g} m per floor off)"]
    for m, d in b["maps"].items():
        for loc, s in d.items():
            a, c, k = s["xy_all_scans"], s["xy_correct_floor"], s["combined"]
            lines.append(f"{m:10s} {loc:10s} {_f(a['mean']):>8s} {_f(a['p75']):>7s} {_f(c['mean']):>13s} "
                         f"{_f(k['mean']):>13s} {_f(k['p75']):>12s}")
    return "\n".join(lines)


def _f(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.2f}"
