"""`rmbuild localize`: localize new walks or bare scans against a workspace's radio map.

The inputs are read with the ingest readers into memory (the workspace is never written): walks go
through the same PDR and attachment as the map's walks (the workspace's [ingest] and [pdr] config), and
every scan becomes one query, as `evaluate` makes them. The map is the one export-map wrote. Positions are
in the map's frame; when the input has ground truth (truth poses, or fixes), its positions are brought
into the map's frame and each scan's error is written beside its estimate:

* map in the building frame (optimize used anchors or the floor plan): as they are;
* map in a walk's frame: by the one SE(2) that maps the workspace's optimised node positions onto its
  own reference positions (fitted on every placed node, as `evaluate` fits its gauge), inverted;
* otherwise (no ground truth in the workspace) errors are not computed, and the report says why.

``hold_out``: the input walks are walks of the workspace (the ones `evaluate` tests, say). The exported map
is then not used: the map is `evaluate`'s "built" map of the workspace's *other* walks
(:func:`rmbuild.evaluate.localization.evaluation_maps`: the optimised positions of those walks, the gauge's
SE(2) to the truth, the same grid and AP list), so the scans of the given walks are localized and scored
exactly as `evaluate --test-walks` scores them. Positions are then in the frame evaluate scores in (the
building's, or the truth's after the SE(2)).
"""

from __future__ import annotations

import io
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from rmbuild.config import EvaluateConfig, IngestConfig, PdrConfig, load_stage_config_text
from rmbuild.errors import InputError
from rmbuild.io.workspace import Workspace, check_output_file
from rmbuild.limits import MAX_QUERIES, MAX_QUERY_CELLS
from rmbuild.radiomap import devices
from rmbuild.radiomap.build import RadioMap
from rmbuild.stages.common import Progress, ensure_progress, locked_workspace
from rmbuild.types import Dataset

log = logging.getLogger(__name__)

#: output suffix -> table format
OUTPUT_FORMATS = {".csv": "csv", ".parquet": "parquet", ".geojson": "geojson"}


def check_query_size(n_queries: int, n_aps: int, inputs: list[str | Path]) -> None:
    """At most :data:`MAX_QUERIES` queries, and their table (scans × the map's APs, dense) at most
    :data:`MAX_QUERY_CELLS` cells."""
    if n_queries > MAX_QUERIES:
        raise InputError(f"{n_queries:,} scans: at most {MAX_QUERIES:,} in one run (localize the input in parts)",
                         ", ".join(map(str, inputs)))
    if n_queries * n_aps > MAX_QUERY_CELLS:
        raise InputError(f"{n_queries:,} scans against a map of {n_aps:,} APs: a query table of {n_queries * n_aps:,} "
                         f"cells, at most {MAX_QUERY_CELLS:,} in one run (localize the input in parts)",
                         ", ".join(map(str, inputs)))


@dataclass
class NewInput:
    """New data read into memory: a Dataset (poses empty for bare scans) and what was read."""

    dataset: Dataset
    kind: str  # "walks" or "scans"
    reader: str
    n_files: int


