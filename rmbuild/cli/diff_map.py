"""`rmbuild diff-map`."""

from __future__ import annotations

import click

from rmbuild.cli.options import start


@click.command("diff-map")
@click.argument("a", type=click.Path(file_okay=False))
@click.argument("b", type=click.Path(file_okay=False))
@click.option("-o", "--output", "out", type=click.Path(dir_okay=False), default=None,
              help="Per-AP table (.csv or .parquet): status, strongest-cell centres in A and B, shifts.")
@click.option("--move-m", type=click.FloatRange(0.1, 1000.0), default=5.0, show_default=True,
              help="m; an AP heard in both maps whose strongest cells' centre shifted more than this is 'moved'.")
@click.option("--force", is_flag=True, help="Replace an existing output file.")
@click.option("-q", "--quiet", is_flag=True, help="No summary: only warnings and errors.")
@click.option("-v", "--verbose", count=True, help="More log output (-vv for debug).")
def diff_map(a, b, out, move_m, force, quiet, verbose):
    """Report per AP what changed from workspace A's radio map to workspace B's (read-only)."""
    start(verbose, quiet)
    from rmbuild.stages import diff_map as stage

    table, s = stage.run(a, b, out, move_m=move_m, force=force)
    if quiet:
        return
    c = s["counts"]
    click.echo(f"APs: {s['aps_a']} in A, {s['aps_b']} in B; of those with >= {s['min_readings']} readings: "
               + ", ".join(f"{c.get(k, 0)} {k}" for k in ("both", "gone", "appeared", "moved")))
    if s.get("note"):
        click.echo(f"note: {s['note']}")
    changed = table[table["status"] != "both"].head(15)
    if len(changed):
        click.echo(changed.to_string(index=False, float_format=lambda x: f"{x:.1f}"))
    if s.get("output"):
        click.echo(f"table: {s['output']}")
