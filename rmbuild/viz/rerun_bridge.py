"""The only module of rmbuild that imports rerun: :class:`RerunViewer`, the rerun implementation of the
:class:`rmbuild.viz.viewer.Viewer` contract (its do-nothing twin is :class:`rmbuild.viz.viewer.NullViewer`).

rerun-sdk is imported lazily (inside :class:`RerunViewer`), so importing this module costs nothing. The SDK's
API moves between releases: rmbuild pins rerun-sdk to one minor (:data:`RERUN_VERSION`) and checks it.

Entity tree (``floor`` and ``raw`` carry a static y-flip so that +y points up in the 2D views)::

    floor/plan/walls                      venue walls (static)
    floor/plan/image                      the plan's raster image, when the workspace has one (static)
    floor/truth/<walk>                    true path (static) + .../pos: the current step (timeline "step")
    floor/optimized/<walk>, .../pos       optimised path in the common frame
    floor/initial/<walk>                  initial guess of the optimiser
    floor/{optimized,initial}_unlinked/<walk>  walks not linked to the map (arbitrary frame; not in the layout)
    (floor/{optimized,initial,vicinity,map} carry the optimiser-frame -> building-frame transform when
    the truth is known and the gauge is free: see RerunViewer.log_alignment)
    floor/vicinity                        vicinity factors (a sample), coloured by final error
    floor/map/coverage                    scans per cell; floor/map/strongest/<ap>: RGBA heat maps
    floor/eval/<map>/<localizer>/<walk>/{estimated,true,error}   localization tracks (timeline "scan")
    raw/<walk>, raw/<walk>/pos            raw PDR walk in its own frame
    map/tensor/{mean,std,count}           per-AP heat maps as tensors (AP, y, x): the AP is a slider
    map/aps                               AP index -> BSSID (text)
    plots/optimize/cost                   optimiser cost (timeline "iteration")
    plots/residuals/{odometry,vicinity}/<walk>   per-step residuals (timeline "step")
    plots/eval/<map>/<localizer>/<walk>   localization error (timeline "scan")
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from rmbuild.errors import RmbuildError
from rmbuild.viz.colors import colormap, error_colors, walk_color
from rmbuild.viz.viewer import (
    ALIGNED_PARTS,
    MAX_TENSOR_APS,
    MAX_VICINITY_LINES,
    STRONGEST_APS,
    NullViewer,
    Viewer,
    ViewTarget,
)

log = logging.getLogger(__name__)

#: The rerun-sdk minor this bridge is written against (pyproject pins ``rerun-sdk>=0.41,<0.42``).
RERUN_VERSION = (0, 41)
APPLICATION_ID = "rmbuild"

# ------------------------------------------------------------------ timelines
#: step index within a walk (sequence)
TIMELINE_STEP = "step"
#: step time of the walk: a timestamp when the times are epoch seconds (MS ILC, IPIN), else a duration (s)
TIMELINE_TIME = "t_s"
#: s; times above this (2001-09-09) are taken as seconds since the Unix epoch
EPOCH_TIME_MIN_S = 1e9
#: optimiser iteration (sequence)
TIMELINE_ITERATION = "iteration"
#: scan index of a test walk in the evaluation (sequence)
TIMELINE_SCAN = "scan"

# ------------------------------------------------------------------ entity roots
FLOOR = "floor"
RAW = "raw"
PLOTS = "plots"
MAP = "map"
#: elements of each (AP, y, x) map tensor at most (float32: 32 MB): a large map's tensors show fewer APs
TENSOR_MAX_ELEMS = 8_000_000

def _spawn(rec) -> None:
    """Open (or connect to) the native viewer on rerun's default port (9876); a one-line error when there is
    no display or no viewer executable (rerun's own message spans many lines)."""
    from rmbuild.errors import InputError

    if not has_display():
        raise InputError("--spawn needs a display (neither DISPLAY nor WAYLAND_DISPLAY is set): use --save "
                         "FILE.rrd and open it elsewhere, or --serve for the web viewer")
    try:
        with _env(XDG_CONFIG_HOME=str(_private_rerun_config()), TELEMETRY_ENABLED="false"):
            rec.spawn()
    except RuntimeError as e:
        raise InputError(f"the rerun viewer could not be started ({str(e).splitlines()[0][:200]}): "
                         "use --save FILE.rrd or --serve") from None


def has_display() -> bool:
    """True when a native window can be opened (X11/Wayland on Linux; always on macOS and Windows)."""
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def default_target(save_path: str | Path, mode: str | None = None, port: int = 9090) -> ViewTarget:
    """``mode`` as given, else "spawn" when a display is available, else "save" to ``save_path``."""
    mode = mode or ("spawn" if has_display() else "save")
    return ViewTarget(mode, Path(save_path) if mode == "save" else None, port)


# ------------------------------------------------------------------ rerun import, version, telemetry
def _import_rerun() -> Any:
    """Import rerun with its own telemetry off and check that the installed minor is the pinned one."""
    # rerun-sdk's OpenTelemetry tracing is opt-in through TELEMETRY_ENABLED; make the "off" explicit.
    os.environ.setdefault("TELEMETRY_ENABLED", "false")
    try:
        import rerun as rr
    except ImportError as e:  # pragma: no cover - rerun-sdk is a dependency
        raise RmbuildError(f"rerun-sdk is not installed ({e}); pip install 'rerun-sdk>=0.41,<0.42'") from None
    check_version(rr.__version__)
    return rr


def check_version(version: str) -> None:
    """Raise RmbuildError unless ``version`` is of the pinned minor (:data:`RERUN_VERSION`)."""
    try:
        major, minor = (int(p) for p in version.split(".")[:2])
    except ValueError:
        raise RmbuildError(f"cannot parse the rerun-sdk version {version!r}") from None
    if (major, minor) != RERUN_VERSION:
        want = f"{RERUN_VERSION[0]}.{RERUN_VERSION[1]}"
        raise RmbuildError(f"rerun-sdk {version} is installed but rmbuild's viewer is written for {want}.x; "
                           f"pip install 'rerun-sdk>={want},<{RERUN_VERSION[0]}.{RERUN_VERSION[1] + 1}'")


def _private_rerun_config() -> Path:
    """An XDG config dir whose rerun/analytics.json has analytics disabled (for the viewers we start).

    The native and served viewers read their usage-analytics switch from ``$XDG_CONFIG_HOME/rerun``; we
    point them at this directory instead of changing the user's own rerun config.
    """
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "rmbuild" / "rerun-config"
    cfg = base / "rerun" / "analytics.json"
    if not cfg.is_file():
        cfg.parent.mkdir(parents=True, exist_ok=True)
        data_dir = Path(os.environ.get("XDG_DATA_HOME") or Path.home() / ".local" / "share") / "rerun" / "analytics"
        cfg.write_text(json.dumps({"analytics_enabled": False, "analytics_id": "0" * 32, "metadata": {},
                                   "config_file_path": str(cfg), "data_dir_path": str(data_dir)}))
    return base


class _env:
    """Temporarily set environment variables (around starting a viewer process or server)."""

    def __init__(self, **values: str) -> None:
        self.values = values
        self.old: dict[str, str | None] = {}

    def __enter__(self) -> None:
        for k, v in self.values.items():
            self.old[k] = os.environ.get(k)
            os.environ[k] = v

    def __exit__(self, *exc: object) -> None:
        for k, v in self.old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


# ------------------------------------------------------------------ helpers
def entity_part(name: object) -> str:
    """A string safe as one entity-path part (BSSIDs have ':', walk ids may have '/' or spaces)."""
    s = str(name)
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in s) or "_"