def run(
    workspace: str | Path,
    inputs: list[str | Path],
    out: str | Path,
    cfg: EvaluateConfig,
    localizer: str | None = None,
    fmt: str | None = None,
    force: bool = False,
    progress: Progress | None = None,
    floor: str | None = None,
    hold_out: bool = False,
) -> dict:
    """Localize ``inputs`` against ``workspace``'s map (a building's: the map of ``floor``), write per-scan
    positions to ``out`` (CSV or Parquet by suffix); returns the report (errors under "errors" when the
    input has ground truth). ``out`` ending in .geojson: a FeatureCollection, when the map is georeferenced
    (:mod:`rmbuild.stages.localize_geojson`). ``hold_out``: against evaluate's built map of the workspace's
    other walks (module docstring)."""
    from rmbuild.evaluate.localization import error_stats, query_reference_xy
    from rmbuild.localize.apply import localize_query, positions_table
    from rmbuild.localize.base import Query, localizer_class

    workspace = one_floor(workspace, floor)
    out = check_output(out, force)
    name = localizer or cfg.localizers[0]
    localizer_class(name)  # an unknown name fails before anything is read
    progress = ensure_progress(progress)
    t0 = time.perf_counter()
    with locked_workspace(workspace, "localize", exclusive=False) as ws:
        if not hold_out:
            rm = _read_map(ws)
            geo = _georef(ws, rm, out, floor)
        progress.phase("reading the input")
        icfg, pcfg = ingest_configs(ws)
        new = read_input(inputs, fmt, icfg, pcfg)
        ds = new.dataset
        unpinned = unpinned_origin_warning(icfg, new)
        if hold_out:
            progress.phase("building the map of the other walks")
            rm, hold_note = held_out_map(ws, ds)
            geo = _georef(ws, rm, out, floor)
        ds = devices.corrected(ds, rm.device_offsets_db)  # the map's phones' offsets on their queries too
        unit = cfg.query if new.kind == "walks" else "scan"
        check_query_size(Query.count(ds, ds.walk_ids(), unit), len(rm.bssids), inputs)
        query = Query.from_dataset(ds, ds.walk_ids(), rm.bssids, unit=unit)
        if new.kind == "scans":
            query.steps = None
        if len(query) == 0:
            raise InputError("the input has no Wi-Fi scans", ", ".join(map(str, inputs)))
        ref = query_reference_xy(ds, query)
        has_truth = bool(np.isfinite(ref).all(axis=1).any())
        if hold_out:
            to_map, frame_note = ((lambda xy: xy), hold_note) if rm.frame == "building" else (None, hold_note)
        else:
            to_map, frame_note = truth_to_map_frame(ws, rm) if has_truth else (None, "")
    warnings = ([] if hold_out else _overlap_warning(ds, rm)) + ([unpinned] if unpinned else [])
    for w in warnings:
        log.warning(w)
    progress.phase(f"localizing {len(query)} scans with {name}")
    res = localize_query(rm, query, name, cfg)
    if (outside := _outside_warning(res)) is not None:
        log.warning(outside)
        warnings.append(outside)
    table = positions_table(query, res, to_map(ref) if to_map is not None else None)
    write_table(table, out, geo)
    report = {
        "stage": "localize", "workspace": str(ws.root), "inputs": [str(p) for p in inputs], "output": str(out),
        "input_kind": new.kind, "format": new.reader, "walks": len(ds.walks), "scans": len(query),
        "localizer": name, "map_frame": rm.frame, "map_aps": len(rm.bssids), "hold_out": hold_out,
        "scans_without_map_aps": int((res.n_aps == 0).sum()),
        "unlocalized": int((~np.isfinite(res.xy).all(axis=1)).sum()),
        "uncertainty_m_median": _median(res.uncertainty_m), "localizer_summary": res.summary,
        "outside_map": {"scans": int(res.outside_map.sum()), "threshold_db": res.outside_db},
        "truth": {"present": has_truth, "frame": frame_note if has_truth else None},
        "errors": error_stats(table["error_m"].to_numpy()) if "error_m" in table else None,
        "warnings": warnings, "time_s": round(time.perf_counter() - t0, 3),
    }
    return report


def held_out_map(ws: Workspace, new: Dataset) -> tuple[RadioMap, str]:
    """Evaluate's built map of the workspace's walks other than ``new``'s (all of which must be workspace
    walks), and a note on its frame. InputError when an input walk is not one of the workspace's."""
    from rmbuild.evaluate.localization import evaluation_maps
    from rmbuild.io.map_store import read_map_config
    from rmbuild.stages.mapping import built_positions

    ds, fp = ws.read_dataset(), ws.read_fingerprints()
    known = ds.walks["walk_id"].astype(str).tolist()
    given = set(new.walks["walk_id"].astype(str))
    unknown = sorted(given - set(known))
    if unknown:
        raise InputError(f"--hold-out: input walk {unknown[0]!r} is not a walk of the workspace (hold-out "
                         "localizes a workspace's own walks against a map of its other walks)", str(ws.root))
    map_walks = [w for w in known if w not in given]
    if not map_walks:
        raise InputError("--hold-out: every walk of the workspace is in the input: no walks left for the map",
                         str(ws.root))
    map_cfg = read_map_config(ws)
    xy, info = built_positions(ws, ds, map_cfg)
    em = evaluation_maps(devices.corrected(ds, info["device_offsets_db"]), fp, xy, map_walks, info["gauge"], map_cfg)
    em.maps["built"].device_offsets_db = info["device_offsets_db"]
    se2 = em.alignment.get("built_se2")
    if se2:
        note = (f"evaluate's built map of the other {len(map_walks)} walks: SE(2) from their placed nodes to the "
                f"truth (residual RMS {se2['residual_rms_m']:.2f} m), positions in the truth's frame")
    elif em.maps["built"].frame == "building":
        note = f"evaluate's built map of the other {len(map_walks)} walks, in the building frame as placed"
    else:
        note = (f"evaluate's built map of the other {len(map_walks)} walks, in its own frame: the workspace has "
                "no ground truth to relate it to the building's, errors not computed")
    return em.maps["built"], note


