"""`rmbuild optimize`."""

from __future__ import annotations

import click

from rmbuild.cli.options import common_options, floor_option, rerun_option, stage_viewer, start, workspace_option


@click.command()
@workspace_option
@click.option("--anchors", "anchors_path", type=click.Path(dir_okay=False), default=None,
              help="CSV/Parquet with walk_id, t_s, x_m, y_m: known building-frame positions (position priors).")
@click.option("--preset", type=click.Choice(["rmbuild", "paper"]), default=None,
              help="Start from rmbuild's defaults or from Gu et al.'s model as published (before --config).")
@click.option("--incremental", is_flag=True, default=False,
              help="Place only the walks added with `ingest --append` since the last optimize, against its "
                   "solution (the old walks keep their poses); much faster than a full run, see docs/api.md.")
@floor_option
@rerun_option
@common_options
def optimize(workspace, anchors_path, preset, incremental, floor, rerun, config_path, force, quiet, verbose):
    """Align all walks of WORKSPACE into one frame (GTSAM: odometry + fuzzy RSS-vicinity factors)."""
    start(verbose, quiet)
    from rmbuild.cli.progress import progress_display
    from rmbuild.config import load_stage_config
    from rmbuild.stages import optimize as stage
    base = None
    if preset == "paper":
        from rmbuild.config.optimize import paper_config

        base = paper_config()
    cfg = load_stage_config("optimize", config_path, base=base)
    with (stage_viewer(rerun, workspace, "optimize", quiet, force) as viewer,
          progress_display(quiet, verbose) as progress):
        r = stage.run(workspace, cfg, anchors_path=anchors_path, progress=progress, viewer=viewer, force=force,
                      floor=floor, incremental=incremental)
    if quiet:
        return
    for name in r.get("ran_floors", [None]):
        if name is not None:
            click.echo(f"floor {name}:")
        _summary(r["floors"][name] if name is not None else r)


def _summary(r: dict) -> None:
    from rmbuild.stages.optimize import frame_text, metrics_text

    f = r["factors"]
    inc = r.get("incremental")
    if inc and inc.get("gave_up"):
        click.echo(f"incremental: gave up ({inc['gave_up']}); ran the full optimization instead")
    elif inc:
        again = inc["old_walks_placed_again"]
        click.echo(f"incremental: {inc['new_walks_placed']} of {len(inc['new_walks'])} new walk(s) placed against "
                   f"the {inc['held_walks']} walks the last optimize linked (kept as they were)"
                   + (f"; the {len(again)} walk(s) it left out placed again with them "
                      f"({len(inc['old_walks_now_linked'])} now linked)" if again else ""))
    click.echo(f"optimized {r['walks']} walks / {r['poses']} poses ({r.get('poses_solved', r['poses'])} solved): "
               f"{f['odometry']} odometry, {f['vicinity']} vicinity, {f['prior']} prior factors in "
               f"{r['time_s'].get('stage_total', 0):.1f} s; {frame_text(r)}")
    sc = r.get("scale") or {}
    if sc.get("fitted_walks"):
        click.echo(f"  step-length scale fitted on {sc['fitted_walks']} walk(s): {sc['min']:.3f}-{sc['max']:.3f} "
                   "(optimize/walks.parquet: scale)")
    vi = r.get("vicinity") or {}
    if vi.get("anisotropic_pairs"):
        how = "estimated" if vi.get("estimated") else "set"
        click.echo(f"  anisotropic pairs: {vi['anisotropic_pairs']} of {f['vicinity']}, sigma across/along "
                   f"{vi['across_ratio']:.2f} ({how}; optimize/pairs.parquet: anisotropic)")
    if (linked := _linked(r)) is not None:
        click.echo(linked)
    plan = (r.get("evidence") or {}).get("floorplan")
    if plan and plan.get("used"):
        click.echo(f"  floor plan: {plan['inside']:.0%} of the reference component's poses in walkable space, "
                   f"{plan['wall_priors']} wall priors, {plan['placed_components']} further component(s) placed")
    _errors(r, metrics_text)


