"""`rmbuild config`: print the settings a user changes (or every setting) as TOML, defaults or a file's."""

from __future__ import annotations

import click

from rmbuild.cli.options import list_option
from rmbuild.config import SECTIONS


@click.command("config")
@list_option("--stage", "stages", choices=list(SECTIONS), metavar="SECTION",
             help=f"Only these sections: {', '.join(SECTIONS)}.")
@click.option("--all", "show_all", is_flag=True,
              help="Every setting: also the finer tuning, the paper baselines' and the simulator's.")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None,
              help="Resolve this TOML file over the defaults (and check it: unknown keys are errors).")
def config(stages, show_all, config_path):
    """Print the settings a user changes, with their unit, range and value: a starting point for a --config
    file. --all prints every setting; any setting may be set in a file, printed or not."""
    from rmbuild.config import load_stage_config, to_toml
    from rmbuild.config.user import OWN_TOOL_SECTIONS, user_keys

    names = stages or [s for s in SECTIONS if show_all or s not in OWN_TOOL_SECTIONS]
    if not show_all:
        click.echo("# The settings a user changes; `rmbuild config --all` prints every setting (finer tuning, "
                   "the paper\n# baselines' [evaluate.baselines.*], the simulator's [simulate]).\n")
    for name in names:
        keys = None if show_all else user_keys(name)
        click.echo(to_toml(load_stage_config(name, config_path), name, comments=True, keys=keys))