def _overlap_warning(ds: Dataset, rm: RadioMap) -> list[str]:
    """A warning when input walks are among the map's own walks (their scans are in the map)."""
    both = sorted(set(ds.walks["walk_id"].astype(str)) & set(map(str, rm.node_walk)))
    if not both:
        return []
    return [f"{len(both)} input walk(s) are among the map's own walks ({', '.join(both[:3])}"
            f"{' ...' if len(both) > 3 else ''}): their scans are in the map, so their errors are optimistic"]


def _outside_warning(res) -> str | None:
    """A warning when scans match the map worse than its own scans match a neighbouring cell: they were
    probably taken where the map has no walks, and their positions are guesses inside the map."""
    n = int(res.outside_map.sum())
    if not n:
        return None
    located = int(np.isfinite(res.xy).all(axis=1).sum())
    return (f"{n} of {located} scans match the map worse than 99% of the map's own scans match a neighbouring "
            f"cell (nearest fingerprint more than {res.outside_db:.1f} dB away): they were probably taken outside "
            "the area the map covers; their positions are guesses inside the map and their uncertainty_m "
            "understates the error (output column outside_map)")


def _median(a: np.ndarray) -> float | None:
    a = a[np.isfinite(a)]
    return float(np.median(a)) if a.size else None


def check_output(out: str | Path, force: bool) -> Path:
    p = Path(out)
    fmt = OUTPUT_FORMATS.get(p.suffix.lower())
    if fmt is None:
        raise InputError(f"output must end in {' or '.join(OUTPUT_FORMATS)}", str(p))
    if not p.parent.is_dir():
        raise InputError("the output's directory does not exist", str(p))
    return check_output_file(p, force, "output")


def _read_map(ws: Workspace) -> RadioMap:
    from rmbuild.io.map_store import read_radio_map

    return read_radio_map(ws)


def ingest_configs(ws: Workspace) -> tuple[IngestConfig, PdrConfig]:
    """The [ingest] and [pdr] config the workspace's walks were read with (defaults when not recorded)."""
    text = ws.read_config_text("ingest")
    if text is None:
        return IngestConfig(), PdrConfig()
    where = str(ws.path("data.config"))
    return load_stage_config_text("ingest", text, where), load_stage_config_text("pdr", text, where)


def unpinned_origin_warning(ingest_cfg: IngestConfig, new: NewInput) -> str | None:
    """A warning when new IPIN logfiles with fixes are read against a workspace that does not record the
    WGS84 origin of its own fixes' frame (ingested before ingest wrote it into the config): the new fixes
    then get a frame of their own."""
    fixes = new.dataset.fixes
    if new.reader != "ipin" or ingest_cfg.ipin.origin_lat_deg is not None or fixes is None or not len(fixes):
        return None
    return ("the workspace does not record the WGS84 origin of its POSI fixes' frame (ingested before rmbuild "
            "wrote it into data/config.toml): the new fixes are put into a frame of their own; re-ingest the "
            "workspace, or set ingest.ipin.origin_lat_deg / origin_lon_deg to the origin its ingest notes name")


