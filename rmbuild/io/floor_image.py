"""A floor plan's raster image (a scan or drawing of the floor, for display only).

The image travels with its plan: in memory the plan's GeoJSON dict holds ``"image": {"png": bytes,
"extent_m": [x0, y0, x1, y1]}`` (the image's edges in the plan's local metres: left, bottom, right, top);
the workspace keeps the PNG (``data.floor_image``) and the plan's ``"image"`` member as ``{"file": its name,
"extent_m": [...]}`` (:func:`split_image`). Images are re-encoded as PNG at most
:data:`DISPLAY_MAX_PX` on their long side: they are drawn under the walks, never measured.
"""

from __future__ import annotations

import io
import warnings
from pathlib import Path

import numpy as np

from rmbuild.errors import InputError
from rmbuild.io.workspace import ARTEFACTS, Workspace
from rmbuild.limits import MAX_IMAGE_BYTES, MAX_IMAGE_PIXELS

#: px; the long side of the kept image (a floor of 250 m at ~0.12 m per pixel)
DISPLAY_MAX_PX = 2048


def read_image(path: str | Path) -> bytes:
    """The image at ``path`` (any format Pillow reads: PNG, JPEG, TIFF, ...) as PNG bytes, scaled down to
    :data:`DISPLAY_MAX_PX`; InputError naming the file when it is unreadable or too large."""
    from PIL import Image, UnidentifiedImageError

    p = Path(path)
    try:
        if p.stat().st_size > MAX_IMAGE_BYTES:
            raise InputError(f"floor plan image larger than {MAX_IMAGE_BYTES // 2**20} MB", str(p))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # the bound is MAX_IMAGE_PIXELS
            with Image.open(p) as im:
                if im.width * im.height > MAX_IMAGE_PIXELS:
                    raise InputError(f"floor plan image of {im.width} x {im.height} pixels: more than "
                                     f"{MAX_IMAGE_PIXELS:,}", str(p))
                im.draft("RGB", (DISPLAY_MAX_PX, DISPLAY_MAX_PX))  # JPEG: decode at a reduced size
                rgb = im.convert("RGBA" if "A" in im.getbands() else "RGB")
        rgb.thumbnail((DISPLAY_MAX_PX, DISPLAY_MAX_PX))
        out = io.BytesIO()
        rgb.save(out, format="PNG", optimize=False)
        return out.getvalue()
    except InputError:
        raise
    except UnidentifiedImageError:
        raise InputError("not an image Pillow can read (PNG, JPEG, TIFF, ...)", str(p)) from None
    except OSError as e:
        raise InputError(f"cannot read floor plan image: {e.strerror or str(e)[:200]}", str(p)) from None
    except (ValueError, Image.DecompressionBombError) as e:
        raise InputError(f"unusable floor plan image: {str(e)[:200]}", str(p)) from None


def check_extent(extent: tuple[float, ...] | list[float], where: str) -> list[float]:
    """``extent`` (x0, y0, x1, y1) as floats; InputError (``where``) unless finite with x0 < x1, y0 < y1."""
    e = [float(v) for v in extent]
    if len(e) != 4 or not np.isfinite(e).all() or e[0] >= e[2] or e[1] >= e[3]:
        raise InputError(f"image extent must be four finite numbers x0,y0,x1,y1 with x0 < x1 and y0 < y1, "
                         f"got {','.join(f'{v:g}' for v in e)}", where)
    return e


def attach_image(plan: dict, png: bytes, extent_m: list[float]) -> dict:
    """A copy of ``plan`` (workspace GeoJSON) carrying the image ``png`` over ``extent_m``."""
    return {**plan, "image": {"png": png, "extent_m": [float(v) for v in extent_m]}}


def split_image(plan: dict) -> tuple[dict, bytes | None]:
    """(the plan as the workspace keeps it, the PNG bytes or None): the in-memory image member becomes a
    reference to the workspace's image file."""
    img = plan.get("image")
    if not isinstance(img, dict) or "png" not in img:
        return plan, None
    name = Path(ARTEFACTS["data.floor_image"]).name
    return {**plan, "image": {"file": name, "extent_m": img["extent_m"]}}, img["png"]


def decode(png: bytes) -> np.ndarray:
    """(rows, cols, 3 or 4) uint8 pixels of PNG bytes; row 0 is the image's top."""
    from PIL import Image

    with Image.open(io.BytesIO(png)) as im:
        return np.asarray(im.convert("RGBA" if "A" in im.getbands() else "RGB"))


def load_image(ws: Workspace) -> tuple[np.ndarray, list[float]] | None:
    """The workspace's plan image as (pixels, extent_m), None when it has none."""
    if not (ws.exists("data.floor_image") and ws.exists("data.floorplan")):
        return None
    extent = (ws.read_json("data.floorplan").get("image") or {}).get("extent_m")
    return None if extent is None else (decode(ws.read_bytes("data.floor_image")), [float(v) for v in extent])
