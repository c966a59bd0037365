"""`rmbuild ingest`."""

from __future__ import annotations

import click

from rmbuild.cli.options import common_options, rerun_option, stage_viewer, start, workspace_option
from rmbuild.io.formats import REGISTRY, reader_names

FORMAT_HELP = "Input format (default: recognised from the files): " + "; ".join(
    f"{name}: {REGISTRY[name].description}" for name in reader_names()) + "."


def _extent(ctx, param, value: str | None) -> tuple[float, float, float, float] | None:
    """X0,Y0,X1,Y1 as four floats (the stage checks their order)."""
    if value is None:
        return None
    try:
        x0, y0, x1, y1 = (float(v) for v in value.split(","))
    except ValueError:
        raise click.BadParameter(f"{value!r} is not four comma-separated numbers X0,Y0,X1,Y1") from None
    return x0, y0, x1, y1


@click.command()
@click.argument("inputs", nargs=-1, required=True, type=click.Path())
@workspace_option
@click.option("--format", "fmt", type=click.Choice(reader_names()), default=None, help=FORMAT_HELP)
@click.option("--floorplan", "floorplan", type=click.Path(dir_okay=False), default=None,
              help="GeoJSON floor plan (WGS84 lon/lat, or metres with \"frame\": \"local_m\") in the frame of "
                   "the data's fixes; kept in the workspace for `optimize` (which uses it unless "
                   "optimize.floorplan.use = false) and pictures.")
@click.option("--floorplan-image", "floorplan_image", type=click.Path(dir_okay=False), default=None,
              help="Raster image of the floor plan (PNG, JPEG, ...), drawn under the walks in the report and the "
                   "viewer; replaces the image the plan file names (its \"image\" member) or an MS ILC floor "
                   "folder brings.")
@click.option("--floorplan-image-extent", "image_extent", callback=_extent, default=None, metavar="X0,Y0,X1,Y1",
              help="Where the image's left, bottom, right and top edges lie, in the plan's coordinates (lon/lat "
                   "degrees for a WGS84 plan, else metres); default: the plan's bounding box.")
@click.option("--append", is_flag=True,
              help="Add the walks of INPUTS to the existing workspace (read with its own [ingest]/[pdr] config; "
                   "a walk id already there is an error); later stages' outputs become stale.")
@rerun_option
@common_options
def ingest(inputs, workspace, fmt, floorplan, floorplan_image, image_extent, append, rerun, config_path, force, quiet,
           verbose):
    """Read INPUTS (files or directories), validate them and create the workspace."""
    start(verbose, quiet)
    from rmbuild.cli.progress import progress_display
    from rmbuild.config import load_stage_config
    from rmbuild.stages import ingest as stage

    if append:
        _append(inputs, workspace, fmt, {"--floorplan": floorplan, "--floorplan-image": floorplan_image,
                                         "--floorplan-image-extent": image_extent, "--rerun": rerun,
                                         "--config": config_path, "--force": force}, quiet, verbose)
        return
    if image_extent is not None and floorplan_image is None:
        raise click.UsageError("--floorplan-image-extent places --floorplan-image, which is not given")

    cfg = load_stage_config("ingest", config_path)
    pdr_cfg = load_stage_config("pdr", config_path)
    with (stage_viewer(rerun, workspace, "ingest", quiet, force) as viewer,
          progress_display(quiet, verbose) as progress):
        s = stage.run(list(inputs), workspace, cfg, fmt=fmt, force=force, progress=progress, pdr_cfg=pdr_cfg,
                      viewer=viewer, floorplan=floorplan, floorplan_image=floorplan_image, image_extent=image_extent)
    if quiet:
        return
    if "floors" in s:  # a building: one line per floor
        for name, f in s["floors"].items():
            click.echo(f"floor {name}: {_line(f)}")
        b = s["building"]
        click.echo(f"building of {b['floors']} floors: {b['walks']} walks, {b['poses']} poses, {b['aps']} APs "
                   f"-> {workspace}")
        if s["skipped"]:
            click.echo(_skipped(s))
        notes = dict.fromkeys([*s["notes"], *(n for f in s["floors"].values() for n in f["notes"])])
    else:
        click.echo(f"{_line(s)} -> {workspace}")
        notes = dict.fromkeys(s["notes"])
    for f in [s] if "floors" not in s else s["floors"].values():
        if f.get("floorplan"):
            fp = f["floorplan"]
            inside = "" if fp["fixes_inside"] is None else f" ({fp['fixes_inside']:.0%} of the fixes inside)"
            doubt = "; its frame looks wrong (warning above): not used by optimize" \
                if (fp.get("frame_check") or {}).get("warning") else ""
            image = " with its image" if fp.get("image_extent_m") else ""
            click.echo(f"floor plan {fp['name'] or '(unnamed)'}{image} kept{inside}{doubt}")
    for note in notes:
        click.echo(f"note: {note}", err=True)


def _line(s: dict) -> str:
    return (f"ingested {s['walks']} walks, {s['poses']} poses, {s['readings']} readings in {s['scans']} scans "
            f"({s['aps']} APs, {s['nodes_with_fingerprint']} fingerprinted nodes)" + _ble(s) + _skipped(s, "; "))


def _ble(s: dict) -> str:
    b = s.get("ble")
    return f"; {b['readings']} BLE readings of {b['beacons']} beacons" if b else ""


def _skipped(s: dict, sep: str = "") -> str:
    skipped = ", ".join(f"{v} {k}" for k, v in s["skipped"].items())
    return f"{sep}skipped {skipped}" if skipped else ""


def _append(inputs, workspace, fmt, options: dict, quiet, verbose) -> None:
    from rmbuild.cli.progress import progress_display
    from rmbuild.stages import append as stage

    given = [name for name, v in options.items() if v]
    if given:
        raise click.UsageError(f"--append reads the new walks with the workspace's own settings: {given[0]} "
                               "cannot be combined with it")
    with progress_display(quiet, verbose) as progress:
        s = stage.run(list(inputs), workspace, fmt=fmt, progress=progress)
    if not quiet:
        a = s["appended"][-1]
        click.echo(f"appended {a['walks']} walks, {a['poses']} poses -> {workspace} (now {s['walks']} walks); "
                   "re-run optimize, export-map and evaluate with --force")
