"""Reference points (RPs): what a radio map offers a localizer to match against.

It lives with the radio map (which builds it) so that ``radiomap`` never imports ``localize``; the
localizers import it from here (``rmbuild.localize.base`` re-exports it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class ReferenceSet:
    """Reference points (RPs) a localizer matches against: grid cells of a radio map or raw map nodes.

    ``xy``: float64 (n_rp, 2) metres, map frame. ``rss_dbm``: float32 (n_rp, n_ap) mean RSSI, NaN = not
    detected. ``std_db``: float32 (n_rp, n_ap) unbiased per-AP std (NaN where fewer than 2 readings or not
    detected) or None. ``count``: int32 (n_rp, n_ap) readings per AP or None. ``interpolated``: bool (n_rp,)
    True for filled (never visited) cells. ``kind``: "cells" or "nodes".
    """

    xy: np.ndarray
    rss_dbm: np.ndarray
    bssids: np.ndarray
    std_db: np.ndarray | None = None
    count: np.ndarray | None = None
    interpolated: np.ndarray | None = None
    kind: str = "cells"

    def __len__(self) -> int:
        return len(self.xy)

    def __post_init__(self) -> None:
        n = len(self.xy)
        if self.rss_dbm.shape != (n, len(self.bssids)):
            raise ValueError(f"rss_dbm shape {self.rss_dbm.shape} != ({n}, {len(self.bssids)})")

    def rows(self, sel: np.ndarray) -> ReferenceSet:
        """The RPs ``sel`` (bool mask or int index) with the same AP columns."""

        def pick(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[sel]

        return ReferenceSet(self.xy[sel], self.rss_dbm[sel], self.bssids, pick(self.std_db), pick(self.count),
                            pick(self.interpolated), self.kind)
