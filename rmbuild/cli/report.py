"""`rmbuild report`."""

from __future__ import annotations

import click

from rmbuild.cli.options import floor_option, start, workspace_option


@click.command()
@workspace_option
@click.option("--out", "out", type=click.Path(dir_okay=False), default=None,
              help="HTML file to write (default WORKSPACE/report.html, PNGs in WORKSPACE/report/); with --out "
                   "its PNGs go beside it (OUT_figures/; a building's floor pages: OUT_floors/), nothing into the "
                   "workspace.")
@click.option("--top-aps", type=click.IntRange(1, 24), default=6, show_default=True,
              help="Heat maps of this many strongest APs.")
@floor_option
@click.option("--force", is_flag=True, help="Replace an existing report (the HTML file and its PNGs).")
@click.option("-q", "--quiet", is_flag=True, help="No summary: only warnings and errors.")
@click.option("-v", "--verbose", count=True, help="More log output (-vv for debug).")
def report(workspace, out, top_aps, floor, force, quiet, verbose):
    """Write a one-page self-contained HTML report of WORKSPACE (figures, key figures, configs)."""
    start(verbose, quiet)
    from rmbuild.stages import report as stage

    r = stage.run(workspace, out, heatmap_top_n=top_aps, force=force, floor=floor)
    if quiet:
        return
    for name, f in r.get("floors", {}).items():
        click.echo(f"floor {name}: ", nl=False)
        _summary(f)
    if "floors" in r:
        click.echo(f"building report: {r['path']}")
    else:
        _summary(r)


def _summary(r: dict) -> None:
    click.echo(f"report: {r['path']} ({len(r['figures'])} figures, PNGs in {r['png_dir']}) in {r['time_s']:.1f} s")
    for k, why in r["missing"].items():
        click.echo(f"  {k}: {why}")
