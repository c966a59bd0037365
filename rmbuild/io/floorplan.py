"""Floor plans on disk: a user's GeoJSON (``rmbuild ingest --floorplan``, with the raster image it may name)
and the workspace's copy.

The workspace keeps the plan in local metres (``data/floorplan.local.json``, :func:`rmbuild.floorplan.to_geojson`)
whatever it came as, so later stages never re-project it. :func:`check_plan_frame` tells whether a plan is in the
frame of the data's fixes (ingest reports it, optimize does not use a plan that fails it).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rmbuild.errors import InputError
from rmbuild.floorplan import frame_correction, from_local_geojson, from_user_geojson, image_extent_m, to_geojson
from rmbuild.io.floor_image import attach_image, check_extent, read_image
from rmbuild.io.jsonfile import read_json_file
from rmbuild.limits import MAX_PLAN_BYTES

#: share of the data's fixes that must lie within 1 m of walkable space, else the plan is taken to be in
#: another frame. Measured on the five MS ILC 2.0 floors: the right plan 100 % on each; shifted 5-30 m,
#: turned 5-180 deg, mirrored or another floor's of the same site 0-83 % (site2/F6's fixes on F4's plan)
MIN_FIXES_INSIDE = 0.9


def read_user_plan(path: str | Path) -> dict:
    """The plan at ``path`` (GeoJSON in WGS84 lon/lat, or local metres with ``"frame": "local_m"``) as
    workspace GeoJSON, with the raster image its ``"image"`` member names (:func:`plan_image`); InputError
    naming the file otherwise."""
    p = Path(path)
    try:
        doc = _read_doc(p)
        plan = from_user_geojson(doc, p.stem)
        out = {**to_geojson(plan), "source": str(p)}
        image = plan_image(doc, p)
        if image is None:
            return out
        return attach_image(out, read_image(image[0]), image_extent_m(plan, image[1]))
    except InputError:
        raise
    except OSError as e:
        raise InputError(f"cannot read floor plan: {e.strerror or e}", str(p)) from None
    except (ValueError, KeyError, TypeError, IndexError, AttributeError) as e:
        raise InputError(f"not a usable GeoJSON floor plan: {str(e)[:200]}", str(p)) from None


def _read_doc(p: Path) -> dict:
    doc = read_json_file(p, MAX_PLAN_BYTES, "floor plan")
    if not isinstance(doc, dict):
        raise InputError("not a GeoJSON FeatureCollection (a JSON object)", str(p))
    return doc


def plan_image(doc: dict, path: Path) -> tuple[Path, tuple[float, float, float, float] | None] | None:
    """The raster image a user's plan names in its ``"image"`` member, ``{"file": PATH (relative to the
    plan's folder, and in it), "extent": [x0, y0, x1, y1] (optional; the plan's coordinates, as
    :func:`rmbuild.floorplan.image_extent_m` takes them)}``: (its path, the extent or None); None without
    the member; InputError naming the plan file when the member is malformed or names a file outside the
    plan's folder (an absolute path, ``..``, a link leading out): a file never makes rmbuild read another
    file elsewhere."""
    img = doc.get("image") if isinstance(doc, dict) else None
    if img is None:
        return None
    if not isinstance(img, dict) or not isinstance(img.get("file"), str) or not img["file"] \
            or set(img) - {"file", "extent"}:
        raise InputError('"image" must be {"file": "PATH", "extent": [x0, y0, x1, y1]} (extent optional)', str(path))
    extent = img.get("extent")
    if extent is not None:
        if not isinstance(extent, list) or not all(isinstance(v, (int, float)) for v in extent):
            raise InputError('"image" "extent" must be four numbers [x0, y0, x1, y1]', str(path))
        e = check_extent(extent, str(path))
        extent = (e[0], e[1], e[2], e[3])
    f = Path(img["file"])
    folder = path.parent.resolve()
    target = (folder / f).resolve()
    if f.is_absolute() or folder not in target.parents:
        raise InputError(f'"image" "file" {img["file"][:200]!r} lies outside the plan\'s folder: give a file in '
                         "that folder (or the image with --floorplan-image)", str(path))
    return path.parent / f, extent


def plan_image_file(path: str | Path) -> Path | None:
    """The image file a user's plan at ``path`` names, None without one or when the plan is unreadable (the
    reading proper reports that)."""
    try:
        image = plan_image(_read_doc(Path(path)), Path(path))
    except (OSError, ValueError, InputError):
        return None
    return None if image is None else image[0]


def check_plan_frame(doc: dict, fixes_xy: np.ndarray) -> dict | None:
    """Whether the plan ``doc`` (workspace GeoJSON) is in the frame of the data's fixes (n, 2): {"fixes",
    "fixes_inside" (share within 1 m of walkable space), "wrong_frame" (under MIN_FIXES_INSIDE), and when
    wrong "correction" (the SE(2) move of the fixes that fits them best,
    :func:`rmbuild.floorplan.frame_correction`) and "warning" (one line naming the plan)}; None without fixes."""
    xy = np.asarray(fixes_xy, float).reshape(-1, 2)
    xy = xy[np.isfinite(xy).all(axis=1)]
    if not len(xy):
        return None
    plan = from_local_geojson(doc)
    share = float(plan.inside(xy, tolerance_m=1.0).mean())
    out: dict = {"fixes": int(len(xy)), "fixes_inside": round(share, 3), "wrong_frame": share < MIN_FIXES_INSIDE}
    if not out["wrong_frame"]:
        return out
    c = frame_correction(plan, xy)
    out["correction"] = {"turn_deg": round(c["turn_deg"], 1), "shift_m": [round(v, 2) for v in c["shift_m"]],
                         "moved_m": round(c["moved_m"], 2), "fixes_inside": round(c["best_inside"], 3)}
    label = doc.get("source") or doc.get("name") or "(unnamed)"
    head = f"floor plan {label}: only {share:.0%} of the {len(xy)} fixes lie in its walkable space (1 m)"
    if not c["searched"]:
        out["warning"] = f"{head}, and they spread too wide to search for a shift or turn that fits them"
    elif c["best_inside"] >= MIN_FIXES_INSIDE:
        dx, dy = c["shift_m"]
        move = (f"moved by ({dx:+.0f}, {dy:+.0f}) m" if c["turn_deg"] == 0 else
                f"turned {c['turn_deg']:+.0f} deg about their centre and shifted ({c['moved_m']:.0f} m on average)")
        out["warning"] = f"{head}, {c['best_inside']:.0%} once {move}: it looks to be in another frame"
    else:
        out["warning"] = (f"{head}, and no shift or turn fits them (at best {c['best_inside']:.0%}): it looks "
                          "like another floor's plan, or a mirrored one")
    return out
