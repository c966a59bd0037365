"""Floor plans on disk: a user's GeoJSON (``rmbuild ingest --floorplan``) and the workspace's copy.

The workspace keeps the plan in local metres (``data/floorplan.geojson``, :func:`rmbuild.floorplan.to_geojson`)
whatever it came as, so later stages never re-project it.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from rmbuild.errors import InputError
from rmbuild.floorplan import from_local_geojson, from_user_geojson, to_geojson

#: bytes; a larger plan file is refused (a detailed mall floor is a few MB)
MAX_PLAN_BYTES = 64 * 1024 * 1024
#: share of the ground-truth fixes that should fall in walkable space (1 m tolerance); fewer suggests the
#: plan is not in the fixes' frame
MIN_FIXES_INSIDE = 0.8


def read_user_plan(path: str | Path) -> dict:
    """The plan at ``path`` (GeoJSON in WGS84 lon/lat, or local metres with ``"frame": "local_m"``) as
    workspace GeoJSON; InputError naming the file otherwise."""
    p = Path(path)
    try:
        if p.stat().st_size > MAX_PLAN_BYTES:
            raise InputError(f"floor plan larger than {MAX_PLAN_BYTES // 2**20} MB", str(p))
        doc = json.loads(p.read_bytes())
        return to_geojson(from_user_geojson(doc, p.stem))
    except InputError:
        raise
    except OSError as e:
        raise InputError(f"cannot read floor plan: {e.strerror or e}", str(p)) from None
    except (ValueError, KeyError, TypeError, IndexError, AttributeError) as e:
        raise InputError(f"not a usable GeoJSON floor plan: {str(e)[:200]}", str(p)) from None


def fixes_inside_share(doc: dict, fixes_xy: np.ndarray) -> float | None:
    """Share of the fixes (n, 2) within 1 m of walkable space; None without fixes."""
    xy = np.asarray(fixes_xy, float).reshape(-1, 2)
    xy = xy[np.isfinite(xy).all(axis=1)]
    if not len(xy):
        return None
    return float(from_local_geojson(doc).inside(xy, tolerance_m=1.0).mean())
