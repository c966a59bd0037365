"""`rmbuild config`: print the default (or a file's resolved) configuration of every stage as TOML."""

from __future__ import annotations

import click


@click.command("config")
@click.option("--stage", "stages", multiple=True,
              help="Only these sections (repeatable): simulate, ingest, pdr, optimize, map, evaluate.")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None,
              help="Resolve this TOML file over the defaults (and check it: unknown keys are errors).")
def config(stages, config_path):
    """Print every setting with its value: a starting point for a --config file."""
    from rmbuild.config import SECTIONS, load_stage_config, to_toml
    from rmbuild.errors import InputError

    unknown = [s for s in stages if s not in SECTIONS]
    if unknown:
        raise InputError(f"unknown section {unknown[0]!r} (known: {', '.join(SECTIONS)})")
    for name in stages or SECTIONS:
        click.echo(to_toml(load_stage_config(name, config_path), name, comments=True))
