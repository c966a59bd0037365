"""`rmbuild config`: print the default (or a file's resolved) configuration of every stage as TOML."""

from __future__ import annotations

import click

from rmbuild.cli.options import list_option
from rmbuild.config import SECTIONS


@click.command("config")
@list_option("--stage", "stages", choices=list(SECTIONS), metavar="SECTION",
             help=f"Only these sections: {', '.join(SECTIONS)}.")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None,
              help="Resolve this TOML file over the defaults (and check it: unknown keys are errors).")
def config(stages, config_path):
    """Print every setting with its value: a starting point for a --config file."""
    from rmbuild.config import load_stage_config, to_toml

    for name in stages or SECTIONS:
        click.echo(to_toml(load_stage_config(name, config_path), name, comments=True))