def _xy(df: pd.DataFrame) -> np.ndarray:
    return df[["x_m", "y_m"]].to_numpy(dtype=np.float64)


def _finite_rows(xy: np.ndarray) -> np.ndarray:
    return xy[np.isfinite(xy).all(axis=1)]


def _walk_groups(poses: pd.DataFrame) -> list[tuple[str, pd.DataFrame]]:
    return [(str(w), g) for w, g in poses.groupby("walk_id", sort=False)]


def blueprint(rrb: Any, has: dict[str, bool]) -> Any:
    """The default layout: walks (raw | common frame) with the optimiser plots, radio map, evaluation."""
    walks_view = rrb.Spatial2DView(
        name="common frame: optimised / truth / waypoints / vicinity", origin="/",
        contents=[f"+ /{FLOOR}/plan/**", f"+ /{FLOOR}/truth/**", f"+ /{FLOOR}/fixes/**",
                  f"+ /{FLOOR}/optimized/**", f"+ /{FLOOR}/vicinity/**"],
    )
    raw_view = rrb.Spatial2DView(name="raw PDR walks (each in its own frame)", origin="/",
                                 contents=[f"+ /{RAW}/**"])
    plots = rrb.Vertical(
        rrb.TimeSeriesView(name="optimiser cost", origin=f"/{PLOTS}/optimize"),
        rrb.TimeSeriesView(name="odometry residual (m)", origin=f"/{PLOTS}/residuals/odometry"),
        rrb.TimeSeriesView(name="vicinity residual", origin=f"/{PLOTS}/residuals/vicinity"),
    )
    tabs = [rrb.Horizontal(rrb.Vertical(walks_view, raw_view), plots, column_shares=[3, 2], name="walks")]
    if has.get("map"):
        tabs.append(rrb.Horizontal(
            rrb.Spatial2DView(name="coverage and strongest APs over the plan", origin="/",
                              contents=[f"+ /{FLOOR}/plan/**", f"+ /{FLOOR}/map/**"]),
            rrb.Vertical(
                rrb.TensorView(name="mean RSSI (dBm) per AP: AP slider", origin=f"/{MAP}/tensor/mean"),
                rrb.TensorView(name="std (dB) per AP", origin=f"/{MAP}/tensor/std"),
                rrb.TensorView(name="readings per AP", origin=f"/{MAP}/tensor/count"),
                rrb.TextDocumentView(name="AP index", origin=f"/{MAP}/aps"),
            ),
            name="radio map",
        ))
    if has.get("eval"):
        tabs.append(rrb.Horizontal(
            rrb.Spatial2DView(name="estimated vs true tracks", origin="/",
                              contents=[f"+ /{FLOOR}/plan/**", f"+ /{FLOOR}/eval/**"]),
            rrb.TimeSeriesView(name="localization error (m)", origin=f"/{PLOTS}/eval"),
            name="localization",
        ))
    return rrb.Blueprint(rrb.Tabs(*tabs), collapse_panels=False)


