"""Vicinity-pair search (Gu et al. 2017, §III-B).

Two searches over the fingerprinted nodes ("rows"; row r is fingerprint r, node ``meta.node[r]``):

- :func:`median_window_pairs` — the paper as written: node k's threshold is the median RSS distance inside
  its own walk's window of L steps; (k, q) is a pair when d(k, q) < d_med(k), for q in any walk except
  same-walk nodes near in time or in walked distance. Blocked all-pairs matrix products, capped per node.
- :func:`run_matched_candidates` — rmbuild's candidates: consecutive scans are averaged into segments,
  each segment keeps its top-k nearest segments of other walks (mutual), and each surviving segment pair
  becomes the one node pair whose run of 2r+1 consecutive scans (same or opposite direction) matches best.

Both return a DataFrame with columns row_k, row_q (row_k < row_q), rss_dist (eq. 9, dB), common (APs),
kind ("within"/"cross") and, for candidates, run_dist (dB) and direction (+1 / -1).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pandas as pd

from rmbuild.blas import blocks_in_parallel
from rmbuild.slam.rss import RssMatrix

Progress = Callable[[str, dict], None] | None

#: entries (rows x columns) of one block of the segment search (16M: the `large` preset's ~5,000 segments
#: keep the full 1,024-row blocks; a venue-month's 50,000 get 335 rows)
BLOCK_ELEMS = 1 << 24
#: segments; every this-many-th segment is the sample that bounds each segment's k-th nearest distance
#: (about top_k x this many candidates per segment are then ranked)
SAMPLE_STRIDE = 8
#: segments; from this many on (a venue walked for months: ~600,000 poses) each segment's k nearest are sought
#: among the segments of the LEAF_PROBES leaves nearest to its own instead of among all: the exact sweep is
#: quadratic (a venue-year's 208,000 segments: ~10 min), this is linear. Leaves are LEAF_SEGMENTS segments
#: alike in the first LEAF_DIMS principal components of their RSS, cut by median splits. On a venue-month's
#: 52,000 segments it found 99.6 % of the exact sweep's neighbours (docs/notes/scale.md)
LEAF_MIN_SEGMENTS = 60_000
LEAF_SEGMENTS = 128
LEAF_PROBES = 64
LEAF_DIMS = 16


@dataclass(frozen=True)
class SearchParams:
    """What the searches need: the eq. 9 window (steps), shared APs per pair, the per-scan cap of the
    median-window rule, the run-matched search's segment length, top-k, mutual rule and run half-length,
    whether same-walk pairs are searched and how far apart in time (s) and walked path (m) they must be,
    and the block size (rows) of the blocked matrix products."""

    window_steps: int = 20
    min_common_aps: int = 3
    max_pairs_per_node: int = 10
    segment_scans: int = 2
    top_k: int = 8
    mutual: bool = True
    run_half_scans: int = 2
    within_walk: bool = True
    within_min_dt_s: float = 30.0
    within_min_path_m: float = 15.0
    block_rows: int = 2048


@dataclass
class RowMeta:
    """Per fingerprint row: node id, walk index, step, time (s) and walked PDR path length (m)."""

    node: np.ndarray
    walk: np.ndarray
    step: np.ndarray
    t_s: np.ndarray
    path_m: np.ndarray


def _allowed(meta: RowMeta, rows: np.ndarray, cols: np.ndarray | slice, pcfg: SearchParams, within: bool):
    """bool (len(rows), n_cols): pair may be searched (different walk, or same walk far in time and path)."""
    cw = meta.walk[cols]
    same = meta.walk[rows][:, None] == cw[None, :]
    ok = ~same
    if within:
        far = (np.abs(meta.t_s[rows][:, None] - meta.t_s[cols][None, :]) >= pcfg.within_min_dt_s) & (
            np.abs(meta.path_m[rows][:, None] - meta.path_m[cols][None, :]) >= pcfg.within_min_path_m
        )
        ok |= same & far
    return ok


def window_median(rm: RssMatrix, meta: RowMeta, L: int) -> np.ndarray:
    """d_med (n,) float32: for row k, the median of d(k, q) over the other rows q of k's walk whose step
    lies in k − L/2 … k + L/2 (NaN when the window holds no other scanned node)."""
    n = len(rm)
    half = L // 2
    cols = []
    for o in range(1, half + 1):
        i = np.arange(n - o)
        j = i + o
        ok = (meta.walk[i] == meta.walk[j]) & (np.abs(meta.step[j] - meta.step[i]) <= half)
        if not ok.any():
            break
        d = np.full(n - o, np.nan, np.float32)
        d[ok], _ = rm.pairs(i[ok], j[ok])
        fwd = np.full(n, np.nan, np.float32)
        bwd = np.full(n, np.nan, np.float32)
        fwd[:-o] = d
        bwd[o:] = d
        cols += [fwd, bwd]
    if not cols:
        return np.full(n, np.nan, np.float32)
    stack = np.stack(cols, axis=1)
    out = np.full(n, np.nan, np.float32)
    has = ~np.isnan(stack).all(axis=1)
    out[has] = np.nanmedian(stack[has], axis=1)
    return out


def _keep_smallest(rows: np.ndarray, cols: np.ndarray, d: np.ndarray, cap: int):
    """Keep per row the ``cap`` entries with the smallest d (cap 0 = all)."""
    if cap <= 0 or len(rows) == 0:
        return rows, cols, d
    order = np.lexsort((d, rows))
    rows, cols, d = rows[order], cols[order], d[order]
    start = np.r_[0, np.flatnonzero(np.diff(rows)) + 1]
    rank = np.arange(len(rows)) - np.repeat(start, np.diff(np.r_[start, len(rows)]))
    keep = rank < cap
    return rows[keep], cols[keep], d[keep]


def _dedupe(ri: np.ndarray, rj: np.ndarray, *cols: np.ndarray):
    a, b = np.minimum(ri, rj), np.maximum(ri, rj)
    key = a.astype(np.int64) * (1 << 32) + b
    _, first = np.unique(key, return_index=True)
    return (a[first], b[first]) + tuple(c[first] for c in cols)


def median_window_pairs(
    rm: RssMatrix, meta: RowMeta, pcfg: SearchParams, progress: Progress = None, only: np.ndarray | None = None
) -> tuple[pd.DataFrame, np.ndarray]:
    """The paper's pair rule over all row pairs (``only``, bool per row: the pairs with one of these rows);
    returns (pairs, d_med per row).

    Row k proposes q when d(k, q) < d_med(k), q allowed (see :func:`_allowed`), at least
    ``min_common_aps`` shared APs; each row keeps its ``max_pairs_per_node`` closest proposals; the
    union over both directions is returned once per unordered pair.
    """
    n = len(rm)
    thr = window_median(rm, meta, pcfg.window_steps)
    thr_f = np.where(np.isnan(thr), -np.inf, thr)
    out_r, out_c, out_d = [], [], []
    bs = pcfg.block_rows
    todo = np.arange(n) if only is None else np.flatnonzero(only)
    for s in range(0, len(todo), bs):
        rows = todo[s:s + bs]
        d, common = rm.block(rows)
        mask = (d < thr_f[rows][:, None]) & (common >= pcfg.min_common_aps)
        mask &= _allowed(meta, rows, slice(None), pcfg, within=True)
        r, c = np.nonzero(mask)
        r, c, dd = _keep_smallest(rows[r], c, d[r, c], pcfg.max_pairs_per_node)
        out_r.append(r)
        out_c.append(c)
        out_d.append(dd)
        if progress:
            progress("pair_search", {"done": s + len(rows), "total": len(todo)})
    r = np.concatenate(out_r) if out_r else np.zeros(0, np.int64)
    c = np.concatenate(out_c) if out_c else np.zeros(0, np.int64)
    d = np.concatenate(out_d) if out_d else np.zeros(0, np.float32)
    a, b, d = _dedupe(r, c, d)
    _, common = rm.pairs(a, b)
    df = pd.DataFrame({
        "row_k": a, "row_q": b, "rss_dist": d, "common": common.astype(np.int32),
        "kind": np.where(meta.walk[a] == meta.walk[b], "within", "cross"),
    })
    return df, thr


def _segments(meta: RowMeta, seg: int) -> np.ndarray:
    """Segment id (n,) per row: consecutive rows of one walk grouped ``seg`` at a time."""
    n = len(meta.walk)
    start = np.r_[True, meta.walk[1:] != meta.walk[:-1]]
    walk_start_row = np.maximum.accumulate(np.where(start, np.arange(n), 0))
    local = np.arange(n) - walk_start_row
    new = start | (local % seg == 0)
    return np.cumsum(new) - 1


def run_matched_candidates(
    rm: RssMatrix, meta: RowMeta, pcfg: SearchParams, progress: Progress = None, rows: np.ndarray | None = None
) -> pd.DataFrame:
    """rmbuild's candidate pairs: segment top-k (mutual) then the best run-matched node pair per segment pair.
    ``rows`` (bool per row): only the pairs with a segment of these rows' walks (:func:`restricted_neighbours`)."""
    n = len(rm)
    seg = _segments(meta, pcfg.segment_scans)
    n_seg = int(seg.max()) + 1 if n else 0
    cnt = np.bincount(seg, minlength=n_seg).astype(np.float32)
    sa = np.zeros((n_seg, rm.a.shape[1]), np.float32)
    sb = np.zeros_like(sa)
    np.add.at(sa, seg, rm.a)
    np.add.at(sb, seg, rm.b)
    sa /= cnt[:, None]
    sb /= cnt[:, None]
    srm = RssMatrix(sa, sb, np.einsum("ij,ij->i", sa, sa, dtype=np.float64), sb.sum(axis=1, dtype=np.float64))
    first = np.r_[0, np.flatnonzero(np.diff(seg)) + 1]
    smeta = RowMeta(meta.node[first], meta.walk[first], meta.step[first],
                    np.bincount(seg, meta.t_s, n_seg) / cnt, np.bincount(seg, meta.path_m, n_seg) / cnt)
    k = min(pcfg.top_k, max(n_seg - 1, 1))
    if rows is not None:
        si, sj = restricted_neighbours(srm, smeta, pcfg, k, rows[first], progress)
    else:
        si, sj = segment_neighbours(srm, smeta, pcfg, k, progress)
    if pcfg.mutual and rows is None:
        key = set((si.astype(np.int64) * n_seg + sj).tolist())
        back = np.fromiter(((b * n_seg + a) in key for a, b in zip(si.tolist(), sj.tolist())), bool, len(si))
        si, sj = si[back], sj[back]
    si, sj = np.minimum(si, sj), np.maximum(si, sj)
    _, u = np.unique(si.astype(np.int64) * n_seg + sj, return_index=True)
    si, sj = si[u], sj[u]
    return _best_run_pairs(rm, meta, seg, first, cnt.astype(np.int64), si, sj, pcfg)


