"""`rmbuild localize`."""

from __future__ import annotations

import click

from rmbuild.cli.ingest import FORMAT_HELP
from rmbuild.cli.options import floor_option, start, workspace_option
from rmbuild.io.formats import reader_names
from rmbuild.localize.registry import describe, localizer_names


@click.command()
@click.argument("inputs", nargs=-1, required=True, type=click.Path())
@workspace_option
@click.option("-o", "--output", "out", required=True, type=click.Path(dir_okay=False),
              help="Per-scan positions (map frame) with an uncertainty: .csv or .parquet; .geojson (lon/lat points) "
                   "when the map is georeferenced (building frame and a floor plan with lon/lat).")
@click.option("--localizer", type=click.Choice(localizer_names()), default=None,
              help=f"Localizer (default: the first of [evaluate] localizers, knn). {describe()}.")
@click.option("--format", "fmt", type=click.Choice(reader_names()), default=None,
              help=FORMAT_HELP + " Bare scans (a wifi table without poses) are rmbuild's schema.")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None,
              help="TOML file whose [evaluate] table configures the localizers; unknown keys are errors.")
@click.option("--hold-out", "hold_out", is_flag=True,
              help="INPUTS are walks of the workspace: localize them against evaluate's built map of its other "
                   "walks (not the exported map), scored as `evaluate --test-walks` scores them.")
@floor_option
@click.option("--force", is_flag=True, help="Replace an existing output file.")
@click.option("-q", "--quiet", is_flag=True, help="No progress or summary: only warnings and errors.")
@click.option("-v", "--verbose", count=True, help="More log output (-vv for debug).")
def localize(inputs, workspace, out, localizer, fmt, config_path, hold_out, floor, force, quiet, verbose):
    """Localize new walks or bare scans in INPUTS against the workspace's radio map (read-only)."""
    start(verbose, quiet)
    from rmbuild.cli.progress import progress_display
    from rmbuild.config import load_stage_config
    from rmbuild.stages import localize as stage

    cfg = load_stage_config("evaluate", config_path)
    with progress_display(quiet, verbose) as progress:
        r = stage.run(workspace, list(inputs), out, cfg, localizer=localizer, fmt=fmt, force=force,
                      progress=progress, floor=floor, hold_out=hold_out)
    if quiet:
        return
    kind = " (bare scans: no steps)" if r["input_kind"] == "scans" else ""
    click.echo(f"localized {r['scans']} scans of {r['walks']} walk(s){kind} with {r['localizer']} "
               f"(map frame {r['map_frame'] or '?'}; {r['unlocalized']} without an estimate) -> {r['output']}")
    e = r["errors"]
    if e is not None and e["n"]:
        click.echo(f"errors vs ground truth (m, {e['n']} scans): mean {e['mean']:.2f}, median {e['median']:.2f}, "
                   f"p90 {e['p90']:.2f}, rmse {e['rmse']:.2f}, max {e['max']:.2f}, <5m {e['p_lt_5m']:.2f}")
        click.echo(f"truth frame: {r['truth']['frame']}")
    elif r["truth"]["present"]:
        click.echo(f"errors not computed: {r['truth']['frame']}")
