"""`rmbuild view`: the saved .rrd read back holds what the workspace holds; the null viewer; the bridge."""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Protocol

import numpy as np
import pandas as pd
import pytest
from cli_util import run_cli
from test_viz_util import DOC_IMG, WRITE_DOC_IMAGES, build_workspace

from rmbuild.errors import RmbuildError
from rmbuild.io.workspace import Workspace
from rmbuild.viz import NullViewer, ViewTarget, ensure_viewer, open_viewer
from rmbuild.viz.rerun_bridge import MAX_VICINITY_LINES, check_version, format_entities, rrd_entities


@pytest.fixture(scope="module")
def ws_full(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny workspace with every stage whose command exists (at least ingest + optimize)."""
    return build_workspace(tmp_path_factory.mktemp("viz"), ("optimize", "export-map", "evaluate"))


def _positions(ents: dict, path: str) -> int:
    return ents[path]["instances"].get("Points2D:positions", 0)


def test_view_save_matches_workspace(ws_full: Path, tmp_path: Path, capsys) -> None:
    rrd = tmp_path / "out.rrd"
    r = run_cli(capsys, "view", "-w", ws_full, "--save", rrd)
    assert r.code == 0, r.err
    assert str(rrd) in r.out and rrd.is_file()
    assert not list(tmp_path.glob(".*.tmp"))  # written atomically
    ents = rrd_entities(rrd)
    ws = Workspace.open(ws_full)
    ds = ws.read_dataset()
    n_walks = len(ds.walks)
    raw = [p for p in ents if p.startswith("/raw/") and p.count("/") == 2]
    opt = [p for p in ents if p.startswith("/floor/optimized/") and p.count("/") == 3]
    assert len(raw) == n_walks and len(opt) == n_walks
    for wid, g in ds.poses.groupby("walk_id"):
        assert _positions(ents, f"/raw/{wid}/pos") == len(g)
        assert _positions(ents, f"/floor/optimized/{wid}/pos") == len(g)
        assert ents[f"/raw/{wid}/pos"]["timelines"] == ["step", "t_s"]
    assert _positions(ents, "/floor/truth/" + ds.walk_ids()[0] + "/pos") == int(
        (ds.truth_poses["walk_id"] == ds.walk_ids()[0]).sum())
    assert ents["/floor/plan/walls"]["instances"]["LineStrips2D:strips"] == len(ds.venue["walls"])
    assert len(ds.fixes) > 0  # the waypoints: crosses in the walk's colour, building frame
    assert sum(_positions(ents, p) for p in ents if p.startswith("/floor/fixes/")) == len(ds.fixes)
    pairs = ws.read_table("optimize.pairs")
    assert ents["/floor/vicinity"]["instances"]["LineStrips2D:strips"] == min(len(pairs), MAX_VICINITY_LINES)
    hist = ws.read_table("optimize.history")
    assert ents["/plots/optimize/cost"]["instances"]["Scalars:scalars"] == len(hist)
    assert sum(1 for p in ents if p.startswith("/plots/residuals/odometry/")) == n_walks
    if ws.has("map"):
        cells = ws.read_table("map.cells")
        assert "/map/tensor/mean" in ents and "/floor/map/coverage" in ents
        assert len([p for p in ents if p.startswith("/floor/map/strongest/")]) == min(6, cells["bssid"].nunique())
    if ws.has("evaluate") and ws.exists("evaluate.tracks"):
        assert any(p.startswith("/floor/eval/") for p in ents)
    listing = format_entities(ents)
    assert "/floor/vicinity" in listing
    if WRITE_DOC_IMAGES:
        DOC_IMG.mkdir(parents=True, exist_ok=True)
        (DOC_IMG / "rrd_entities.txt").write_text(
            "# `rmbuild view -w WS --save view.rrd` on `simulate --preset tiny --seed 7`"
            " (written by tests/test_viz.py)\n"
            + listing)


def test_view_defaults_to_save_without_display(ws_full: Path, tmp_path: Path, capsys, monkeypatch) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    ws = tmp_path / "ws"
    shutil.copytree(ws_full, ws)
    r = run_cli(capsys, "view", "-w", ws)
    assert r.code == 0, r.err
    assert (ws / "view.rrd").is_file()
    mask = os.umask(0)
    os.umask(mask)
    assert (ws / "view.rrd").stat().st_mode & 0o777 == 0o666 & ~mask  # like any new file, not mkstemp's 0600


def test_spawn_without_a_display_is_a_one_line_error(ws_full: Path, capsys, monkeypatch) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr("rmbuild.viz.rerun_bridge.sys.platform", "linux")
    for args in (["view", "-w", ws_full, "--spawn"], ["evaluate", "-w", ws_full, "--rerun", "spawn", "--force"]):
        r = run_cli(capsys, *args)
        assert r.code == 2 and len(r.err.strip().splitlines()) == 1, r.err
        assert "--spawn needs a display" in r.err and "--save" in r.err


def test_view_ingest_only_workspace(tmp_path: Path, capsys) -> None:
    ws = build_workspace(tmp_path, stages=())
    r = run_cli(capsys, "view", "-w", ws, "--save", tmp_path / "v.rrd")
    assert r.code == 0, r.err
    assert "skipped optimize" in r.out
    ents = rrd_entities(tmp_path / "v.rrd")
    assert any(p.startswith("/raw/") for p in ents)
    assert not any(p.startswith("/floor/optimized") for p in ents)


def test_view_usage_errors(tmp_path: Path, capsys) -> None:
    r = run_cli(capsys, "view", "-w", tmp_path / "nothing", "--save", tmp_path / "x.rrd")
    assert r.code == 2 and "not an rmbuild workspace" in r.err
    r = run_cli(capsys, "view", "-w", tmp_path, "--spawn", "--serve")
    assert r.code == 2


def _public_methods(cls: type) -> set[str]:
    return {n for n in dir(cls) if callable(getattr(cls, n)) and (not n.startswith("_") or n in ("__enter__",
                                                                                               "__exit__"))}


def test_viewer_contract_is_explicit() -> None:
    """The protocol, the do-nothing viewer and the rerun viewer have the same methods (and signatures), so a
    misspelt call fails whether viewing is on or off."""
    import inspect

    from rmbuild.viz import RerunViewer, Viewer

    proto = {n for n in _public_methods(Viewer) if n not in dir(Protocol)} | {"__enter__", "__exit__"}
    assert proto >= {"log_cost", "log_vicinity", "log_tracks", "set_walks", "close", "flush"}
    assert _public_methods(NullViewer) == proto
    assert {n for n in _public_methods(RerunViewer) if not n.startswith("_") or n.startswith("__e")} == proto
    for n in proto - {"__enter__", "__exit__"}:
        want = inspect.signature(getattr(Viewer, n))
        assert inspect.signature(getattr(NullViewer, n)) == want, n
        assert inspect.signature(getattr(RerunViewer, n)) == want, n
    assert isinstance(NullViewer(), Viewer)


def test_null_viewer_accepts_everything() -> None:
    v = ensure_viewer(None)
    assert isinstance(v, NullViewer) and not v.enabled
    v.set_walks(["a"])
    v.log_raw_walks(pd.DataFrame())
    v.log_cost(3, 1.5)
    v.log_particles("slac", 1, np.zeros((3, 2)))
    assert v.close() is None
    assert isinstance(open_viewer(None), NullViewer)
    with pytest.raises(AttributeError):
        v.not_a_method  # noqa: B018


def test_version_check() -> None:
    check_version("0.41.3")
    with pytest.raises(RmbuildError, match="0.41"):
        check_version("0.40.1")


def test_bridge_radiomap_tracks_and_live_hooks(tmp_path: Path) -> None:
    """Tables with missing columns are logged as far as they go; live hooks land on their timelines."""
    rng = np.random.default_rng(0)
    ix, iy = np.meshgrid(np.arange(6), np.arange(4))
    rows = []
    for ap in ("aa:00", "bb:00", "cc:00"):
        rows.append(pd.DataFrame({"cell": np.arange(24), "ix": ix.ravel(), "iy": iy.ravel(),
                                  "x_m": ix.ravel() * 2 + 1.0, "y_m": iy.ravel() * 2 + 1.0, "bssid": ap,
                                  "count": rng.integers(1, 5, 24), "rssi_mean_dbm": rng.uniform(-90, -40, 24)}))
    cells = pd.concat(rows, ignore_index=True)  # no rssi_std_db column
    tracks = pd.DataFrame({"localizer": "knn", "walk_id": "w9", "t_s": np.arange(5.0),
                           "x_est_m": np.arange(5.0), "y_est_m": np.zeros(5)})  # no truth, no map column
    path = tmp_path / "bridge.rrd"
    with open_viewer(ViewTarget("save", path)) as v:
        v.log_radiomap(cells, strongest=2)
        assert v.log_tracks(tracks) == 1
        assert v.log_tracks(pd.DataFrame({"walk_id": ["a"]})) == 0
        for i, c in enumerate((10.0, 5.0, 4.0)):
            v.log_cost(i, c)
        v.log_particles("slac", 2, rng.normal(size=(50, 2)), rng.uniform(size=50), xi=0.7)
    ents = rrd_entities(path)
    assert ents["/plots/optimize/cost"]["instances"]["Scalars:scalars"] == 3
    assert "iteration" in ents["/plots/optimize/cost"]["timelines"]
    assert ents["/map/tensor/mean"]["instances"]["Tensor:data"] == 1
    assert len([p for p in ents if p.startswith("/floor/map/strongest/")]) == 2
    assert _positions(ents, "/floor/eval/knn/w9/estimated/pos") == 5
    assert _positions(ents, "/floor/eval/particles/slac") == 50
    assert "/plots/eval/xi/slac" in ents


@pytest.mark.parametrize("t0, kind", [(1.5e9, "timestamp"), (0.0, "duration")])
def test_walk_times_are_a_timestamp_when_absolute(t0: float, kind: str, tmp_path: Path) -> None:
    """Epoch seconds (MS ILC, IPIN) show as dates in the viewer, not as a 47-year duration."""
    import pyarrow as pa
    from rerun.chunk import RrdReader

    poses = pd.DataFrame({"walk_id": "w", "step": np.arange(5), "t_s": t0 + 0.5 * np.arange(5),
                          "x_m": np.arange(5.0), "y_m": np.zeros(5), "heading_rad": np.zeros(5)})
    with open_viewer(ViewTarget("save", tmp_path / "t.rrd")) as v:
        v.log_raw_walks(poses)
    types = {rb.schema.field("t_s").type for c in RrdReader(tmp_path / "t.rrd").stream()
             if "t_s" in (rb := c.to_record_batch()).schema.names}
    assert len(types) == 1
    t = types.pop()
    assert pa.types.is_timestamp(t) if kind == "timestamp" else pa.types.is_duration(t), t


def test_interrupted_save_leaves_no_recording(tmp_path: Path) -> None:
    path = tmp_path / "x.rrd"
    with pytest.raises(RuntimeError), open_viewer(ViewTarget("save", path)) as v:
        v.log_cost(0, 1.0)
        raise RuntimeError("boom")
    assert not path.exists() and not list(tmp_path.iterdir())


def test_vicinity_labels_name_the_anisotropic_pairs(tmp_path: Path) -> None:
    """Each vicinity segment's label carries its kind, "anisotropic" for an along/across factor, and its
    error."""
    pairs = pd.DataFrame({"node_k": [0, 1, 2], "node_q": [3, 4, 5], "kind": ["cross", "cross", "within"],
                          "final_error": [0.1, 0.5, 0.2], "anisotropic": [True, False, True]})
    node_xy = np.arange(12.0).reshape(6, 2)
    logged = []
    with open_viewer(ViewTarget("save", tmp_path / "v.rrd")) as v:
        log = v.rec.log
        v.rec.log = lambda path, ent, **kw: (logged.append((path, ent)), log(path, ent, **kw))[1]
        assert v.log_vicinity(pairs, node_xy) == 3
    (ent,) = [e for p, e in logged if p.endswith("/vicinity")]
    assert ent.labels.pa_array.to_pylist() == ["cross anisotropic e=0.1", "cross e=0.5", "within anisotropic e=0.2"]


def test_walks_placed_on_their_waypoints_without_truth() -> None:
    """Real data has waypoints, not true paths: the report fits each raw walk (and the optimised map) to
    them, so both panels are in the building frame and the waypoints can be drawn."""
    from rmbuild.viz.align import frame_to_fixes, per_walk_to_fixes, poses_at_fixes

    t = np.arange(20.0)
    local = np.c_[t * 0.7, np.sin(t / 3.0) * 2]
    a, shift = 0.6, np.array([30.0, -4.0])
    r = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    building = local @ r.T + shift
    poses = pd.DataFrame({"walk_id": "w", "t_s": t, "x_m": local[:, 0], "y_m": local[:, 1]})
    ft = np.array([0.0, 6.5, 13.0, 19.0, 40.0])  # the last one is long after the walk: not used
    fx = np.c_[np.interp(ft, t, building[:, 0]), np.interp(ft, t, building[:, 1])]
    fixes = pd.DataFrame({"walk_id": "w", "t_s": ft, "x_m": fx[:, 0], "y_m": fx[:, 1]})
    assert np.isnan(poses_at_fixes(poses, fixes)[-1]).all()
    placed = per_walk_to_fixes(poses, fixes)
    assert placed is not None
    np.testing.assert_allclose(placed[["x_m", "y_m"]].to_numpy(), building, atol=0.05)
    rt = frame_to_fixes(poses, fixes)
    assert rt is not None and np.allclose(rt[0], r, atol=1e-3) and np.allclose(rt[1], shift, atol=0.05)
    assert frame_to_fixes(poses, fixes, "anchors") is None  # already in the building frame
    assert per_walk_to_fixes(poses, fixes.iloc[:1]) is None  # one waypoint cannot fix a rotation