def _masked_sq(srm: RssMatrix, smeta: RowMeta, rows: np.ndarray, cols: np.ndarray, pcfg: SearchParams) -> np.ndarray:
    """Squared eq. 9 distances rows x cols (float32), inf where the pair is not searched (too few shared
    APs, or same walk and not allowed by :func:`_allowed`)."""
    d, common = srm.block_sq32(rows, cols)
    d[common < pcfg.min_common_aps] = np.inf
    # only the columns of the rows' own walks can be disallowed (_allowed is True across walks)
    same = np.flatnonzero(np.isin(smeta.walk[cols], np.unique(smeta.walk[rows])))
    sub = d[:, same]
    sub[~_allowed(smeta, rows, cols[same], pcfg, within=pcfg.within_walk)] = np.inf
    d[:, same] = sub
    return d


def segment_neighbours(srm: RssMatrix, smeta: RowMeta, pcfg: SearchParams, k: int,
                       progress: Progress = None) -> tuple[np.ndarray, np.ndarray]:
    """(si, sj): each segment's (up to) ``k`` nearest searchable segments (finite distance), one row per
    (segment, neighbour), in order of segment, distance, neighbour.

    Up to LEAF_MIN_SEGMENTS segments exactly: each row's k-th smallest distance to every SAMPLE_STRIDE-th
    segment bounds its k-th nearest from above; one sweep over the upper triangle of the distance matrix (it is
    symmetric) then keeps every entry within its row's or its column's bound, and the k smallest per row are
    taken from those. From LEAF_MIN_SEGMENTS on among the segments of the nearest leaves (:func:`leaf_blocks`).
    The blocks run on worker threads (:func:`rmbuild.blas.blocks_in_parallel`)."""
    n = len(srm)
    if n >= LEAF_MIN_SEGMENTS:
        jobs = leaf_blocks(srm)
        parts = blocks_in_parallel(lambda job: _leaf_candidates(srm, smeta, pcfg, k, *job), jobs,
                                   _progress_of(progress, np.cumsum([len(r) for r, _ in jobs])))
    else:
        bs = max(16, min(pcfg.block_rows // 2, BLOCK_ELEMS // max(n, 1)))
        bound = _sample_bounds(srm, smeta, pcfg, k, bs)
        starts = list(range(0, n, bs))
        parts = blocks_in_parallel(lambda s: _sweep_block(srm, smeta, pcfg, bound, s, min(n, s + bs)), starts,
                                   _progress_of(progress, [min(n, s + bs) for s in starts], n))
    ri, ci, dd = (np.concatenate([p[i] for p in parts]) for i in range(3))
    order = np.lexsort((ci, dd, ri))
    ri, ci = ri[order], ci[order]
    start = np.r_[0, np.flatnonzero(np.diff(ri)) + 1] if len(ri) else np.zeros(0, np.int64)
    rank = np.arange(len(ri)) - np.repeat(start, np.diff(np.r_[start, len(ri)]))
    return ri[rank < k], ci[rank < k]


def restricted_neighbours(srm: RssMatrix, smeta: RowMeta, pcfg: SearchParams, k: int, new: np.ndarray,
                          progress: Progress = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`segment_neighbours` and the mutual rule for the pairs with a ``new`` segment (bool per segment):
    each new segment's ``k`` nearest searchable segments, kept when the pair is mutual. A new neighbour's own
    k nearest are known; an old neighbour's k-th distance is bounded from above by its k-th nearest among every
    SAMPLE_STRIDE-th segment (:func:`_sample_bounds`), so the rule keeps a few more pairs than the full
    search would (the old-by-old distances are never computed)."""
    n = len(srm)
    rows = np.flatnonzero(new)
    bs = max(16, min(pcfg.block_rows // 2, BLOCK_ELEMS // max(n, 1)))
    cols = np.arange(n)
    starts = list(range(0, len(rows), bs))
    parts = blocks_in_parallel(lambda s: _leaf_candidates(srm, smeta, pcfg, k, rows[s:s + bs], cols), starts,
                               _progress_of(progress, [min(len(rows), s + bs) for s in starts], len(rows)))
    ri, ci, dd = (np.concatenate([p[i] for p in parts]) if parts else np.zeros(0) for i in range(3))
    ri, ci = ri.astype(np.int64), ci.astype(np.int64)
    if not pcfg.mutual or not len(ri):
        return np.minimum(ri, ci), np.maximum(ri, ci)
    key = set((ri * n + ci).tolist())
    back_new = np.fromiter(((b * n + a) in key for a, b in zip(ri.tolist(), ci.tolist())), bool, len(ri))
    old_cols = np.unique(ci[~new[ci]])
    bound = np.full(n, np.inf, np.float32)
    bound[old_cols] = _sample_bounds(srm, smeta, pcfg, k, bs, old_cols)
    keep = np.where(new[ci], back_new, dd <= bound[ci])
    return np.minimum(ri[keep], ci[keep]), np.maximum(ri[keep], ci[keep])


def _progress_of(progress: Progress, done_after: list | np.ndarray, total: int | None = None):
    """A callback for :func:`blocks_in_parallel`: block i done -> progress("pair_search", done, total)."""
    if progress is None:
        return None
    total = int(done_after[-1]) if total is None and len(done_after) else total
    return lambda i: progress("pair_search", {"done": int(done_after[i]), "total": total, "phase": "segments"})


def _sample_bounds(srm: RssMatrix, smeta: RowMeta, pcfg: SearchParams, k: int, bs: int,
                   rows: np.ndarray | None = None) -> np.ndarray:
    """Each row's (of ``rows``, default all) k-th smallest squared distance to every SAMPLE_STRIDE-th segment
    (inf with fewer)."""
    rows = np.arange(len(srm)) if rows is None else rows
    sample = np.arange(0, len(srm), SAMPLE_STRIDE)
    bound = np.full(len(rows), np.inf, np.float32)
    if len(sample) <= k:
        return bound

    def block(s: int) -> np.ndarray:
        # a copy: the column as a view would keep the block's whole (rows x sample) matrix alive until every
        # block is done (1.2 GB of the 500k-pose case's 2.2 GB peak)
        return np.partition(_masked_sq(srm, smeta, rows[s:s + bs], sample, pcfg), k - 1, axis=1)[:, k - 1].copy()

    starts = list(range(0, len(rows), bs))
    for s, b in zip(starts, blocks_in_parallel(block, starts)):
        bound[s:s + len(b)] = b
    return bound


def _sweep_block(srm: RssMatrix, smeta: RowMeta, pcfg: SearchParams, bound: np.ndarray, s: int, e: int):
    """The candidates of rows [s, e) against columns [s, n) and of the columns past the block against the
    rows: (row, column, squared distance) with the distance within that row's bound."""
    n = len(srm)
    rows, cols = np.arange(s, e), np.arange(s, n)
    d = _masked_sq(srm, smeta, rows, cols, pcfg)
    fin = np.isfinite(d)
    r, c = np.nonzero(fin & (d <= bound[rows][:, None]))  # candidates of the rows
    r2, c2 = np.nonzero(fin[:, e - s:] & (d[:, e - s:] <= bound[e:][None, :]))  # of the columns past the block
    return (np.r_[rows[r], cols[e - s + c2]], np.r_[cols[c], rows[r2]], np.r_[d[r, c], d[r2, e - s + c2]])


def leaf_blocks(srm: RssMatrix) -> list[tuple[np.ndarray, np.ndarray]]:
    """(rows, columns) per leaf: a leaf's segments (rows) and those of the LEAF_PROBES leaves whose centres lie
    nearest to its own (its own included). Leaves: the segments' RSS projected on its first LEAF_DIMS
    principal components (from every 7th segment), split at the median of the widest coordinate until at most
    LEAF_SEGMENTS remain."""
    from scipy.spatial import cKDTree

    x = srm.a.astype(np.float64)
    mu = x[::7].mean(axis=0)
    _, vec = np.linalg.eigh((x[::7] - mu).T @ (x[::7] - mu))
    y = (x - mu) @ vec[:, ::-1][:, :LEAF_DIMS]
    leaves, todo = [], [np.arange(len(y))]
    while todo:
        idx = todo.pop()
        if len(idx) <= LEAF_SEGMENTS:
            leaves.append(np.sort(idx))
            continue
        sub = y[idx]
        half = len(idx) // 2
        part = np.argpartition(sub[:, np.argmax(np.ptp(sub, axis=0))], half)
        todo += [idx[part[half:]], idx[part[:half]]]
    centre = np.stack([y[leaf].mean(axis=0) for leaf in leaves])
    _, near = cKDTree(centre).query(centre, k=min(LEAF_PROBES, len(leaves)))
    near = near.reshape(len(leaves), -1)
    return [(leaf, np.sort(np.concatenate([leaves[q] for q in near[i]]))) for i, leaf in enumerate(leaves)]


def _leaf_candidates(srm: RssMatrix, smeta: RowMeta, pcfg: SearchParams, k: int, rows: np.ndarray,
                     cols: np.ndarray):
    """(row, column, squared distance) of each row's k nearest searchable columns."""
    d = _masked_sq(srm, smeta, rows, cols, pcfg)
    kk = min(k, d.shape[1])
    part = np.argpartition(d, kk - 1, axis=1)[:, :kk]
    dd = np.take_along_axis(d, part, axis=1).ravel()
    ok = np.isfinite(dd)
    return np.repeat(rows, kk)[ok], cols[part.ravel()][ok], dd[ok]


def _best_run_pairs(rm, meta, seg, first, cnt, si, sj, pcfg: SearchParams) -> pd.DataFrame:
    """For each segment pair, the node pair (i in si, j in sj) with the smallest mean RSS distance over a
    run of 2r+1 consecutive rows of each walk, walked in the same (+1) or opposite (-1) direction."""
    n = len(rm)
    s, r = pcfg.segment_scans, pcfg.run_half_scans
    off = np.arange(-r, s + r)
    # extended row windows (rows outside the walk are marked invalid)
    def window(sg):
        rows = first[sg][:, None] + off[None, :]
        valid = (rows >= 0) & (rows < n)
        rc = np.clip(rows, 0, n - 1)
        valid &= meta.walk[rc] == meta.walk[first[sg]][:, None]
        return rc, valid

    out = []
    chunk = 4096
    for c0 in range(0, len(si), chunk):
        a_rows, a_ok = window(si[c0:c0 + chunk])
        b_rows, b_ok = window(sj[c0:c0 + chunk])
        A, Ab = rm.a[a_rows], rm.b[a_rows]
        B, Bb = rm.a[b_rows], rm.b[b_rows]
        dot = np.einsum("pim,pjm->pij", A, B)
        com = np.einsum("pim,pjm->pij", Ab, Bb)
        union = rm.cnt[a_rows][:, :, None] + rm.cnt[b_rows][:, None, :] - com
        sq = rm.sq[a_rows][:, :, None] + rm.sq[b_rows][:, None, :] - 2 * dot
        D = np.sqrt(np.maximum(sq, 0) / np.maximum(union, 1))
        D[~(a_ok[:, :, None] & b_ok[:, None, :])] = np.nan
        best = np.full(len(A), np.inf)
        bi = np.zeros(len(A), np.int64)
        bj = np.zeros(len(A), np.int64)
        bdir = np.ones(len(A), np.int64)
        for ii in range(r, r + s):
            for jj in range(r, r + s):
                for dr in (1, -1):
                    vals = np.stack([D[:, ii + o, jj + dr * o] for o in range(-r, r + 1)], axis=1)
                    nvalid = np.sum(~np.isnan(vals), axis=1)
                    if r > 0:  # nan-mean without numpy's all-NaN-row warning
                        m = np.where(nvalid > 0, np.nansum(vals, axis=1) / np.maximum(nvalid, 1), np.nan)
                    else:
                        m = vals[:, 0]
                    m = np.where((nvalid >= r + 1) & ~np.isnan(D[:, ii, jj]), m, np.inf)
                    better = m < best
                    best[better] = m[better]
                    bi[better], bj[better], bdir[better] = ii, jj, dr
        p = np.arange(len(A))
        ri, rj = a_rows[p, bi], b_rows[p, bj]
        valid = np.isfinite(best) & a_ok[p, bi] & b_ok[p, bj]
        out.append(pd.DataFrame({
            "row_k": ri[valid], "row_q": rj[valid], "rss_dist": D[p, bi, bj][valid].astype(np.float32),
            "common": com[p, bi, bj][valid].astype(np.int32), "run_dist": best[valid].astype(np.float32),
            "direction": bdir[valid],
        }))
    df = pd.concat(out, ignore_index=True) if out else pd.DataFrame({  # no pair (sparse Wi-Fi): typed, empty
        "row_k": np.zeros(0, np.int64), "row_q": np.zeros(0, np.int64), "rss_dist": np.zeros(0, np.float32),
        "common": np.zeros(0, np.int32), "run_dist": np.zeros(0, np.float32), "direction": np.zeros(0, np.int64)})
    a = np.minimum(df["row_k"].to_numpy(), df["row_q"].to_numpy())
    b = np.maximum(df["row_k"].to_numpy(), df["row_q"].to_numpy())
    df["row_k"], df["row_q"] = a, b
    df = df[df["common"] >= pcfg.min_common_aps].drop_duplicates(["row_k", "row_q"]).reset_index(drop=True)
    df["kind"] = np.where(meta.walk[df["row_k"].to_numpy()] == meta.walk[df["row_q"].to_numpy()], "within", "cross")
    return df
