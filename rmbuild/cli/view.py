"""`rmbuild view`: log a workspace to the rerun viewer (the stages' `--rerun` option: rmbuild.cli.options)."""

from __future__ import annotations

from pathlib import Path

import click

from rmbuild.cli.options import floor_option, start, workspace_option


@click.command()
@workspace_option
@click.option("--save", "save_path", type=click.Path(dir_okay=False), default=None,
              help="Write the recording to FILE.rrd (default WORKSPACE/view.rrd when there is no display).")
@click.option("--spawn", is_flag=True, help="Open the native rerun viewer.")
@click.option("--serve", is_flag=True, help="Serve the web viewer on localhost (see --port).")
@click.option("--port", type=int, default=9090, show_default=True,
              help="Web viewer port for --serve (its gRPC server uses PORT+1).")
@floor_option
@click.option("--force", is_flag=True, help="Replace an existing recording file.")
@click.option("-q", "--quiet", is_flag=True, help="No summary: only warnings and errors.")
@click.option("-v", "--verbose", count=True, help="More log output (-vv for debug).")
def view(workspace, save_path, spawn, serve, port, floor, force, quiet, verbose):
    """Log what WORKSPACE holds (walks, optimisation, radio map, evaluation) to the rerun viewer."""
    start(verbose, quiet)
    if sum(map(bool, (save_path, spawn, serve))) > 1:
        raise click.UsageError("give at most one of --save, --spawn, --serve")
    from rmbuild.io.workspace import Workspace, check_output_file
    from rmbuild.stages import view as stage
    from rmbuild.stages.building import floor_workspaces
    from rmbuild.stages.view import floor_target
    from rmbuild.viz import ViewTarget, default_target

    if save_path:
        target = ViewTarget("save", Path(save_path))
    elif spawn or serve:
        target = ViewTarget("spawn" if spawn else "serve", port=port)
    else:
        target = default_target(Workspace(workspace).path("view.rrd"), port=port)
    floors = floor_workspaces(workspace, floor)
    if target.path is not None:
        for name in floors or [None]:
            check_output_file(floor_target(target, name).path if name else target.path, force, "recording")
    if target.mode == "serve":  # the viewer must outlive the logging: keep it open until Ctrl-C
        from rmbuild.viz import open_viewer

        viewer = open_viewer(target, recording_name=f"rmbuild {Path(workspace).name}")
        r = stage.run(workspace, viewer=viewer, floor=floor)
        click.echo(f"logged {', '.join(r['logged'])}; serving the web viewer on http://localhost:{port} "
                   f"(Ctrl-C to stop)", err=True)
        try:
            _wait_forever()
        finally:
            viewer.close()
    from rmbuild.cli.progress import progress_display

    with progress_display(quiet, verbose) as progress:
        r = stage.run(workspace, target, progress=progress, floor=floor)
    if quiet:
        return
    for name in r.get("ran_floors", [None]):
        if name is not None:
            click.echo(f"floor {name}: ", nl=False)
        _summary(r["floors"][name] if name is not None else r)


def _summary(r: dict) -> None:
    where = r["path"] if r["path"] else f"the {r['mode']} viewer"
    click.echo(f"logged {', '.join(r['logged'])} to {where} in {r['time_total_s']:.1f} s")
    for k, why in r["skipped"].items():
        click.echo(f"  skipped {k}: {why}")
    if r["path"]:
        click.echo(f"recording: {r['path']}  (open with: rerun {r['path']})")


def _wait_forever() -> None:  # pragma: no cover - interactive
    import time

    while True:
        time.sleep(3600)
