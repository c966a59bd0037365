"""`rmbuild export-map`."""

from __future__ import annotations

import click

from rmbuild.cli.options import common_options, floor_option, rerun_option, stage_viewer, start, workspace_option


@click.command("export-map")
@workspace_option
@click.option("--anchors", "anchors_path", type=click.Path(dir_okay=False), default=None,
              help="CSV/Parquet with walk_id, t_s, x_m, y_m: place the map in the building frame (SE(2) fit).")
@click.option("--cell-size", "cell_size_m", type=float, default=None, help="Grid cell edge in metres.")
@floor_option
@rerun_option
@common_options
def export_map(workspace, anchors_path, cell_size_m, floor, rerun, config_path, force, quiet, verbose):
    """Rasterise the optimised fingerprints of WORKSPACE into a radio map (WORKSPACE/map/)."""
    start(verbose, quiet)
    from rmbuild.cli.progress import progress_display
    from rmbuild.config import load_stage_config
    from rmbuild.io.workspace import Workspace, building_floors
    from rmbuild.stages import export_map as stage

    cfg = load_stage_config("map", config_path, overrides={"cell_size_m": cell_size_m})
    with (stage_viewer(rerun, workspace, "map", quiet, force) as viewer,
          progress_display(quiet, verbose) as progress):
        r = stage.run(workspace, cfg, anchors_path=anchors_path, progress=progress, viewer=viewer, force=force,
                      floor=floor)
    if quiet:
        return
    floors = building_floors(workspace) or {}
    for name in r.get("ran_floors", [None]):
        where = Workspace(floors.get(name, workspace)).path("map.cells").parent
        if name is not None:
            click.echo(f"floor {name}: ", nl=False)
        _summary(r["floors"][name] if name is not None else r, where)


def _summary(r: dict, where) -> None:
    click.echo(f"radio map: {r['cells']} cells of {r['cell_size_m']:g} m, {r['aps']} APs, "
               f"{r['reference_nodes']} reference nodes, {_frame(r['frame'])} -> {where}")
    cov = r.get("plan_coverage")
    if cov and cov.get("share") is not None:
        click.echo(f"the map's visited cells cover {cov['share']:.0%} of the floor plan's walkable space "
                   f"({cov['covered_m2']:,.0f} of {cov['walkable_m2']:,.0f} m²)")
    ble = r.get("ble")
    if ble and "skipped" in ble:
        click.echo(f"note: no BLE radio map: {ble['skipped']}", err=True)
    elif ble:
        click.echo(f"BLE radio map: {ble['cells']} cells, {ble['beacons']} beacons -> {where / 'radiomap_ble.parquet'}")
    for cmd in (r.get("evo") or {}).get("commands") or []:
        click.echo(f"score the whole map with evo (in the workspace): {cmd}")
    left = r["frame_info"].get("left_out_walks") or []
    if left:
        click.echo(f"note: {len(left)} walk(s) placed neither by Wi-Fi links nor by anchors were left out: "
                   f"{', '.join(left[:8])}", err=True)


def _frame(frame: str) -> str:
    """The map's frame in plain words ("walk:<id>" is the sidecar's name for a walk's frame)."""
    if frame == "building":
        return "in the building frame"
    if frame.startswith("walk:"):
        return f"in the frame of walk {frame[5:]} (not tied to the building)"
    return f"in the frame of the {frame}"
