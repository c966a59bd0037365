"""`rmbuild evaluate`."""

from __future__ import annotations

import click

from rmbuild.cli.options import (
    common_options,
    floor_option,
    list_option,
    rerun_option,
    stage_viewer,
    start,
    workspace_option,
)
from rmbuild.localize.registry import describe, localizer_names


@click.command()
@workspace_option
@list_option("--test-walks", metavar="ID",
             help="Walks held out for testing (default: walks with role 'test', else every 5th walk).")
@list_option("--localizer", "localizers", choices=localizer_names(),
             help=f"Localizer(s) to run side by side (default from config: knn, wknn). {describe()}.")
@floor_option
@rerun_option
@common_options
def evaluate(workspace, test_walks, localizers, floor, rerun, config_path, force, quiet, verbose):
    """Localize held-out walks with maps built from optimised, true and raw positions; report errors."""
    start(verbose, quiet)
    from rmbuild.cli.progress import progress_display
    from rmbuild.config import load_stage_config
    from rmbuild.io.workspace import Workspace, building_report_path
    from rmbuild.stages import evaluate as stage

    cfg = load_stage_config("evaluate", config_path,
                            overrides={"localizers": list(localizers) if localizers else None})
    # the maps are rasterised like export-map did (map_cfg None), unless a config file says otherwise
    map_cfg = load_stage_config("map", config_path) if config_path else None
    walks = list(test_walks) or None
    with (stage_viewer(rerun, workspace, "evaluate", quiet, force) as viewer,
          progress_display(quiet, verbose) as progress):
        report, table = stage.run(workspace, cfg, map_cfg, test_walks=walks, progress=progress, viewer=viewer,
                                  force=force, floor=floor)
    if quiet:
        return
    click.echo(table)
    if "floors" in report:
        click.echo(f"report: {building_report_path(workspace, 'evaluate')} (each floor's: "
                   "floors/<NAME>/evaluate/report.json)")
        return
    ws = Workspace(workspace)
    click.echo(f"report: {ws.report_path('evaluate')}, CDF plot: {ws.path('evaluate.cdf_png')}")
