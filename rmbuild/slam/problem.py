"""The optimisation problem: the walks, each in its own dead-reckoned frame, as flat numpy arrays.

A :class:`WalkSet` is built once from a :class:`Dataset` (after the input checks) and is read by every
other part of the back end: node i is row i of ``dataset.poses``; walk w is row w of ``dataset.walks``
and owns nodes ``starts[w] .. ends[w] - 1``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from rmbuild import geometry
from rmbuild.errors import InputError
from rmbuild.types import Dataset, Fingerprints

POSE_COLUMNS = ("walk_id", "step", "t_s", "x_m", "y_m", "heading_rad")
# m; the bins of walked distance :func:`covered_m` counts
COVERED_BIN_M = 3.0


@dataclass
class WalkSet:
    """Walks in their own frames.

    ``raw`` (n, 3) own-frame poses [m, m, rad]; ``walk_of`` (n,) walk index of each node; ``starts`` /
    ``ends`` (n_walks,) node range of each walk; ``path`` (n,) metres walked since the walk's start;
    ``t_s`` / ``step`` (n,); ``keep`` (n_walks,) walks that take part (a walk of < 2 poses is skipped);
    ``yaw_abs`` / ``yaw_sigma`` (n,) absolute (compass) heading per step and its 1-sigma [rad], NaN where
    none; ``fingerprints``: the Wi-Fi fingerprints of the kept walks' nodes; ``device`` (n_walks,) the
    device that recorded each walk ("" when unknown).
    """

    walk_ids: list[str]
    raw: np.ndarray
    walk_of: np.ndarray
    starts: np.ndarray
    ends: np.ndarray
    path: np.ndarray
    t_s: np.ndarray
    step: np.ndarray
    keep: np.ndarray
    yaw_abs: np.ndarray
    yaw_sigma: np.ndarray
    fingerprints: Fingerprints
    device: np.ndarray | None = None

    @property
    def n(self) -> int:
        return len(self.raw)

    @property
    def n_walks(self) -> int:
        return len(self.walk_ids)

    def walk_lengths(self) -> np.ndarray:
        """Walked length (m) of each walk."""
        return walked_lengths(self.path, self.walk_of, self.n_walks)

    def scan_density(self) -> tuple[float, float]:
        """(median metres walked between consecutive Wi-Fi scans of a walk, median scans per walk with any);
        NaN where there are none."""
        node = self.fingerprints.node
        per_walk = np.bincount(self.walk_of[node], minlength=self.n_walks)
        same = self.walk_of[node[1:]] == self.walk_of[node[:-1]]
        gaps = np.diff(self.path[node])[same]
        spacing = float(np.median(gaps)) if len(gaps) else float("nan")
        return spacing, float(np.median(per_walk[per_walk > 0])) if per_walk.any() else float("nan")

    def apply_frames(self, T: np.ndarray, raw: np.ndarray | None = None) -> np.ndarray:
        """(n, 3) poses with walk w's own-frame poses (``raw`` or ``self.raw``) mapped by T[w] (n_walks, 3)."""
        raw = self.raw if raw is None else raw
        return geometry.compose(T[self.walk_of], raw)

    def world_xy(self, T: np.ndarray, nodes: np.ndarray) -> np.ndarray:
        """Positions (len(nodes), 2) of ``nodes`` under walk frames T (n_walks, 3)."""
        Tw = T[self.walk_of[nodes]]
        c, s = np.cos(Tw[:, 2]), np.sin(Tw[:, 2])
        x, y = self.raw[nodes, 0], self.raw[nodes, 1]
        return np.c_[Tw[:, 0] + c * x - s * y, Tw[:, 1] + s * x + c * y]

    def poses_frame(self, poses: pd.DataFrame, xyt: np.ndarray) -> pd.DataFrame:
        """The poses table (walk_id, step, t_s, x_m, y_m, heading_rad) of positions ``xyt`` (n, 3)."""
        return pd.DataFrame({
            "walk_id": poses["walk_id"].to_numpy(), "step": poses["step"].to_numpy(), "t_s": self.t_s,
            "x_m": xyt[:, 0], "y_m": xyt[:, 1], "heading_rad": xyt[:, 2],
        })

    @staticmethod
    def from_dataset(dataset: Dataset, fingerprints: Fingerprints, single_step_walks: str,
                     default_yaw_sigma_rad: float) -> tuple[WalkSet, list[str]]:
        """The walk set of ``dataset`` and the input warnings (skipped walks). Raises InputError for no
        poses, missing columns, NaN poses, no fingerprints or (with ``single_step_walks == "error"``) a
        walk of fewer than 2 poses."""
        keep, warnings = check_inputs(dataset, fingerprints, single_step_walks)
        poses = dataset.poses
        walk_ids = [str(w) for w in dataset.walks["walk_id"]]
        slices = {str(k): v for k, v in dataset.walk_slices().items()}
        starts = np.array([slices[w].start if w in slices else 0 for w in walk_ids], np.int64)
        ends = np.array([slices[w].stop if w in slices else 0 for w in walk_ids], np.int64)
        walk_of = dataset.walk_index()
        raw = poses[["x_m", "y_m", "heading_rad"]].to_numpy(float)
        n = len(raw)
        step_len = np.r_[0.0, np.hypot(np.diff(raw[:, 0]), np.diff(raw[:, 1]))]
        step_len[starts[starts < n]] = 0.0
        path = np.cumsum(step_len)
        path -= np.repeat(path[starts], ends - starts)  # metres walked within each walk
        yaw = poses["yaw_abs_rad"].to_numpy(float) if "yaw_abs_rad" in poses else np.full(n, np.nan)
        ysig = poses["yaw_abs_sigma_rad"].to_numpy(float) if "yaw_abs_sigma_rad" in poses else np.full(n, np.nan)
        ysig = np.where(np.isfinite(ysig) & (ysig > 0), ysig, default_yaw_sigma_rad)
        active = keep[walk_of]
        dev = (dataset.walks["device_id"].fillna("").astype(str).to_numpy(object) if "device_id" in dataset.walks
               else np.full(len(walk_ids), "", dtype=object))
        on = active[fingerprints.node]  # the fingerprints of the walks that take part (not copied when all do)
        ws = WalkSet(walk_ids, raw, walk_of, starts, ends, path, poses["t_s"].to_numpy(float),
                     poses["step"].to_numpy(), keep, yaw, ysig, fingerprints if on.all() else fingerprints.subset(on),
                     dev)
        return ws, warnings


