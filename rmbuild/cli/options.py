"""Options shared by every stage command."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import click

from rmbuild.cli import setup_logging


def common_options(f: Callable[..., Any]) -> Callable[..., Any]:
    """--config, --force, --quiet, -v; sets up logging before the command body runs."""
    f = click.option("-v", "--verbose", count=True, help="More log output (-vv for debug).")(f)
    f = click.option("-q", "--quiet", is_flag=True,
                     help="No progress, tables or summaries: only warnings and errors.")(f)
    f = click.option("--force", is_flag=True,
                     help="Replace existing outputs (for ingest: the workspace); without it nothing is "
                          "overwritten.")(f)
    f = click.option(
        "--config", "config_path", type=click.Path(dir_okay=False), default=None,
        help="TOML file with a table per stage ([ingest], [optimize], ...); unknown keys are errors.",
    )(f)
    return f


def start(verbose: int, quiet: bool) -> None:
    setup_logging(verbose, quiet)


def list_option(*decls: str, choices: list[str] | None = None, metavar: str = "NAME", help: str = "") -> Any:
    """A list option with one convention everywhere: repeatable and comma-separated (``--x a,b --x c`` is
    ``(a, b, c)``), order kept, duplicates dropped, each item checked against ``choices`` when given."""

    def split(ctx: click.Context, param: click.Parameter, value: tuple[str, ...]) -> tuple[str, ...]:
        items = [v.strip() for raw in value for v in raw.split(",") if v.strip()]
        bad = [v for v in items if choices is not None and v not in choices]
        if bad:
            raise click.BadParameter(f"{bad[0]!r} is not one of {', '.join(choices or [])}")
        return tuple(dict.fromkeys(items))

    return click.option(*decls, multiple=True, callback=split, metavar=f"{metavar}[,{metavar}...]",
                        help=f"{help} Repeatable or comma-separated.")


floor_option = click.option(
    "--floor", "floor", default=None, metavar="NAME",
    help="A building workspace (several floors): run on this floor only (default: every floor).",
)

workspace_option = click.option(
    "-w", "--workspace", required=True, type=click.Path(file_okay=False),
    help="Workspace directory (created by `rmbuild ingest`).",
)


#: `--rerun` for stage commands: absent -> no viewer; `--rerun` alone -> "auto" (spawn when a display is
#: available, else save WORKSPACE/<stage>.rrd); `--rerun spawn|serve|FILE.rrd`.
rerun_option = click.option(
    "--rerun", "rerun", default=None, is_flag=False, flag_value="auto", metavar="[spawn|serve|FILE.rrd]",
    help="Log to rerun while the stage runs: spawn the viewer, serve the web viewer, or save FILE.rrd "
         "(alone: spawn with a display, else save WORKSPACE/<stage>.rrd; an existing recording is replaced "
         "only with --force).",
)


def rerun_target(value: str | None, workspace: str | Path, stage: str):
    """The ViewTarget for a stage's ``--rerun`` value (None -> None: the stage gets a NullViewer)."""
    if value is None:
        return None
    from rmbuild.io.workspace import Workspace
    from rmbuild.viz import ViewTarget, default_target

    if value == "auto":
        return default_target(Workspace(workspace).path(f"{stage}.rrd"))
    if value in ("spawn", "serve"):
        return ViewTarget(value)
    if not value.endswith(".rrd"):
        raise click.BadParameter("expected spawn, serve or a path ending in .rrd", param_hint="--rerun")
    return ViewTarget("save", Path(value))


@contextmanager
def stage_viewer(rerun: str | None, workspace: str, stage: str, quiet: bool = False,
                 force: bool = False) -> Iterator[Any]:
    """The viewer of a stage's ``--rerun`` value (a do-nothing viewer when absent); closed on exit. An
    existing recording is replaced only with ``force``."""
    from rmbuild.io.workspace import check_output_file
    from rmbuild.viz import open_viewer

    target = rerun_target(rerun, workspace, stage)
    if target is not None and target.path is not None:
        check_output_file(target.path, force, "recording")
    viewer = open_viewer(target, recording_name=f"rmbuild {stage}")
    ok = False
    try:
        yield viewer
        ok = True
    finally:
        path = viewer.close(keep=ok)
        if path is not None and not quiet:
            click.echo(f"rerun recording: {path}")
