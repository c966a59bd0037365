"""The self-building fingerprint database: fold located fingerprints into a set of reference points.

UILoc (Chen, Zhang and Xue, Sensors 2018, sec. 4.1): a fingerprint located online is looked up in the
database; if a reference point lies within 1 m of its position, the two are averaged (position and RSSI),
otherwise it is inserted as a new reference point. "Averaged" is taken as the running mean over every
fingerprint an RP has absorbed (per AP over the fingerprints that heard it; the position over all), so
the result does not depend on which of two fingerprints came first and an RP's values are plain means.
"""

from __future__ import annotations

import numpy as np

from rmbuild.radiomap.reference import ReferenceSet

#: Merge radius (m): a fingerprint this close to an RP is averaged into it (the paper's 1 m).
MERGE_RADIUS_M = 1.0


def merge_fingerprints(
    ref: ReferenceSet | None,
    xy: np.ndarray,
    rss_dbm: np.ndarray,
    bssids: np.ndarray,
    radius_m: float = MERGE_RADIUS_M,
) -> ReferenceSet:
    """``ref`` (None = an empty database) with the fingerprints ``rss_dbm`` (n, n_ap; NaN = not heard, columns
    ``bssids`` = the reference's) at ``xy`` (n, 2) folded in, in row order.

    Each fingerprint joins the nearest RP within ``radius_m`` (the RP moves to the mean position of its
    fingerprints; per AP the mean RSSI over the fingerprints that heard it) or becomes a new RP. The
    returned ``count`` (n_rp, n_ap) holds the readings per AP; an RP's weight in the position mean is its
    largest count (at least 1; ``ref.count`` None counts every existing reading once). Returns kind
    "nodes", ``std_db`` None (not tracked), the rows of ``ref`` first in their order, new RPs after.
    """
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    new = np.asarray(rss_dbm, dtype=np.float64)
    bssids = np.asarray(bssids, dtype=object)
    if ref is not None and not np.array_equal(ref.bssids, bssids):
        raise ValueError("fingerprint columns differ from the reference's APs")
    n0 = 0 if ref is None else len(ref)
    cap = n0 + len(xy)
    pos = np.zeros((cap, 2))
    val = np.full((cap, len(bssids)), np.nan)
    cnt = np.zeros((cap, len(bssids)), dtype=np.int64)
    size = np.zeros(cap, dtype=np.int64)
    if ref is not None and n0:
        pos[:n0] = ref.xy
        val[:n0] = ref.rss_dbm
        heard = np.isfinite(ref.rss_dbm)
        cnt[:n0] = ref.count if ref.count is not None else heard
        cnt[:n0] = np.where(heard, np.maximum(cnt[:n0], 1), 0)
        size[:n0] = np.maximum(cnt[:n0].max(axis=1, initial=0), 1)
    n = n0
    for p, v in zip(xy, new, strict=True):
        j = -1
        if n:
            d2 = ((pos[:n] - p) ** 2).sum(axis=1)
            j = int(np.argmin(d2))
            if d2[j] > radius_m * radius_m:
                j = -1
        if j < 0:
            pos[n], val[n], size[n] = p, v, 1
            cnt[n] = np.isfinite(v)
            n += 1
            continue
        size[j] += 1
        pos[j] += (p - pos[j]) / size[j]
        ok = np.isfinite(v)
        c = cnt[j, ok] + 1
        old = np.where(cnt[j, ok] > 0, val[j, ok], 0.0)
        val[j, ok] = old + (v[ok] - old) / c
        cnt[j, ok] = c
    interp = np.zeros(n, dtype=bool)
    if ref is not None and ref.interpolated is not None:
        interp[:n0] = ref.interpolated
    return ReferenceSet(pos[:n].copy(), val[:n].astype(np.float32), bssids, None, cnt[:n].astype(np.int32),
                        interp, "nodes")
