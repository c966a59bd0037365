"""The `rmbuild` command line: a click group whose commands are loaded lazily (fast --help).

Each command lives in its own thin module; this module maps the project's errors to a one-line message
and an exit code (2 bad input/usage, 1 other failures).
"""

from __future__ import annotations

import importlib
import logging
import signal
import sys
import threading
from typing import Any

import click

#: command name -> "module:attribute"
COMMANDS = {
    "simulate": "rmbuild.cli.simulate:simulate",
    "ingest": "rmbuild.cli.ingest:ingest",
    "optimize": "rmbuild.cli.optimize:optimize",
    "export-map": "rmbuild.cli.export_map:export_map",
    "evaluate": "rmbuild.cli.evaluate:evaluate",
    "localize": "rmbuild.cli.localize:localize",
    "diff-map": "rmbuild.cli.diff_map:diff_map",
    "view": "rmbuild.cli.view:view",
    "report": "rmbuild.cli.report:report",
    "config": "rmbuild.cli.config_cmd:config",
    "build": "rmbuild.cli.build:build",
}

#: one-line summaries shown by `rmbuild --help` without importing the commands
SUMMARIES = {
    "simulate": "Write a seeded synthetic venue (input files + truth/).",
    "ingest": "Read walks and Wi-Fi scans, validate them, create a workspace.",
    "optimize": "Align all walks in one frame with a GTSAM factor graph.",
    "export-map": "Rasterise the aligned fingerprints into a radio map.",
    "evaluate": "Localize held-out walks with built, surveyed and raw maps.",
    "localize": "Localize new walks or scans against a workspace's radio map.",
    "diff-map": "Report per AP what changed between two workspaces' radio maps.",
    "view": "Log a workspace to the rerun viewer.",
    "report": "Write a one-page HTML report of a workspace.",
    "config": "Print the settings a user changes as TOML (--all: every setting).",
    "build": "The whole pipeline in one command; floors run as parallel (Dask) tasks.",
}


class LazyGroup(click.Group):
    """Imports a command's module only when the command runs (or its help is shown). A module that fails
    to import is an error naming the command, never a command that silently disappears."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return list(COMMANDS)

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        if name not in COMMANDS:
            return None
        return load_command(name)

    def resolve_command(self, ctx: click.Context, args: list[str]) -> tuple[str | None, click.Command | None,
                                                                           list[str]]:
        """As click's, but a mistyped command is told the commands it resembles (as options are)."""
        name = args[0] if args else ""
        if name and not name.startswith("-") and name not in COMMANDS:
            import difflib

            close = difflib.get_close_matches(name, list(COMMANDS), n=2, cutoff=0.6)
            hint = f" Did you mean {' or '.join(repr(c) for c in close)}?" if close else ""
            raise click.UsageError(f"No such command {name!r}.{hint}", ctx)
        return super().resolve_command(ctx, args)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        rows = [(n, SUMMARIES.get(n, "")) for n in self.list_commands(ctx)]
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)


def load_command(name: str) -> click.Command:
    """The click command ``name`` of :data:`COMMANDS`; RmbuildError when its module cannot be imported."""
    from rmbuild.errors import RmbuildError

    mod, attr = COMMANDS[name].split(":")
    try:
        cmd = getattr(importlib.import_module(mod), attr)
    except (ImportError, AttributeError) as e:
        raise RmbuildError(f"command {name!r} is broken: {type(e).__name__}: {e} (module {mod}); "
                           "reinstall rmbuild") from None
    if not isinstance(cmd, click.Command):
        raise RmbuildError(f"command {name!r} is broken: {COMMANDS[name]} is not a click command")
    return cmd


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="rmbuild")
def cli() -> None:
    """rmbuild: offline graph-SLAM radio-map builder.

    Typical run: simulate (or bring your own walks) -> ingest -> optimize -> export-map -> evaluate.
    """


def setup_logging(verbose: int, quiet: bool) -> None:
    level = logging.WARNING if quiet else (logging.DEBUG if verbose > 1 else logging.INFO)
    if verbose == 0 and not quiet:
        level = logging.WARNING
    from rmbuild.cli.progress import log_handler

    root = logging.getLogger("rmbuild")
    root.handlers[:] = [log_handler()]
    root.setLevel(logging.INFO if verbose == 1 else level)


def main(argv: list[str] | None = None) -> None:
    """Entry point of the console script: runs the group, turns errors into one line + exit code.

    The exit happens outside every exception handler, and the Ctrl-C handler stays in place until the
    process has exited (a library may re-raise a caught SIGINT late)."""
    ctrl_c = _CtrlC().install()
    sys.exit(_dispatch(argv, ctrl_c))


class _CtrlC:
    """SIGINT while a command runs: the first raises KeyboardInterrupt, later ones (re-raised by libraries
    that catch it, or a second Ctrl-C during the clean-up) are ignored; remembered, because a C extension
    interrupted while it loads turns it into another error (e.g. "ImportError: initialization failed")."""

    def __init__(self) -> None:
        self.seen = False

    def install(self) -> _CtrlC:
        """Handle SIGINT from now on (in the main thread, unless SIGINT is ignored, as in a background job)."""
        if threading.current_thread() is threading.main_thread() and \
                signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:
            signal.signal(signal.SIGINT, self._handle)
        return self

    def _handle(self, signum: int, frame: Any) -> None:
        if not self.seen:
            self.seen = True
            raise KeyboardInterrupt


def _dispatch(argv: list[str] | None, ctrl_c: _CtrlC) -> int:
    from rmbuild.errors import RmbuildError, one_line

    try:
        cli.main(args=argv, prog_name="rmbuild", standalone_mode=False)
    except (click.exceptions.Abort, KeyboardInterrupt):  # click turns Ctrl-C into Abort
        click.echo("interrupted; no partial outputs were kept", err=True)
        return 130
    except click.UsageError as e:  # a bad option or argument: one line, like every other input error
        where = e.ctx.command_path if e.ctx is not None else "rmbuild"
        click.echo(f"error: {one_line(e.format_message())} (see '{where} --help')", err=True)
        return 2
    except click.ClickException as e:
        e.show()
        return 2 if e.exit_code in (1, 2) else e.exit_code
    except RmbuildError as e:
        click.echo(f"error: {one_line(str(e))}", err=True)
        return e.exit_code
    except Exception as e:  # an internal failure: one line, the traceback only with -v
        if ctrl_c.seen:
            click.echo("interrupted; no partial outputs were kept", err=True)
            return 130
        args = sys.argv[1:] if argv is None else argv
        if any(a in ("-v", "-vv", "--verbose") for a in args):
            raise
        click.echo(f"internal error: {type(e).__name__}: {one_line(str(e))[:500]} (re-run with -v for the traceback)",
                   err=True)
        return 1
    return 0