def walked_lengths(path: np.ndarray, walk_of: np.ndarray, n_walks: int) -> np.ndarray:
    """Walked length (m) of each walk from the walked distance ``path`` of its nodes (0: none)."""
    hi = np.full(n_walks, -np.inf)
    lo = np.full(n_walks, np.inf)
    np.maximum.at(hi, walk_of, path)
    np.minimum.at(lo, walk_of, path)
    return np.where(np.isfinite(hi), hi - lo, 0.0)


def covered_m(path: np.ndarray, bin_m: float = COVERED_BIN_M) -> float:
    """Walked length (m) covered by a set of nodes: distinct ``bin_m`` bins of their walked distance."""
    return float(len(np.unique(np.floor(np.asarray(path) / bin_m)))) * bin_m


def check_inputs(dataset: Dataset, fp: Fingerprints, single_step_walks: str) -> tuple[np.ndarray, list[str]]:
    """Validate the dataset for the optimizer; returns (walks that take part (n_walks,), warnings)."""
    poses = dataset.poses
    if poses is None or len(poses) == 0:
        raise InputError("no poses: the dataset has no walk poses to optimise")
    for col in POSE_COLUMNS:
        if col not in poses:
            raise InputError(f"poses table lacks column {col!r}")
    bad = poses[["t_s", "x_m", "y_m", "heading_rad"]].isna().any(axis=1).to_numpy()
    if bad.any():
        r = int(np.flatnonzero(bad)[0])
        raise InputError(f"NaN in poses (first at node {r}, walk {poses['walk_id'].iloc[r]!s}, "
                         f"step {poses['step'].iloc[r]}); fix or drop those steps")
    if fp is None or len(fp) == 0:
        raise InputError("no Wi-Fi fingerprints: no pose node has a Wi-Fi reading attached")
    if fp.node.min() < 0 or fp.node.max() >= len(poses):
        raise InputError("fingerprint node ids outside the poses table")
    warnings: list[str] = []
    sizes = poses.groupby("walk_id", sort=False).size()
    keep = np.ones(len(dataset.walks), bool)
    for i, wid in enumerate(dataset.walks["walk_id"]):
        nwk = int(sizes.get(wid, 0))
        if nwk < 2:
            if single_step_walks == "error":
                raise InputError(f"walk {wid!s} has {nwk} pose(s); a walk needs at least 2 steps")
            keep[i] = False
            warnings.append(f"walk {wid!s} has {nwk} pose(s): skipped (kept at its raw pose, unlinked)")
    return keep, warnings
