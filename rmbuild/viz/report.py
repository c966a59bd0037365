"""A one-page, self-contained HTML report of a workspace (figures embedded as base64 PNG data URIs).

:func:`build_report` reads what the workspace holds (any stage may be missing) and returns the page and
its figures in memory; :func:`rmbuild.stages.report.run` writes them. Figures: walks before/after the
optimisation over the floor plan, heat maps of the strongest APs, CDFs of every localizer and map, the
optimiser's cost; tables: key figures (each stage's report.json) and the config each stage ran with.
"""

from __future__ import annotations

import base64
import html
import io
import json
import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

import numpy as np
import pandas as pd

from rmbuild import __version__
from rmbuild.io.floor_image import load_image
from rmbuild.io.workspace import ARTEFACTS, STAGE_COMMANDS, STAGE_DIRS, Workspace
from rmbuild.types import BUILDING_FRAME_GAUGES
from rmbuild.viz import figures
from rmbuild.viz.align import plan_segments
from rmbuild.viz.report_walks import walk_caption, walk_panels, walk_style
from rmbuild.viz.walk_table import real_errors, walk_rows

log = logging.getLogger(__name__)

#: (stage, dotted key in the stage's report.json, label) shown in the key-figures table when present
KEY_FIGURES: tuple[tuple[str, str, str], ...] = (
    ("ingest", "walks", "walks"),
    ("ingest", "poses", "poses (steps)"),
    ("ingest", "readings", "Wi-Fi readings"),
    ("ingest", "scans", "scans"),
    ("ingest", "aps", "access points"),
    ("ingest", "fixes", "position fixes"),
    ("ingest", "ble.readings", "BLE readings"),
    ("ingest", "ble.beacons", "BLE beacons"),
    ("optimize", "factors.odometry", "odometry factors"),
    ("optimize", "factors.vicinity", "vicinity factors"),
    ("optimize", "linked_walks", "walks linked into the map"),
    ("optimize", "vicinity.scan_spacing_m", "Wi-Fi scans: median metres walked between two of a walk's scans"),
    ("optimize", "vicinity.scans_per_walk", "Wi-Fi scans per walk (median)"),
    ("optimize", "vicinity.rss_exponent", "fingerprints compared as powed RSS, exponent (1 = dBm as read)"),
    ("optimize", "vicinity.rf_model.threshold_db", "RF model: RSS distance where near and far are equally likely"),
    ("optimize", "components", "connected components"),
    ("optimize", "gauge", "map frame fixed by (se2: one walk's frame; anchors / floorplan: the building's)"),
    ("optimize", "iterations", "optimiser iterations"),
    ("optimize", "final_cost", "final cost"),
    ("optimize", "raw.ate_m.rmse", "raw PDR ATE rmse (m)"),
    ("optimize", "optimized.ate_m.rmse", "optimised ATE rmse (m)"),
    ("optimize", "raw.landmark_error_m.mean", "raw PDR landmark error mean (m)"),
    ("optimize", "optimized.landmark_error_m.mean", "optimised landmark error mean (m)"),
    ("optimize", "optimized.landmark_error_fitted_walks_m.mean", "optimised landmark error mean, linked walks (m)"),
    ("optimize", "optimized.landmark_error_unlinked_at_raw_m.mean",
     "optimised landmark error mean, unlinked walks at their raw placement (m)"),
    ("optimize", "time_s.stage_total", "optimise time (s)"),
    ("map", "cells", "radio map cells"),
    ("map", "aps", "radio map APs"),
    ("map", "cell_size_m", "cell size (m)"),
    ("map", "plan_coverage.share", "share of the floor plan's walkable space the map's cells cover"),
    ("map", "ble.cells", "BLE radio map cells (map/radiomap_ble.*)"),
    ("map", "ble.beacons", "BLE radio map beacons"),
)

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:2em auto;max-width:1180px;
 color:#222;padding:0 1em;line-height:1.4}
