"""`rmbuild build`."""

from __future__ import annotations

import click

from rmbuild.cli.ingest import FORMAT_HELP
from rmbuild.cli.options import common_options, start, workspace_option
from rmbuild.io.formats import reader_names


@click.command()
@click.argument("inputs", nargs=-1, required=True, type=click.Path())
@workspace_option
@click.option("--format", "fmt", type=click.Choice(reader_names()), default=None, help=FORMAT_HELP)
@click.option("--floorplan", "floorplan", type=click.Path(dir_okay=False), default=None,
              help="GeoJSON floor plan, as for `rmbuild ingest --floorplan`.")
@click.option("--scheduler", default=None, metavar="serial|local[:N]|tcp://HOST:PORT",
              help="Where the floors run: in this process one after the other, on a Dask cluster of N local "
                   "worker processes, or on a running Dask scheduler (default from config [build]: local).")
@common_options
def build(inputs, workspace, fmt, floorplan, scheduler, config_path, force, quiet, verbose):
    """Run the whole pipeline on INPUTS: ingest, then per floor optimize, export-map, evaluate (when there is
    ground truth) and report, the floors as parallel tasks; then the building's reports."""
    start(verbose, quiet)
    from rmbuild.cli.progress import progress_display
    from rmbuild.config import load_stage_config
    from rmbuild.stages import build as stage

    cfgs = {s: load_stage_config(s, config_path) for s in stage.SECTIONS if s != "build"}
    cfgs["build"] = load_stage_config("build", config_path, overrides={"scheduler": scheduler})
    say = (lambda text: None) if quiet else (lambda text: click.echo(text, err=True))
    with progress_display(quiet, verbose) as progress:
        r = stage.run(list(inputs), workspace, cfgs, fmt=fmt, force=force, floorplan=floorplan, progress=progress,
                      on_cluster=say)
    if not quiet:
        _summary(r, workspace)
    if r["failed"]:
        n = len(r["floors"])
        raise stage.FloorsFailedError(f"{len(r['failed'])} of {n} floor(s) failed: {', '.join(r['failed'])} "
                                      "(the others are complete)")


def _summary(r: dict, workspace: str) -> None:
    ing = r["ingest"]
    b = ing.get("building") or ing
    click.echo(f"ingested {b['walks']} walks, {b['poses']} poses"
               + (f" on {len(r['floors'])} floors" if r["building"] else "") + f" in {r['time_s']['ingest']:.1f} s")
    for name, f in r["floors"].items():
        head = f"floor {name}: " if r["building"] else ""
        if not f.get("ok"):
            click.echo(f"{head}FAILED: {f['error']}")
            continue
        click.echo(f"{head}{_floor_line(f)}")
    t = r["time_s"]
    click.echo(f"done in {t['total']:.1f} s (floors {t['floors']:.1f} s, scheduler {r['scheduler']}); "
               f"report: {workspace}/report.html")


def _floor_line(f: dict) -> str:
    s = f["stages"]
    o = s["optimize"]
    parts = [f"{o['poses_solved']} of {o['poses']} poses solved", f"map {s['export-map']['cells']} cells"]
    ev = s.get("evaluate")
    if ev:
        knn = (ev["mean_error_m"].get("built") or {})
        loc = next(iter(knn), None)
        if loc is not None and knn[loc] is not None:
            parts.append(f"built map {loc} mean error {knn[loc]:.2f} m")
    else:
        parts.append(f"not evaluated: {f['evaluate_skipped']}")
    return ", ".join(parts) + f" ({f['time_s']:.1f} s, peak {f['peak_rss_mb']:.0f} MB, {f['worker']})"
