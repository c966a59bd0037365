"""`rmbuild build`."""

from __future__ import annotations

import click

from rmbuild.cli.ingest import FORMAT_HELP
from rmbuild.cli.options import common_options, start
from rmbuild.io.formats import reader_names


@click.command()
@click.argument("inputs", nargs=-1, type=click.Path())
@click.option("-w", "--workspace", type=click.Path(file_okay=False), default=None,
              help="The workspace to create from INPUTS.")
@click.option("--venues", "venues_path", type=click.Path(dir_okay=False), default=None,
              help="Instead of INPUTS: a TOML file of [[venue]] tables (name, inputs, optional format, config, "
                   "floorplan; docs/scale-out.md), one workspace each under -o.")
@click.option("-o", "--out-dir", type=click.Path(file_okay=False), default=None,
              help="With --venues: the directory of the venues' workspaces (OUT_DIR/<name>).")
@click.option("--format", "fmt", type=click.Choice(reader_names()), default=None, help=FORMAT_HELP)
@click.option("--floorplan", "floorplan", type=click.Path(dir_okay=False), default=None,
              help="GeoJSON floor plan, as for `rmbuild ingest --floorplan`.")
@click.option("--scheduler", default=None, metavar="serial|local[:N]|tcp://HOST:PORT",
              help="Where the floors run: in this process one after the other, on a Dask cluster of N local "
                   "worker processes, or on a running Dask scheduler (default from config [build]: serial).")
@common_options
def build(inputs, workspace, venues_path, out_dir, fmt, floorplan, scheduler, config_path, force, quiet, verbose):
    """Run the whole pipeline on INPUTS into -w WORKSPACE (or on every venue of --venues into -o OUT_DIR):
    ingest, then per floor optimize, export-map, evaluate (when there is ground truth) and report, the floors
    as parallel tasks; then the building's reports. Run again on a workspace it made, it redoes only what
    changed (inputs, config); --force redoes everything."""
    start(verbose, quiet)
    _check_usage(inputs, workspace, venues_path, out_dir, fmt, floorplan)
    from rmbuild.cli.progress import progress_display
    from rmbuild.config import load_stage_config
    from rmbuild.stages import build as stage

    cfgs = {s: load_stage_config(s, config_path) for s in stage.SECTIONS if s != "build"}
    cfgs["build"] = load_stage_config("build", config_path, overrides={"scheduler": scheduler})
    say = (lambda text: None) if quiet else (lambda text: click.echo(text, err=True))
    if venues_path is not None:
        from rmbuild.io.venues import read_venues

        venues = read_venues(venues_path, reader_names())
        with progress_display(quiet, verbose) as progress:
            r = stage.run_venues(venues, out_dir, cfgs, force=force, progress=progress, on_cluster=say)
        if not quiet:
            _venues_summary(r, out_dir)
    else:
        with progress_display(quiet, verbose) as progress:
            r = stage.run(list(inputs), workspace, cfgs, fmt=fmt, force=force, floorplan=floorplan,
                          progress=progress, on_cluster=say)
        if not quiet:
            _summary(r, workspace)
    if r["failed"]:
        causes = "; ".join(f"{name}: {why}" for name, why in r["failed"].items())
        raise stage.FloorsFailedError(f"{len(r['failed'])} failed ({causes}); the others are complete")


def _check_usage(inputs, workspace, venues_path, out_dir, fmt, floorplan) -> None:
    if venues_path is None:
        if not inputs or workspace is None:
            raise click.UsageError("give INPUTS and -w WORKSPACE, or --venues VENUES.toml and -o OUT_DIR")
        if out_dir is not None:
            raise click.UsageError("-o goes with --venues (one workspace: -w)")
        return
    if inputs or workspace is not None or fmt is not None or floorplan is not None:
        raise click.UsageError("--venues: each venue's inputs, format and floor plan are in the venues file "
                               "(no INPUTS, -w, --format, --floorplan)")
    if out_dir is None:
        raise click.UsageError("--venues needs -o OUT_DIR")


def _summary(r: dict, workspace: str, indent: str = "") -> None:
    ing = r["ingest"]
    b = ing.get("building") or ing
    click.echo(f"{indent}{'ingested' if r.get('ingested', True) else 'inputs unchanged, not ingested again:'} "
               f"{b['walks']} walks, {b['poses']} poses" + (f" on {len(r['floors'])} floors" if r["building"] else ""))
    for name, f in r["floors"].items():
        head = f"floor {name}: " if r["building"] else ""
        click.echo(f"{indent}{head}" + (_floor_line(f) if f.get("ok") else f"FAILED: {f['error']}"))
    t = r.get("time_s", {})
    if "total" in t:
        click.echo(f"done in {t['total']:.1f} s (ingest {t['ingest']:.1f} s, floors {t['floors']:.1f} s, "
                   f"scheduler {r['scheduler']}); report: {workspace}/report.html")


def _venues_summary(r: dict, out_dir: str) -> None:
    for name, err in r["failed_venues"].items():
        click.echo(f"venue {name}: FAILED: {err}")
    for name, v in r["venues"].items():
        click.echo(f"venue {name}:")
        _summary(v, f"{out_dir}/{name}", indent="  ")
    t = r["time_s"]
    click.echo(f"{len(r['venues'])} of {len(r['venues']) + len(r['failed_venues'])} venues built in "
               f"{t['total']:.1f} s (ingest round {t['ingest']:.1f} s, scheduler {r['scheduler']}) -> {out_dir}")


def _floor_line(f: dict) -> str:
    s = f["stages"]
    o = s["optimize"]
    parts = [f"{o['poses_solved']} of {o['poses']} poses solved", f"map {s['export-map']['cells']} cells"]
    ev = s.get("evaluate")
    if ev:
        built = ev["mean_error_m"].get("built") or {}
        loc = next(iter(built), None)
        if loc is not None and built[loc] is not None:
            parts.append(f"built map {loc} mean error {built[loc]:.2f} m")
    else:
        parts.append(f"not evaluated: {f['evaluate_skipped']}")
    if f.get("reused"):
        return ", ".join(parts) + " (unchanged since the last build: not re-run)"
    return ", ".join(parts) + f" ({f['time_s']:.1f} s, peak {f['peak_rss_mb']:.0f} MB, {f['worker']})"