h1{font-size:1.6em;margin-bottom:.2em} h2{border-bottom:1px solid #ddd;padding-bottom:.2em;margin-top:1.6em}
.meta{color:#666;font-size:.9em} figure{margin:1em 0} figure img{max-width:100%;border:1px solid #eee}
figcaption{color:#555;font-size:.9em} table{border-collapse:collapse;font-size:.9em;margin:.5em 0}
td,th{border:1px solid #ddd;padding:.25em .6em;text-align:left;white-space:pre-line;vertical-align:top}
td.num{text-align:right;font-variant-numeric:tabular-nums}
th{background:#f5f5f5} pre{background:#f7f7f7;padding:.7em;overflow-x:auto;font-size:.85em}
.missing{color:#999;font-style:italic} details{margin:.4em 0}
.warnings{background:#fff8e6;border-left:4px solid #e69f00;padding:.2em 1em;font-size:.9em}
.warnings h3{font-size:1em;margin:.6em 0 .2em} .warnings li{margin:.2em 0}
"""


@dataclass
class ReportFigure:
    """One figure of the report: ``name`` (PNG file stem), ``title``, ``png`` bytes, ``caption``."""

    name: str
    title: str
    png: bytes
    caption: str = ""


@dataclass
class Report:
    """The page (``html``, self-contained), its figures and what was missing (section -> why)."""

    html: str
    figures: list[ReportFigure]
    missing: dict[str, str] = field(default_factory=dict)


def _png(fig: Any, dpi: int = 100) -> bytes:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


def _get(d: Any, dotted: str) -> Any:
    for part in dotted.split("."):
        if not isinstance(d, dict) or part not in d:
            return None
        d = d[part]
    return d


def _flatten(d: Any, prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    if isinstance(d, dict):
        for k, v in d.items():
            out.update(_flatten(v, f"{prefix}{k}."))
    elif isinstance(d, list):
        if d and all(isinstance(v, str) for v in d):  # warnings, notes: their text, one per line
            out[prefix[:-1]] = "\n".join(d)
        elif d and len(d) <= 8 and all(not isinstance(v, (dict, list)) for v in d):
            out[prefix[:-1]] = ", ".join(map(str, d))
        elif d:
            out[prefix[:-1]] = f"[{len(d)} values]"
    else:
        out[prefix[:-1]] = d
    return out


def _fmt(v: Any) -> str:
    if v is None:  # a figure that could not be computed (e.g. an ATE without true paths)
        return "not computed"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.4g}" if abs(v) < 1e5 else f"{v:.3e}"
    return str(v)


class Markup(str):
    """A table cell that is HTML already (a link), not text to escape."""


def _cell(c: str) -> str:
    return c if isinstance(c, Markup) else html.escape(c)


def _table(rows: Sequence[tuple[str, ...]], header: tuple[str, ...]) -> str:
    h = "".join(f"<th>{html.escape(c)}</th>" for c in header)
    body = "".join(
        "<tr>" + "".join(
            f"<td class=\"num\">{_cell(c)}</td>" if i and _is_num(c) else f"<td>{_cell(c)}</td>"
            for i, c in enumerate(r)) + "</tr>"
        for r in rows)
    return f"<table><thead><tr>{h}</tr></thead><tbody>{body}</tbody></table>"


def _is_num(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def _errors_by_label(df: pd.DataFrame) -> dict[str, np.ndarray]:
    """Per "map / localizer" the per-scan errors (m) of evaluate/errors.parquet, long or wide layout."""
    err_col = next((c for c in ("error_m", "err_m", "error") if c in df.columns), None)
    if err_col is not None:
        keys = [c for c in ("map", "localizer") if c in df.columns]
        if not keys:
            return {"all": df[err_col].to_numpy(dtype=float)}
        return {" / ".join(map(str, k if isinstance(k, tuple) else (k,))): g[err_col].to_numpy(dtype=float)
                for k, g in df.groupby(keys, sort=False)}
    skip = {"walk_id", "t_s", "node", "scan", "step", "x_m", "y_m"}
    return {str(c): df[c].to_numpy(dtype=float) for c in df.columns
            if c not in skip and pd.api.types.is_float_dtype(df[c])}


def build_report(ws: Workspace, heatmap_top_n: int = 6) -> Report:
    """Read ``ws`` and lay out the report; stages that have not run leave a note instead of a section."""
    ws.require("ingest")
    missing: dict[str, str] = {}
    reports = {s: ws.read_report(s) for s in STAGE_DIRS}
    for s in STAGE_DIRS:
        if stale := ws.stale_inputs(s):
            missing[f"{s} (stale)"] = (f"{STAGE_COMMANDS[s]} ran on an earlier run of {', '.join(stale)}: its "
                                       f"figures may not match; re-run `rmbuild {STAGE_COMMANDS[s]} --force`")
    ds = ws.read_dataset()
    walls = _plan_segments(ws, ds)
    gauge = (reports.get("optimize") or {}).get("gauge")
    image = load_image(ws)  # the plan's raster, decoded once for every figure drawn over it
    figs, rt = _walk_figures(ws, ds, gauge, (walls, image), missing)
    figs += _map_figures(ws, heatmap_top_n, gauge, rt, (walls, image), _fixes_of(ds), missing)
    eval_figs, eval_rows = _evaluation(ws, reports.get("evaluate"), missing)
    page = _page(ws, figs + eval_figs, missing, eval_rows, reports, _walks_html(ws, ds, rt, gauge))
    return Report(page, figs + eval_figs, missing)


def _walks_html(ws: Workspace, ds: Any, rt: Any, gauge: str | None) -> str:
    """The per-walk table (folded: one row per walk) after the walk figures; "" before optimize."""
    if not (ws.has("optimize") and ws.exists("optimize.walks")):
        return ""
    walks = ws.read_table("optimize.walks")
    errors = real_errors(ws.read_table("optimize.poses"), ds, rt, gauge)
    header, rows = walk_rows(walks, errors)
    n_linked = sum(r[1] == "yes" for r in rows)
    note = ("The linked walks first, the largest predicted error on top, then the walks left out. "
            "Placed by: how optimize put the walk in the map (Wi-Fi pairs, continuity with the previous "
            "recording, ...); shared path: length of path it shares with other walks by Wi-Fi; predicted "
            "error: optimize's own estimate of how far off its placement is; why: the evidence that placed the walk "
            "or the reason it was left out")
    if errors:
        note += f"; {errors[0].split(' (')[0]}: the mean distance after the map's fit to the building"
    return (f"<details><summary>Per walk: {len(rows)} walks, {n_linked} linked into the map "
            f"(optimize/walks.parquet)</summary><p class=\"meta\">{html.escape(note)}.</p>"
            f"{_table(rows, header)}</details>")


def _plan_segments(ws: Workspace, ds: Any) -> np.ndarray | None:
    """The floor plan as segments (n, 4) in the building frame (m), None without one."""
    return plan_segments(ds.venue, ws.read_json("data.floorplan") if ws.exists("data.floorplan") else None)


def _fixes_of(ds: Any) -> pd.DataFrame | None:
    fx = getattr(ds, "fixes", None)
    if fx is None or len(fx) == 0 or not {"walk_id", "x_m", "y_m"} <= set(fx.columns):
        return None
    return fx


def _walk_figures(ws: Workspace, ds: Any, gauge: str | None, plan: tuple[np.ndarray | None, Any],
                  missing: dict[str, str]) -> tuple[list[ReportFigure], Any]:
    """The walks before/after the optimisation (:mod:`rmbuild.viz.report_walks`), the optimiser's cost and
    its RF model; also the optimiser-to-building transform (None when unknown or not needed). ``plan``: its
    walls (n, 4) m and raster image, each None when absent."""
    walls, plan_image = plan
    fixes = _fixes_of(ds)
    optimized = ws.has("optimize")
    if not optimized:
        missing["optimize"] = "optimize has not run: only the raw walks are shown"
    opt = ws.read_table("optimize.poses") if optimized else None
    walks = ws.read_table("optimize.walks") if optimized and ws.exists("optimize.walks") else None
    wp = walk_panels(ds, opt, walks, gauge, fixes)
    style = walk_style([str(w) for w in ds.walk_ids()], walks)
    drawn_walls = walls if wp.building else None
    image = plan_image if wp.building else None
    fig = figures.walks_figure(wp.panels, style, truth=ds.truth_poses, walls=drawn_walls, fixes=wp.fixes,
                               image=image)
    caption = walk_caption(wp, style, ws.read_report("optimize") if optimized else None,
                           ds.truth_poses is not None, drawn_walls is not None, image is not None)
    figs = [ReportFigure("walks", "Walks before and after optimisation", _png(fig), caption)]
    if optimized and ws.exists("optimize.history"):
        h = ws.read_table("optimize.history")
        if "cost" in h and len(h):
            solve = h["solve"].to_numpy() if "solve" in h else None
            figs.append(ReportFigure(
                "cost", "Optimiser cost", _png(figures.cost_figure(h["cost"].to_numpy(), solve)),
                "Cost after each Levenberg-Marquardt iteration of every solve; a dotted line starts the next solve, "
                "whose graph has other factors (re-selected pairs, rescaled odometry), so its cost jumps."))
    rf = ((ws.read_report("optimize") or {}).get("vicinity") or {}) if optimized else {}
    if rf.get("rf_model"):
        figs.append(ReportFigure(
            "rf", "RF model", _png(figures.rf_model_figure(rf["rf_model"], rf.get("rss_exponent_auc"),
                                                            rf.get("rss_exponent"))), _rf_caption(rf)))
    return figs, wp.rt


def _rf_caption(rf: dict) -> str:
    text = ("How the RSS distance of two walks' scans relates to how far apart they were, calibrated on the data "
            "itself (pairs of scans of one walk, whose separation its dead reckoning knows); right: the powed "
            "exponent's choice (a β other than 1 only when it gains ≥ 0.03 AUC).")
    offsets = rf.get("device_offsets_db") or {}
    moved = {dev: float(v) for dev, v in offsets.items() if abs(float(v)) >= 0.05}
    if moved:
        shown = ", ".join(f"{dev} {v:+.1f} dB" for dev, v in moved.items())
        rest = len(offsets) - len(moved)
        text += (f" Phones' RSS offsets against the reference phone, removed before fingerprints are compared: "
                 f"{shown}" + (f" (the other {rest} read alike)." if rest else "."))
    elif len(offsets) > 1:
        text += f" The {len(offsets)} phones read alike: no RSS offset removed."
    return text


def _map_figures(ws: Workspace, heatmap_top_n: int, gauge: str | None, rt: Any, plan: tuple[np.ndarray | None, Any],
                 fixes: pd.DataFrame | None, missing: dict[str, str]) -> list[ReportFigure]:
    walls, plan_image = plan
    if not (ws.has("map") and ws.exists("map.cells")):
        missing["map"] = "export-map has not run"
        return []
    cells = ws.read_table("map.cells")
    sidecar = ws.read_json("map.sidecar") if ws.exists("map.sidecar") else {}
    cell_size = ((sidecar or {}).get("grid") or {}).get("cell_size_m")
    frame = (sidecar or {}).get("frame")
    in_building = frame == "building" or gauge in BUILDING_FRAME_GAUGES

    def to_map(xy: np.ndarray) -> np.ndarray | None:  # building frame -> map frame, None when unknown
        if in_building:
            return xy
        if rt is None:
            return None
        r, t = rt
        return (xy - t) @ r  # map = R^T (building - t)

    walls_map = None if walls is None else to_map(walls.reshape(-1, 2))
    fixes_map = None if fixes is None else to_map(fixes[["x_m", "y_m"]].to_numpy(dtype=float))
    image = plan_image if in_building else None  # the raster is not turned into a walk's frame
    walls4 = None if walls_map is None else walls_map.reshape(-1, 4)
    fig = figures.heatmaps_figure(cells, heatmap_top_n, walls4, cell_size, fixes_map, image)
    if fig is None:
        missing["map"] = "the radio map table has no usable rows"
        return []
    caption = ("Mean RSSI per cell (dBm) in the map frame, one colour scale from the weakest to the strongest "
               "value drawn; empty cells were never visited; one access point per radio (the other networks a "
               "radio announces, BSSIDs differing in the first octet or the last digit, map the same signal)")
    caption += "; dark lines: floor plan" if walls_map is not None else ""
    caption += "; underneath: the plan's image" if image is not None else ""
    caption += "; grey dots: waypoints / position fixes" if fixes_map is not None else ""
    out = [ReportFigure("heatmaps", f"Radio map: the {heatmap_top_n} strongest radios", _png(fig), caption + ".")]
    if ws.exists("map.cell_table"):
        cov = figures.coverage_figure(ws.read_table("map.cell_table"), cell_size, walls4, frame, image)
        share = _get(ws.read_report("map"), "plan_coverage.share")
        out.append(ReportFigure(
            "coverage", "Coverage", _png(cov),
            "Scans per visited cell over the whole floor plan: the blank part of the plan is where no walk of the "
            "map went" + (f"; the map's cells cover {share:.0%} of the plan's walkable space" if share else "")
            + "."))
    return out


def _evaluation(ws: Workspace, ev: dict | None, missing: dict[str, str]
                ) -> tuple[list[ReportFigure], list[tuple[str, ...]]]:
    """The CDF figure and the per map and localizer error rows."""
    if not ws.has("evaluate"):
        missing["evaluate"] = "evaluate has not run"
        return [], []
    figs = []
    if ws.exists("evaluate.errors"):
        errs = _errors_by_label(ws.read_table("evaluate.errors"))
        if errs:
            ref = "true positions" if (ev or {}).get("reference") == "truth_poses" else \
                "positions interpolated between the waypoints / position fixes"
            figs.append(ReportFigure("cdf", "Localization error CDFs", _png(figures.cdf_figure(errs)),
                                     f"Per test scan, error against the {ref}, of each localizer (colour) with "
                                     "each map (line style; built: from the optimised walks; surveyed: from "
                                     f"the {ref}, what a site survey would give; raw: from raw PDR); grey "
                                     "lines at 5 and 10 m."))
    rows: list[tuple[str, ...]] = []
    for mname, locs in ((ev or {}).get("maps") or {}).items():
        for lname, st in (locs or {}).items():
            st = st or {}
            rows.append((str(mname), str(lname), *(_fmt(st.get(k)) for k in ("mean", "median", "p90", "n"))))
    return figs, rows


def _fig_html(f: ReportFigure) -> str:
    uri = "data:image/png;base64," + base64.b64encode(f.png).decode("ascii")
    return (f"<figure id=\"fig-{f.name}\"><img src=\"{uri}\" alt=\"{html.escape(f.title)}\">"
            f"<figcaption>{html.escape(f.title)}. {html.escape(f.caption)}</figcaption></figure>")


def _tables_html(ws: Workspace, reports: dict[str, dict | None]) -> tuple[str, str]:
    """The key figures (with every report folded out below) and the config each stage ran with."""
    key_rows = [(label, _fmt(v), f"{stage}: {key}") for stage, key, label in KEY_FIGURES
                if (v := _get(reports.get(stage), key)) is not None]
    details = []
    for stage, rep in reports.items():
        if rep is None:
            continue
        flat = [(k, _fmt(v)) for k, v in _flatten(rep).items() if k]
        rel = ARTEFACTS[f"{STAGE_DIRS[stage]}.report"]
        details.append(f"<details><summary>{html.escape(rel)} ({len(flat)} values)</summary>"
                       f"{_table(flat, ('key', 'value'))}</details>")
    configs = []
    for stage, d in STAGE_DIRS.items():
        text = ws.read_config_text(stage)
        if text is not None:
            rel = ARTEFACTS[f"{d}.config"]
            configs.append(f"<h3>{html.escape(stage)} <span class=\"meta\">({html.escape(rel)})</span></h3>"
                           f"<pre>{html.escape(text)}</pre>")
    keys = "<h2>Key figures</h2>" + (_table(key_rows, ("figure", "value", "source")) if key_rows
                                     else "<p class=\"missing\">no stage reports</p>") + "".join(details)
    return keys, "<h2>Configuration used</h2>" + ("".join(configs) or "<p class=\"missing\">none found</p>")


def _warnings_html(reports: dict[str, dict | None], missing: dict[str, str]) -> str:
    """Every stage's warnings, in full, and what the report could not show; "" when there are none."""
    parts = []
    for stage, rep in reports.items():
        warnings = [w for w in (rep or {}).get("warnings") or [] if isinstance(w, str)]
        if warnings:
            items = "".join(f"<li>{html.escape(w)}</li>" for w in warnings)
            parts.append(f"<h3>{html.escape(STAGE_COMMANDS.get(stage, stage))} ({len(warnings)})</h3><ul>{items}</ul>")
    if missing:
        items = "".join(f"<li>{html.escape(k)}: {html.escape(v)}</li>" for k, v in missing.items())
        parts.append(f"<h3>not shown</h3><ul>{items}</ul>")
    return ("<h2 id=\"warnings\">Warnings</h2><div class=\"warnings\">" + "".join(parts) + "</div>") if parts else ""


def _page(ws: Workspace, figs: list[ReportFigure], missing: dict[str, str], eval_rows: list[tuple[str, ...]],
          reports: dict[str, dict | None], walks_html: str = "") -> str:
    by_name = {f.name: f for f in figs}
    sections = [_warnings_html(reports, missing)]
    sections.append("<h2>Walks</h2>" + _fig_html(by_name["walks"]) + walks_html
                + (_fig_html(by_name["cost"]) if "cost" in by_name else "")
                + (_fig_html(by_name["rf"]) if "rf" in by_name else ""))
    sections.append("<h2>Radio map</h2>" + (_fig_html(by_name["heatmaps"]) if "heatmaps" in by_name
                                            else f"<p class=\"missing\">{html.escape(missing.get('map', ''))}</p>")
                    + (_fig_html(by_name["coverage"]) if "coverage" in by_name else ""))
    ev_html = "<h2>Localization</h2>"
    if "cdf" in by_name:
        ev_html += _fig_html(by_name["cdf"])
    if eval_rows:
        ev_html += _table(eval_rows, ("map", "localizer", "mean (m)", "median (m)", "p90 (m)", "scans"))
    if "cdf" not in by_name and not eval_rows:
        ev_html += f"<p class=\"missing\">{html.escape(missing.get('evaluate', 'no evaluation results'))}</p>"
    sections.append(ev_html)
    sections.extend(_tables_html(ws, reports))
    stages_run = [s for s in STAGE_DIRS if ws.has(s)]
    now = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    return (
        "<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\">"
        f"<title>rmbuild report: {html.escape(ws.root.name)}</title>"
        f"<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\"><style>{_CSS}</style></head><body>"
        f"<h1>rmbuild report: {html.escape(ws.root.name)}</h1>"
        f"<p class=\"meta\">workspace {html.escape(str(ws.root.resolve()))} · stages: {', '.join(stages_run)} · "
        f"rmbuild {__version__} · written {now}</p>"
        + "".join(sections)
        + f"<script type=\"application/json\" id=\"rmbuild-missing\">{html.escape(json.dumps(missing))}</script>"
        "</body></html>\n"
    )


# ------------------------------------------------------------------ a building's page
def _stat(s: dict | None, key: str) -> str:
    v = (s or {}).get(key)
    return "—" if v is None else (f"{v:.2f}" if isinstance(v, float) else str(v))


def _floor_row(name: str, link: str | None, reps: dict[str, dict | None]) -> tuple[str, ...]:
    """One floor of the building table: walks, linked, landmark error, map cells, kNN medians, report."""
    ing, opt, mp, ev = (reps.get(s) or {} for s in ("ingest", "optimize", "map", "evaluate"))
    lm = _get(opt, "optimized.landmark_error_fitted_walks_m.mean") or _get(opt, "optimized.landmark_error_m.mean")
    knn = {m: _get(ev, f"maps.{m}.knn.median") for m in ("built", "surveyed", "raw")}
    return (name, _fmt(ing.get("walks")), _fmt(opt.get("linked_walks")), "—" if lm is None else f"{lm:.1f}",
            _fmt(mp.get("cells")), *("—" if v is None else f"{v:.1f}" for v in knn.values()),
            _fmt(ev.get("n_scored")),
            Markup(f'<a href="{html.escape(link)}">floor {html.escape(name)}</a>') if link else "")


def _floor_eval_html(name: str, ev: dict) -> str:
    """A floor's evaluation table, the rows and columns `rmbuild evaluate` prints."""
    cols = ("mean", "median", "p90", "rmse", "max", "p_lt_5m", "p_lt_10m", "n")
    rows = [(m, loc, *(_stat(s, c) for c in cols)) for m, locs in (ev.get("maps") or {}).items()
            for loc, s in (locs or {}).items()]
    head = ("map", "localizer", "mean", "median", "p90", "rmse", "max", "<5m", "<10m", "n")
    return f"<h3>floor {html.escape(name)}</h3>" + _table(rows, head)


def _building_eval_html(b: dict) -> str:
    """The building's floor classification and combined errors, as `rmbuild evaluate` prints them."""
    fc = b.get("floor_classification")
    if not fc:
        return "<p class=\"missing\">no floor classification (no floor evaluated)</p>"
    per = ", ".join(f"{f} {v['hit_rate']:.1%}" for f, v in fc["per_floor"].items())
    rows = []
    for m, d in (b.get("maps") or {}).items():
        for loc, s in d.items():
            a, c, k = s["xy_all_scans"], s["xy_correct_floor"], s["combined"]
            rows.append((m, loc, _stat(a, "mean"), _stat(a, "p75"), _stat(c, "mean"), _stat(k, "mean"),
                         _stat(k, "p75")))
    head = ("map", "localizer", "xy mean", "xy p75", "correct-floor mean", "combined mean", "combined p75")
    return (f"<p>Floor hit rate on the test scans: {fc['hit_rate']:.1%} of {fc['n']} (single scans "
            f"{fc['hit_rate_single_scan']:.1%}); per floor: {html.escape(per)}. Errors in m; combined: + "
            f"{b.get('floor_penalty_m', 15):g} m per floor off.</p>" + _table(rows, head))


def building_html(title: str, floors: dict[str, tuple[str | None, dict[str, dict | None]]],
                  evaluate_building: dict | None) -> str:
    """A building's page: per floor its walks, linked walks, landmark error, map and kNN medians with a link
    to its own report (``floors``: name -> (relative link or None, that floor's report per stage)), each
    floor's evaluation table, the floors skipped and the building's floor classification."""
    head = ("floor", "walks", "linked", "landmark error, linked (m)", "map cells", "kNN median built (m)",
            "surveyed (m)", "raw (m)", "test scans", "report")
    table = _table([_floor_row(n, link, reps) for n, (link, reps) in floors.items()], head)
    b = evaluate_building or {}
    skipped = b.get("skipped_floors") or {}
    evals = "".join(_floor_eval_html(n, reps.get("evaluate") or {}) for n, (_, reps) in floors.items()
                    if reps.get("evaluate") and n not in skipped)
    skip = "".join(f"<li>floor {html.escape(n)}: {html.escape(why)}</li>" for n, why in skipped.items())
    body = (f"<h1>{html.escape(title)}</h1><h2>Floors</h2>{table}"
            + (f"<h2>Floors not evaluated</h2><ul>{skip}</ul>" if skip else "")
            + ("<h2>Localization per floor</h2>" + evals if evals else "")
            + ("<h2>Building: which floor</h2>" + _building_eval_html(b) if evaluate_building else ""))
    return ("<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{html.escape(title)}</title><meta name=\"viewport\" content=\"width=device-width, "
            f"initial-scale=1\"><style>{_CSS}</style></head><body>{body}</body></html>\n")