# ------------------------------------------------------------------ the viewer
class RerunViewer:
    """Logs rmbuild's in-memory tables to one rerun recording (a file, a spawned viewer or a web viewer).

    All ``log_*`` methods take the workspace tables (see docs/data-format.md) and tolerate missing
    optional columns. Use as a context manager or call :meth:`close`; for "save" the .rrd is written to a
    temporary file and renamed into place on close, so an interrupted run leaves no half recording.
    """

    enabled = True

    def __init__(self, target: ViewTarget, recording_name: str | None = None) -> None:
        self.rr = _import_rerun()
        import rerun.blueprint as rrb

        self.rrb = rrb
        self.target = target
        self._has: dict[str, bool] = {}
        self._walk_index: dict[str, int] = {}
        self._tmp_path: Path | None = None
        self._closed = False
        self.counts: dict[str, int] = {}
        self._time_kind: str | None = None
        self.rec = self.rr.RecordingStream(APPLICATION_ID, make_default=False)
        if target.mode == "save":
            assert target.path is not None
            # recorded outside the target's directory (ingest replaces the workspace that will hold it)
            fd, tmp = tempfile.mkstemp(prefix="rmbuild-", suffix=".rrd")
            os.close(fd)
            self._tmp_path = Path(tmp)
            self.rec.save(self._tmp_path)
        elif target.mode == "spawn":
            _spawn(self.rec)
        else:  # serve: gRPC server + web viewer, both on localhost
            with _env(XDG_CONFIG_HOME=str(_private_rerun_config()), TELEMETRY_ENABLED="false"):
                uri = self.rec.serve_grpc(grpc_port=target.port + 1)
                self.rr.serve_web_viewer(web_port=target.port, open_browser=False, connect_to=uri)
            log.info("rerun web viewer on http://localhost:%d (gRPC %s)", target.port, uri)
        if recording_name:
            self.rec.send_recording_name(recording_name)
        for root in (FLOOR, RAW):  # +y up in the 2D views (images and views are y-down by default)
            self.rec.log(root, self.rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)
        self._send_blueprint()

    # -------------------------------------------------------------- lifecycle
    def __enter__(self) -> RerunViewer:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        self.close(keep=exc_type is None)

    def flush(self) -> None:
        self.rec.flush()

    def close(self, keep: bool = True) -> Path | None:
        """Finish the recording; for "save" returns the .rrd path (None when not kept)."""
        if self._closed:
            return self.target.path if self.target.mode == "save" else None
        self._closed = True
        self._send_blueprint()
        self.rec.flush()
        if self.target.mode != "save":
            return None
        self.rec.disconnect()  # closes the file sink
        assert self._tmp_path is not None and self.target.path is not None
        if keep:
            _move_into_place(self._tmp_path, self.target.path)
            return self.target.path
        self._tmp_path.unlink(missing_ok=True)
        return None

    def _send_blueprint(self) -> None:
        self.rec.send_blueprint(blueprint(self.rrb, self._has), make_active=True, make_default=True)

    def _count(self, key: str, n: int = 1) -> None:
        self.counts[key] = self.counts.get(key, 0) + n

    # -------------------------------------------------------------- walks
    def set_walks(self, walk_ids: Sequence[str]) -> None:
        """Fix the walk order (one colour per walk, in this order); call before logging walks."""
        for w in walk_ids:
            self._walk_index.setdefault(str(w), len(self._walk_index))

    def _color(self, walk_id: str) -> tuple[int, int, int]:
        i = self._walk_index.setdefault(walk_id, len(self._walk_index))
        return walk_color(i)

    def _log_walk(self, path: str, walk_id: str, g: pd.DataFrame, radius: float = 0.35) -> None:
        rr = self.rr
        xy = _xy(g)
        ok = np.isfinite(xy).all(axis=1)
        color = self._color(walk_id)
        self.rec.log(path, rr.LineStrips2D([xy[ok]], colors=[color], radii=[0.08], labels=[walk_id],
                                           show_labels=False), static=True)
        n = int(ok.sum())
        if n == 0:
            return
        steps = g["step"].to_numpy(dtype=np.int64)[ok] if "step" in g else np.arange(len(g))[ok]
        indexes = [rr.TimeColumn(TIMELINE_STEP, sequence=steps)]
        if "t_s" in g:
            t = g["t_s"].to_numpy(dtype=np.float64)[ok]
            if self._time_kind is None:  # one kind per recording: a timeline has one type
                self._time_kind = "timestamp" if float(np.median(t)) > EPOCH_TIME_MIN_S else "duration"
            indexes.append(rr.TimeColumn(TIMELINE_TIME, **{self._time_kind: t}))
        self.rec.log(f"{path}/pos", rr.Points2D.from_fields(colors=[color], radii=[radius]), static=True)
        self.rec.send_columns(f"{path}/pos", indexes=indexes, columns=rr.Points2D.columns(positions=xy[ok]))

    def log_raw_walks(self, poses: pd.DataFrame) -> None:
        """Raw PDR poses (walk_id, step, t_s, x_m, y_m), each walk in its own frame: ``raw/<walk>``."""
        for wid, g in _walk_groups(poses):
            self._log_walk(f"{RAW}/{entity_part(wid)}", wid, g)
            self._count("raw_walks")

    def log_truth(self, truth_poses: pd.DataFrame) -> None:
        """True building-frame poses per step: ``floor/truth/<walk>``."""
        for wid, g in _walk_groups(truth_poses):
            self._log_walk(f"{FLOOR}/truth/{entity_part(wid)}", wid, g, radius=0.25)
            self._count("truth_walks")

    def log_optimized(self, poses: pd.DataFrame, kind: str = "optimized") -> None:
        """Poses in the common frame (``kind`` "optimized" or "initial"): ``floor/<kind>/<walk>``; a walk
        not linked to the map (``linked`` false) under ``floor/<kind>_unlinked/<walk>``, which the default
        layout does not show (its frame is arbitrary)."""
        for wid, g in _walk_groups(poses):
            placed = "linked" not in g or bool(g["linked"].iloc[0])
            path = f"{FLOOR}/{kind if placed else kind + '_unlinked'}/{entity_part(wid)}"
            if kind == "optimized":
                self._log_walk(path, wid, g)
            else:  # the initial guess: path only, no per-step point
                xy = _finite_rows(_xy(g))
                self.rec.log(path, self.rr.LineStrips2D([xy], colors=[self._color(wid)], radii=[0.04]),
                             static=True)
            self._count(f"{kind}_walks")

    def log_venue(self, venue: dict | None) -> None:
        """Floor plan: ``venue["walls"]`` = [[x0, y0, x1, y1], ...] (m) -> ``floor/plan/walls``."""
        walls = np.asarray((venue or {}).get("walls") or [], dtype=np.float64)
        if walls.size == 0:
            return
        strips = walls.reshape(-1, 2, 2)
        self.rec.log(f"{FLOOR}/plan/walls", self.rr.LineStrips2D(strips, colors=[(90, 90, 90)], radii=[0.1]),
                     static=True)
        self._count("walls", len(strips))

    def log_plan_image(self, pixels: np.ndarray, extent_m: Sequence[float]) -> None:
        """The floor plan's raster image (rows, cols, 3 or 4 uint8; row 0 the top) over ``extent_m`` (x0, y0,
        x1, y1 m) -> ``floor/plan/image``, under everything else."""
        x0, y0, x1, y1 = (float(v) for v in extent_m)
        rows, cols = pixels.shape[:2]
        path = f"{FLOOR}/plan/image"
        self.rec.log(path, self.rr.Transform3D(translation=[x0, y1, 0.0],
                                               scale=[(x1 - x0) / cols, -(y1 - y0) / rows, 1.0]), static=True)
        model = "RGBA" if pixels.shape[2] == 4 else "RGB"
        self.rec.log(path, self.rr.Image(pixels, color_model=model, opacity=0.5, draw_order=-10.0), static=True)
        self._count("plan_image")

    def log_fixes(self, fixes: pd.DataFrame) -> None:
        """Waypoints / position fixes (walk_id, x_m, y_m, optional label), building frame: crosses in the
        walk's colour under ``floor/fixes/<walk>``, labelled (e.g. "wp3") on hover."""
        if fixes is None or len(fixes) == 0:
            return
        for wid, g in _walk_groups(fixes):
            xy = _xy(g)
            ok = np.isfinite(xy).all(axis=1)
            if not ok.any():
                continue
            labels = g["label"].astype(str).to_numpy()[ok].tolist() if "label" in g else None
            self.rec.log(f"{FLOOR}/fixes/{entity_part(wid)}",
                         self.rr.Points2D(xy[ok], colors=[self._color(wid)], radii=[0.45], labels=labels,
                                          show_labels=False),
                         static=True)
            self._count("fixes", int(ok.sum()))

    def log_alignment(self, theta_rad: float, translation_xy: Sequence[float] | np.ndarray,
                      parts: Sequence[str] = ALIGNED_PARTS) -> None:
        """Place the optimiser's frame in the building frame: ``building = R(theta) @ map + t``.

        Logged as a static transform on ``floor/<part>`` (the data under it stays in its own frame), so the
        optimised walks, vicinity factors and radio map overlay the truth and floor plan.
        """
        tr = self.rr.Transform3D(translation=[float(translation_xy[0]), float(translation_xy[1]), 0.0],
                                 rotation=self.rr.RotationAxisAngle(axis=[0.0, 0.0, 1.0], radians=float(theta_rad)))
        for part in parts:
            self.rec.log(f"{FLOOR}/{part}", tr, static=True)

    # -------------------------------------------------------------- optimisation
    def log_vicinity(self, pairs: pd.DataFrame, node_xy: np.ndarray, max_lines: int = MAX_VICINITY_LINES,
                     error_scale: float | None = None, seed: int = 0) -> int:
        """Vicinity factors as segments between their nodes' positions ``node_xy`` (n_nodes, 2), coloured
        by ``final_error`` (blue low -> red at ``error_scale``, default the 95th percentile), labelled with
        their kind (and "anisotropic" for along/across factors) and error.

        When there are more than ``max_lines`` pairs, the worst 20 % of the sample are the pairs with the
        largest errors (so false matches stay visible) and the rest a seeded random sample. Returns the
        number of segments logged.
        """
        if pairs is None or len(pairs) == 0 or not {"node_k", "node_q"} <= set(pairs.columns):
            return 0
        k = pairs["node_k"].to_numpy(dtype=np.int64)
        q = pairs["node_q"].to_numpy(dtype=np.int64)
        ok = (k >= 0) & (q >= 0) & (k < len(node_xy)) & (q < len(node_xy))
        idx = np.flatnonzero(ok)
        err = (pairs["final_error"].to_numpy(dtype=np.float64) if "final_error" in pairs
               else np.full(len(pairs), np.nan))
        if len(idx) > max_lines:
            n_worst = max_lines // 5
            by_err = idx[np.argsort(-np.nan_to_num(err[idx], nan=np.inf), kind="stable")]
            worst = by_err[:n_worst]
            rest = np.setdiff1d(idx, worst)
            rng = np.random.default_rng(seed)
            idx = np.sort(np.r_[worst, rng.choice(rest, max_lines - n_worst, replace=False)])
        seg = np.stack([node_xy[k[idx]], node_xy[q[idx]]], axis=1)
        good = np.isfinite(seg).all(axis=(1, 2))
        seg, idx = seg[good], idx[good]
        if len(idx) == 0:
            return 0
        e = err[idx]
        if error_scale is None:
            fin = e[np.isfinite(e)]
            error_scale = float(np.percentile(fin, 95)) if fin.size else 1.0
        kind = pairs["kind"].astype(str).to_numpy()[idx] if "kind" in pairs else np.full(len(idx), "")
        if "anisotropic" in pairs:  # an along/across factor (VicinityConfig.across_ratio)
            kind = np.where(pairs["anisotropic"].to_numpy(bool)[idx], np.char.add(kind.astype(str), " anisotropic"),
                            kind)
        labels = [f"{kd} e={v:.3g}" for kd, v in zip(kind, e)]
        self.rec.log(f"{FLOOR}/vicinity", self.rr.LineStrips2D(seg, colors=error_colors(e, error_scale),
                                                                radii=[0.05], labels=labels, show_labels=False),
                     static=True)
        self._count("vicinity_lines", len(idx))
        return len(idx)

    def log_cost_history(self, cost: Sequence[float] | np.ndarray, iteration: np.ndarray | None = None) -> None:
        """The optimiser's cost per iteration (timeline "iteration"): ``plots/optimize/cost``."""
        c = np.asarray(cost, dtype=np.float64)
        if c.size == 0:
            return
        it = np.arange(c.size) if iteration is None else np.asarray(iteration, dtype=np.int64)
        path = f"{PLOTS}/optimize/cost"
        self.rec.log(path, self.rr.SeriesLines(names="cost", colors=[(31, 119, 180)]), static=True)
        self.rec.send_columns(path, indexes=[self.rr.TimeColumn(TIMELINE_ITERATION, sequence=it)],
                              columns=self.rr.Scalars.columns(scalars=c))
        self._count("cost_points", int(c.size))

    def log_cost(self, iteration: int, cost: float) -> None:
        """One optimiser iteration while it runs (the stage's progress hook)."""
        self.rec.set_time(TIMELINE_ITERATION, sequence=int(iteration))
        self.rec.log(f"{PLOTS}/optimize/cost", self.rr.Scalars(float(cost)))
        self._count("cost_points")

    def _series(self, path: str, name: str, color: tuple[int, int, int], steps: np.ndarray,
                values: np.ndarray, timeline: str = TIMELINE_STEP) -> None:
        ok = np.isfinite(values)
        if not ok.any():
            return
        self.rec.log(path, self.rr.SeriesLines(names=name, colors=[color]), static=True)
        self.rec.send_columns(path, indexes=[self.rr.TimeColumn(timeline, sequence=steps[ok])],
                              columns=self.rr.Scalars.columns(scalars=values[ok]))

    def log_residuals(self, raw: pd.DataFrame, optimized: pd.DataFrame, pairs: pd.DataFrame | None) -> None:
        """Per-step residuals (timeline "step"): ``plots/residuals/odometry/<walk>`` — the length of the
        difference between the raw and the optimised step (each in the previous pose's frame, m) — and
        ``plots/residuals/vicinity/<walk>`` — the final error of each vicinity factor at its first node.
        ``raw`` and ``optimized`` have the same rows (node ids)."""
        if len(raw) != len(optimized) or len(raw) == 0:
            return
        walk = raw["walk_id"].astype(str).to_numpy()
        steps = raw["step"].to_numpy(dtype=np.int64) if "step" in raw else np.arange(len(raw))
        res = np.full(len(raw), np.nan)
        same = np.r_[False, walk[1:] == walk[:-1]]
        for df, sign in ((raw, -1.0), (optimized, 1.0)):
            xy = _xy(df)
            h = df["heading_rad"].to_numpy(dtype=np.float64)
            d = np.zeros_like(xy)
            d[1:] = xy[1:] - xy[:-1]
            c, s = np.cos(h), np.sin(h)
            local = np.zeros_like(xy)  # the step in the previous pose's frame
            local[1:, 0] = c[:-1] * d[1:, 0] + s[:-1] * d[1:, 1]
            local[1:, 1] = -s[:-1] * d[1:, 0] + c[:-1] * d[1:, 1]
            if sign < 0:
                base = local
            else:
                res = np.where(same, np.hypot(*(local - base).T), np.nan)
        for wid in dict.fromkeys(walk):
            m = walk == wid
            self._series(f"{PLOTS}/residuals/odometry/{entity_part(wid)}", wid, self._color(wid), steps[m], res[m])
            self._count("odometry_series")
        if pairs is None or len(pairs) == 0 or "final_error" not in pairs or "node_k" not in pairs:
            return
        k = pairs["node_k"].to_numpy(dtype=np.int64)
        k_ok = (k >= 0) & (k < len(raw))
        e = pairs["final_error"].to_numpy(dtype=np.float64)
        pw = walk[k[k_ok]]
        ps = steps[k[k_ok]]
        pe = e[k_ok]
        for wid in dict.fromkeys(pw):
            m = pw == wid
            o = np.argsort(ps[m], kind="stable")
            self._series(f"{PLOTS}/residuals/vicinity/{entity_part(wid)}", wid, self._color(wid),
                         ps[m][o], pe[m][o])
            self._count("vicinity_series")

    # -------------------------------------------------------------- radio map
    def log_radiomap(self, cells: pd.DataFrame, cell_size_m: float | None = None,
                     origin_xy_m: Sequence[float] | None = None, strongest: int = STRONGEST_APS,
                     max_aps: int = MAX_TENSOR_APS) -> None:
        """The radio map's long table (cell, ix, iy, bssid, count, rssi_mean_dbm, rssi_std_db, ...).

        ``map/tensor/{mean,std,count}``: (AP, y, x) tensors (AP slider in the tensor view; the ``max_aps``
        most-heard APs); ``floor/map/coverage``: readings per cell; ``floor/map/strongest/<ap>``: mean RSSI
        of the ``strongest`` APs (highest peak cell mean) as images over the plan.
        """
        need = {"ix", "iy", "bssid"}
        if cells is None or len(cells) == 0 or not need <= set(cells.columns):
            log.info("radio map table lacks %s; not logged", sorted(need - set(cells.columns)) if cells is not None
                     else "rows")
            return
        rr = self.rr
        ix = cells["ix"].to_numpy(dtype=np.int64)
        iy = cells["iy"].to_numpy(dtype=np.int64)
        x0, y0 = int(ix.min()), int(iy.min())
        nx, ny = int(ix.max()) - x0 + 1, int(iy.max()) - y0 + 1
        s = float(cell_size_m) if cell_size_m else _infer_cell_size(cells)
        if origin_xy_m is not None:
            ox, oy = float(origin_xy_m[0]) + x0 * s, float(origin_xy_m[1]) + y0 * s
        elif "x_m" in cells and "y_m" in cells:  # x_m, y_m are cell centres
            ox = float(np.nanmin(cells["x_m"].to_numpy(dtype=np.float64) - (ix - x0 + 0.5) * s))
            oy = float(np.nanmin(cells["y_m"].to_numpy(dtype=np.float64) - (iy - y0 + 0.5) * s))
        else:
            ox, oy = x0 * s, y0 * s
        count = (cells["count"].to_numpy(dtype=np.float64) if "count" in cells else np.ones(len(cells)))
        mean = (cells["rssi_mean_dbm"].to_numpy(dtype=np.float64) if "rssi_mean_dbm" in cells
                else np.full(len(cells), np.nan))
        std = (cells["rssi_std_db"].to_numpy(dtype=np.float64) if "rssi_std_db" in cells
               else np.full(len(cells), np.nan))
        codes, aps = pd.factorize(cells["bssid"].astype(str), sort=True)
        heard = np.bincount(codes, weights=count, minlength=len(aps))
        # the tensors are (AP, y, x) over the map's bounding box: fewer APs on a large map (bounded memory)
        max_aps = max(1, min(max_aps, TENSOR_MAX_ELEMS // max(nx * ny, 1)))
        keep_aps = np.sort(np.argsort(-heard, kind="stable")[:max_aps])
        remap = np.full(len(aps), -1)
        remap[keep_aps] = np.arange(len(keep_aps))
        a = remap[codes]
        sel = a >= 0
        r, c = iy[sel] - y0, ix[sel] - x0
        shape = (len(keep_aps), ny, nx)
        t_mean = np.full(shape, np.nan, dtype=np.float32)
        t_std = np.full(shape, np.nan, dtype=np.float32)
        t_cnt = np.zeros(shape, dtype=np.float32)
        t_mean[a[sel], r, c] = mean[sel]
        t_std[a[sel], r, c] = std[sel]
        t_cnt[a[sel], r, c] = count[sel]
        names = ["ap", "y", "x"]
        # cells never heard: -110 dBm (the fill value) / 0, so the tensor colour scale stays meaningful
        self.rec.log(f"{MAP}/tensor/mean", rr.Tensor(np.nan_to_num(t_mean, nan=-110.0), dim_names=names),
                     static=True)
        self.rec.log(f"{MAP}/tensor/std", rr.Tensor(np.nan_to_num(t_std, nan=0.0), dim_names=names), static=True)
        self.rec.log(f"{MAP}/tensor/count", rr.Tensor(t_cnt, dim_names=names), static=True)
        table = "| AP index | BSSID | readings |\n|---:|---|---:|\n" + "".join(
            f"| {i} | {aps[j]} | {int(heard[j])} |\n" for i, j in enumerate(keep_aps))
        self.rec.log(f"{MAP}/aps", rr.TextDocument(table, media_type=rr.MediaType.MARKDOWN), static=True)
        placement = rr.Transform3D(translation=[ox, oy, 0.0], scale=[s, s, 1.0])
        # coverage: readings per cell over all APs
        cov = np.zeros((ny, nx))
        np.add.at(cov, (iy - y0, ix - x0), count)
        cov_img = colormap(np.where(cov > 0, np.log10(np.maximum(cov, 1)), np.nan), 0.0,
                           float(np.log10(max(cov.max(), 10))))
        self.rec.log(f"{FLOOR}/map/coverage", placement, static=True)
        self.rec.log(f"{FLOOR}/map/coverage", rr.Image(cov_img, color_model="RGBA", opacity=0.8, draw_order=-5.0),
                     static=True)
        peak = np.nanmax(np.where(np.isnan(t_mean), -np.inf, t_mean), axis=(1, 2))
        order = [int(j) for j in np.argsort(-peak, kind="stable")[:strongest] if np.isfinite(peak[j])]
        shown = t_mean[order][np.isfinite(t_mean[order])] if order else np.zeros(0)
        lo, hi = (float(shown.min()), float(shown.max())) if shown.size else (-100.0, -30.0)  # no clipping
        for rank, j in enumerate(order):
            path = f"{FLOOR}/map/strongest/{rank:02d}_{entity_part(aps[keep_aps[j]])}"
            img = colormap(t_mean[j], lo, hi)
            self.rec.log(path, placement, static=True)
            self.rec.log(path, rr.Image(img, color_model="RGBA", opacity=0.9, draw_order=-4.0 + 0.01 * rank),
                         static=True)
        self._has["map"] = True
        self._count("map_aps", len(keep_aps))
        self._count("map_cells", int(len(np.unique(np.c_[ix, iy], axis=0))))

    # -------------------------------------------------------------- evaluation
    def log_tracks(self, tracks: pd.DataFrame) -> int:
        """Localization tracks: per scan the estimated and true positions of a test walk, per map and
        localizer. Recognised columns (others ignored; any missing -> that part skipped): ``map``,
        ``localizer``, ``walk_id``, ``t_s``, estimated ``x_est_m``/``y_est_m`` (or ``est_x_m``, ``pred_x_m``,
        ``x_pred_m``, ``x_m``), true ``x_true_m``/``y_true_m`` (or ``true_x_m``, ``ref_x_m``, ``x_ref_m``),
        ``error_m``. Returns the number of tracks logged."""
        if tracks is None or len(tracks) == 0:
            return 0
        est = _find_xy(tracks, ("x_est_m", "est_x_m", "pred_x_m", "x_pred_m", "x_m"))
        true = _find_xy(tracks, ("x_true_m", "true_x_m", "ref_x_m", "x_ref_m"))
        if est is None and true is None:
            log.info("tracks table has no position columns (%s); not logged", list(tracks.columns))
            return 0
        keys = [c for c in ("map", "localizer", "walk_id") if c in tracks.columns]
        groups = tracks.groupby(keys, sort=False) if keys else [((), tracks)]
        n = 0
        for key, g in groups:
            key = key if isinstance(key, tuple) else (key,)
            parts = [entity_part(v) for v in key]
            base = "/".join([f"{FLOOR}/eval", *parts]) if parts else f"{FLOOR}/eval/track"
            walk_id = str(g["walk_id"].iloc[0]) if "walk_id" in g else "track"
            color = self._color(walk_id)
            if "t_s" in g:
                g = g.sort_values("t_s", kind="stable")
            scan = np.arange(len(g))
            e_xy = g[list(est)].to_numpy(dtype=np.float64) if est else None
            t_xy = g[list(true)].to_numpy(dtype=np.float64) if true else None
            for name, xy, col in (("estimated", e_xy, color), ("true", t_xy, (40, 40, 40))):
                if xy is None:
                    continue
                ok = np.isfinite(xy).all(axis=1)
                if not ok.any():
                    continue
                self.rec.log(f"{base}/{name}", self.rr.LineStrips2D([xy[ok]], colors=[col], radii=[0.06]),
                             static=True)
                self.rec.log(f"{base}/{name}/pos", self.rr.Points2D.from_fields(colors=[col], radii=[0.3]),
                             static=True)
                self.rec.send_columns(f"{base}/{name}/pos",
                                      indexes=[self.rr.TimeColumn(TIMELINE_SCAN, sequence=scan[ok])],
                                      columns=self.rr.Points2D.columns(positions=xy[ok]))
            if "error_m" in g:
                err = g["error_m"].to_numpy(dtype=np.float64)
            elif e_xy is not None and t_xy is not None:
                err = np.hypot(*(e_xy - t_xy).T)
            else:
                err = None
            if err is not None:
                label = "/".join(str(v) for v in key) or "error"
                self._series("/".join([f"{PLOTS}/eval", *parts]) if parts else f"{PLOTS}/eval/track", label,
                             color, scan, err, timeline=TIMELINE_SCAN)
            n += 1
        self._has["eval"] = n > 0
        self._count("eval_tracks", n)
        return n

    def log_particles(self, localizer: str, scan: int, xy: np.ndarray, weights: np.ndarray | None = None,
                      xi: float | None = None) -> None:
        """A particle cloud of a particle-filter localizer (e.g. SLAC) at one scan, and its ξ when given."""
        xy = np.asarray(xy, dtype=np.float64)
        self.rec.set_time(TIMELINE_SCAN, sequence=int(scan))
        radii = None
        if weights is not None:
            w = np.asarray(weights, dtype=np.float64)
            radii = 0.05 + 0.4 * w / max(float(w.max()), 1e-12)
        self.rec.log(f"{FLOOR}/eval/particles/{entity_part(localizer)}",
                     self.rr.Points2D(xy, radii=radii, colors=[(200, 80, 200)]))
        if xi is not None:
            self.rec.log(f"{PLOTS}/eval/xi/{entity_part(localizer)}", self.rr.Scalars(float(xi)))
        self._has["eval"] = True


def _move_into_place(src: Path, dst: Path) -> None:
    """Move ``src`` to ``dst`` so that ``dst`` is never half written (copy beside it, then rename); ``dst``
    gets the mode of any new file (``src`` came from mkstemp: 0600)."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    from rmbuild.io.atomic import new_file_mode

    os.chmod(src, new_file_mode())
    try:
        os.replace(src, dst)
        return
    except OSError:  # another file system
        pass
    part = dst.with_name(f".{dst.name}.{os.getpid()}.part")
    try:
        shutil.copyfile(src, part)
        os.replace(part, dst)
    finally:
        part.unlink(missing_ok=True)
        src.unlink(missing_ok=True)


def _find_xy(df: pd.DataFrame, x_names: Sequence[str]) -> tuple[str, str] | None:
    for x in x_names:
        y = x.replace("x", "y", 1)
        if x in df.columns and y in df.columns:
            return x, y
    return None


def _infer_cell_size(cells: pd.DataFrame) -> float:
    """Cell size from x_m over ix (cell centres); 1 m when it cannot be told."""
    if "x_m" in cells and cells["ix"].nunique() > 1:
        d = cells.drop_duplicates("ix").sort_values("ix")
        dx = np.diff(d["x_m"].to_numpy(dtype=np.float64)) / np.diff(d["ix"].to_numpy(dtype=np.float64))
        dx = dx[np.isfinite(dx) & (dx > 0)]
        if dx.size:
            return float(np.median(dx))
    return 1.0


def open_viewer(target: ViewTarget | None, recording_name: str | None = None) -> Viewer:
    """A :class:`RerunViewer` for ``target``, or a :class:`NullViewer` when ``target`` is None."""
    if target is None:
        return NullViewer()
    t0 = time.perf_counter()
    v = RerunViewer(target, recording_name)
    log.debug("rerun viewer (%s) ready in %.2f s", target.mode, time.perf_counter() - t0)
    return v


# ------------------------------------------------------------------ reading recordings back
def rrd_entities(path: str | Path) -> dict[str, dict]:
    """Summary of a saved .rrd: entity path -> {"rows", "static", "timelines", "components",
    "instances"} (``instances``: per component, the total number of values, e.g. points or strips)."""
    import pyarrow as pa
    import pyarrow.compute as pc

    _import_rerun()
    from rerun.chunk import RrdReader

    out: dict[str, dict] = {}
    for chunk in RrdReader(path).stream():
        ent = out.setdefault(chunk.entity_path, {"rows": 0, "static": False, "timelines": set(),
                                                 "components": set(), "instances": {}})
        ent["rows"] += chunk.num_rows
        ent["static"] |= chunk.is_static
        ent["timelines"].update(chunk.timeline_names)
        rb = chunk.to_record_batch()
        for name in rb.schema.names:
            if ":" not in name:
                continue
            ent["components"].add(name)
            col = rb.column(name)
            if pa.types.is_list(col.type) or pa.types.is_large_list(col.type):
                n = int(pc.sum(pc.list_value_length(col)).as_py() or 0)
            else:
                n = len(col) - col.null_count
            ent["instances"][name] = ent["instances"].get(name, 0) + n
    for ent in out.values():
        ent["timelines"] = sorted(ent["timelines"])
        ent["components"] = sorted(ent["components"])
    return dict(sorted(out.items()))


def format_entities(entities: dict[str, dict]) -> str:
    """A plain-text listing of :func:`rrd_entities` (one line per entity)."""
    lines = [f"{'entity':60s} {'rows':>6s}  static  timelines        components"]
    for path, e in entities.items():
        comps = ", ".join(f"{c.split(':')[0]}:{c.split(':')[1]}={e['instances'].get(c, 0)}"
                          for c in e["components"] if not c.endswith(("colors", "radii", "show_labels",
                                                                      "draw_order", "names", "widths")))
        lines.append(f"{path:60s} {e['rows']:6d}  {'yes' if e['static'] else 'no ':6s}  "
                     f"{','.join(e['timelines']) or '-':16s} {comps}")
    return "\n".join(lines) + "\n"