def _errors(r: dict, metrics_text) -> None:
    """The error lines: only figures that could be computed, and what they were measured against. With
    unlinked walks, the optimised figure is the linked walks' (an unlinked walk's frame is arbitrary); the
    all-walk comparison puts the unlinked walks where their dead reckoning alone puts them."""
    raw, opt = r.get("raw") or {}, r.get("optimized") or {}
    al = r.get("metrics_alignment") or {}
    lk = opt.get("landmark_error_fitted_walks_m")
    some_unlinked = al.get("fitted_on") == "linked walks" and al.get("walks", 0) < r["walks"]
    shown_opt = {"landmark_error_m": lk} if some_unlinked and lk else opt
    if not (metrics_text(raw) or metrics_text(shown_opt)):
        click.echo("  no true paths or position fixes: no error against ground truth")
        return
    have_truth = raw.get("ate_m") is not None
    how = "true paths" if have_truth else "the waypoints / position fixes (no true paths: no ATE)"
    fit = ("each after one rigid fit of all walks together" if r.get("gauge") == "se2" else
           "raw after one rigid fit of all walks together, optimised as placed in the building frame")
    click.echo(f"  errors against {how}, {fit}:")
    if metrics_text(raw):
        click.echo(f"  raw       {metrics_text(raw)} (all {r['walks']} walks)")
    if some_unlinked:
        n_un = r["walks"] - al["walks"]
        if lk:
            click.echo(f"  optimized {metrics_text(shown_opt)} (the {al['walks']} linked walks; the {n_un} "
                       "unlinked keep arbitrary frames and are left out of the map)")
        at_raw = opt.get("landmark_error_unlinked_at_raw_m")
        if at_raw:
            click.echo(f"  all walks, the unlinked at their raw placement (against raw above): "
                       f"{metrics_text({'landmark_error_m': at_raw})}")
    elif metrics_text(opt):
        click.echo(f"  optimized {metrics_text(opt)}")


def _linked(r: dict) -> str | None:
    """How many walks are in the map, reconciled with the progress bar's count of walks placed by Wi-Fi
    (which is taken before the RF check leaves some of them out)."""
    n = r.get("linked_walks")
    if not isinstance(n, int):
        return None
    refuted = len(r.get("refuted_walks") or [])
    anchored = r.get("anchored_only_walks") or 0
    text = f"  linked into the map: {n} of {r['walks']} walks"
    if refuted:
        text += (f"; the RF check then refuted {refuted} of the walks the progress bar counted as placed by "
                 "Wi-Fi (optimize/walks.parquet: placement 'refuted')")
    if anchored:
        text += f"; {anchored} more placed by anchors alone"
    return text + _kinds(r.get("placement_kinds") or {})


#: placement kinds (slam/report.py:placement_summary) as the summary names them
KIND_NAMES = {"reference": "reference", "held": "the last optimize (held)", "wifi": "Wi-Fi fits",
              "merge": "group merges", "continuity": "continuity ties", "floorplan": "the floor plan",
              "anchor": "anchors alone"}


def _kinds(kinds: dict) -> str:
    """A second line: walks per placement kind with their median predicted error, the walks left out."""
    parts = []
    for kind, name in KIND_NAMES.items():
        k = kinds.get(kind)
        if k and kind != "reference":
            err = k.get("median_predicted_error_m")
            parts.append(f"{name} {k['walks']} walk(s)" + (f" (median predicted error {err:.1f} m)" if err is not None
                                                             else ""))
    if not parts:
        return ""
    out = (kinds.get("left out") or {}).get("walks", 0)
    return ("\n  placed by: " + ", ".join(parts) + (f"; left out: {out} walk(s)" if out else "")
            + "; why, walk by walk: optimize/walks.parquet: reason")
