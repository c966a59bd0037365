"""`rmbuild simulate`."""

from __future__ import annotations

import click

from rmbuild.cli.options import common_options, start
from rmbuild.config.simulate import PRESETS


@click.command()
@click.argument("out_dir", type=click.Path(file_okay=False), required=False)
@click.option("--preset", type=click.Choice(list(PRESETS)), default="default",
              show_default=True, help="Venue size: tiny (tests, seconds), default (~10 walks, ~5,000 steps), "
              "large (~50,000 steps, benchmarks), month (large's venue, ~500,000 steps, 1,000 walks), "
              "year (~2,000,000 steps, 4,000 walks), corridor12 (12 walks along one corridor, as in Gu et al. "
              "2017), short (160 short phone walks of ~15-20 m, ~10 scans each).")
@click.option("--seed", type=int, default=7, show_default=True, help="Random seed; same seed, same files.")
@click.option("--format", "fmt", type=click.Choice(["csv", "parquet"]), default="csv", show_default=True,
              help="File format of the written tables.")
@click.option("--test-device", default=None, metavar="K,B",
              help="Put the test walks on a device with RSS model k*phi + b (e.g. 1.25,-6).")
@click.option("--raw-imu", is_flag=True,
              help="Write raw phone-IMU signals (imu table, [phone] settings) instead of poses: ingest runs the PDR.")
@click.option("--print-config", "print_config", is_flag=True,
              help="Print the simulator's settings (the preset, seed and --config applied) as TOML and stop.")
@common_options
def simulate(out_dir, preset, seed, fmt, test_device, raw_imu, print_config, config_path, force, quiet, verbose):
    """Write a seeded synthetic venue to OUT_DIR: the files `rmbuild ingest OUT_DIR` reads, plus truth/.

    The simulator's settings are its own (venue, radio, walkers, sensors): a --config file's [simulate]
    table is applied on top of the preset (nested tables key by key); --print-config shows them.
    """
    start(verbose, quiet)
    from rmbuild.cli.progress import progress_display
    from rmbuild.config import load_stage_config
    from rmbuild.config.base import from_dict, to_dict
    from rmbuild.config.simulate import preset_config
    from rmbuild.errors import InputError
    from rmbuild.stages import simulate as stage

    cfg = load_stage_config("simulate", config_path, base=preset_config(preset, seed))
    if test_device is not None:
        try:
            k, b = (float(v) for v in test_device.split(","))
        except ValueError:
            raise InputError(f"--test-device: expected K,B (two numbers), got {test_device!r}") from None
        data = to_dict(cfg)
        data.setdefault("devices", {})["test_device"] = [k, b]
        cfg = from_dict(type(cfg), data, "--test-device")
    if print_config:
        from rmbuild.config import to_toml

        click.echo(to_toml(cfg, "simulate", comments=True), nl=False)
        return
    if out_dir is None:
        raise click.UsageError("missing argument OUT_DIR")
    with progress_display(quiet, verbose) as progress:
        s = stage.run(out_dir, cfg, fmt=fmt, force=force, progress=progress, raw_imu=raw_imu)
    if not quiet:
        click.echo(f"simulated {s['walks']} walks, {s['steps']} steps, {s['readings']} Wi-Fi readings "
                   f"-> {s['out_dir']}")