def read_input(inputs: list[str | Path], fmt: str | None, ingest_cfg: IngestConfig, pdr_cfg: PdrConfig) -> NewInput:
    """Read walks (any ingest format) or bare scans (rmbuild's schema without poses) into memory."""
    from rmbuild.ingest.core import build_dataset
    from rmbuild.io.formats import choose_reader, expand_inputs
    from rmbuild.io.scans import are_bare_scans, read_bare_scans

    files = expand_inputs(inputs)
    if fmt in (None, "rmbuild") and are_bare_scans(files):
        return NewInput(read_bare_scans(files, ingest_cfg), "scans", "rmbuild", len(files))
    reader = choose_reader(files, fmt)
    raw = reader.read(files, ingest_cfg)
    ds, _, _ = build_dataset(raw, ingest_cfg, source=reader.name, pdr_cfg=pdr_cfg)
    return NewInput(ds, "walks", reader.name, len(files))


def truth_to_map_frame(ws: Workspace, rm: RadioMap) -> tuple[Callable[[np.ndarray], np.ndarray] | None, str]:
    """(function taking building-frame (n, 2) positions into the map's frame, or None; a note saying how)."""
    from rmbuild.evaluate.localization import reference_positions
    from rmbuild.evaluate.trajectory import align_se2
    from rmbuild.io.map_store import read_map_config
    from rmbuild.stages.mapping import built_positions

    if rm.frame == "building":
        return (lambda xy: xy), "building (the map's own frame)"
    ds = ws.read_dataset()
    ref, src = reference_positions(ds)
    if src is None:
        return None, (f"the map is in the frame {rm.frame!r} and the workspace has no ground truth to relate it to "
                      "the building frame: errors not computed")
    xy, _ = built_positions(ws, ds, read_map_config(ws))
    ok = np.isfinite(xy).all(axis=1) & np.isfinite(ref).all(axis=1)
    if ok.sum() < 2:
        return None, "fewer than 2 placed nodes with ground truth in the workspace: errors not computed"
    r, t = align_se2(xy[ok], ref[ok])  # building = r @ map + t
    res = np.hypot(*(xy[ok] @ r.T + t - ref[ok]).T)
    note = (f"SE(2) from the workspace's {int(ok.sum())} placed nodes to their {src} "
            f"(residual RMS {float(np.sqrt((res ** 2).mean())):.2f} m), inverted")
    return (lambda b: (np.asarray(b, dtype=float) - t) @ r), note


def _georef(ws: Workspace, rm: RadioMap, out: Path, floor: str | None):
    """(georeference, floor name) for a .geojson output (an InputError when the map has none), else None."""
    if OUTPUT_FORMATS[out.suffix.lower()] != "geojson":
        return None
    from rmbuild.stages.localize_geojson import map_georef

    georef, plan_name = map_georef(ws, rm)
    return georef, floor or plan_name or None


def write_table(df: pd.DataFrame, out: Path, geo=None) -> None:
    """Write ``df`` to ``out`` (CSV, Parquet or, with ``geo`` = (georeference, floor), GeoJSON by suffix)
    through a temporary file: never half written."""
    from rmbuild.io.atomic import write_bytes_atomic

    buf = io.BytesIO()
    if OUTPUT_FORMATS[out.suffix.lower()] == "geojson":
        from rmbuild.stages.localize_geojson import geojson_bytes

        if geo is None:
            raise InputError("GeoJSON is written for localized positions only: write .csv or .parquet", str(out))
        buf.write(geojson_bytes(df, *geo))
    elif OUTPUT_FORMATS[out.suffix.lower()] == "parquet":
        df.to_parquet(buf, index=False)
    else:
        buf.write(df.to_csv(index=False, float_format="%.4f").encode("utf-8"))
    write_bytes_atomic(out, buf.getvalue())


def one_floor(workspace: str | Path, floor: str | None) -> Path:
    """The workspace whose map to use: ``workspace`` itself, or the floor ``floor`` of a building."""
    from rmbuild.errors import InputError
    from rmbuild.stages.building import floor_workspaces

    floors = floor_workspaces(workspace, floor)
    if floors is None:
        return Path(workspace)
    if len(floors) != 1:
        raise InputError(f"a building workspace (floors {', '.join(floors)}): localize against one floor's map "
                         "with --floor NAME", str(workspace))
    return next(iter(floors.values()))
