"""The localizer interface: reference sets (what a map offers), queries (what is localized), the protocol.

Every localizer — single-scan fingerprint matchers (kNN, naive Bayes, SSD) and sequence localizers that
also use each test walk's step events (SLAC, PFL) — has the same shape::

    loc = make_localizer("knn", evaluate_cfg)   # registry name -> configured instance
    loc.fit(radio_map)                          # a RadioMap or a ReferenceSet
    xy = loc.predict(query)                     # (n_scans, 2) metres in the map's frame, NaN = no estimate

A :class:`Query` carries, per scan, the fingerprint in the map's AP order, the scan time and walk id, and
(optionally) per-walk step tables in the walk's own frame, so a sequence localizer can walk each test
walk's scans in time order with :meth:`Query.walks` and read its steps from :attr:`Query.steps`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Literal, Protocol, runtime_checkable

import numpy as np
import pandas as pd

from rmbuild.errors import InputError
from rmbuild.localize.registry import REGISTRY
from rmbuild.radiomap.reference import ReferenceSet

if TYPE_CHECKING:
    from rmbuild.radiomap.build import RadioMap
    from rmbuild.types import Dataset

#: Columns of a per-walk step table (walk's own PDR frame): step time, length, heading, step frequency.
STEP_COLUMNS = ("t_s", "step_length_m", "heading_rad", "step_freq_hz")


@dataclass
class Query:
    """Scans to localize, in time order within each walk.

    ``rss_dbm``: float32 (n, n_ap) mean RSSI per AP in the column order ``bssids``, NaN = not detected.
    ``t_s``: float64 (n,) scan times (s, the walk's clock). ``walk_id``: object (n,). ``node``: int64 (n,)
    the pose node the scan is attached to (-1 unknown). ``steps``: walk_id -> DataFrame with
    :data:`STEP_COLUMNS` (the walk's PDR step events in its own frame), or None when not available.
    """

    rss_dbm: np.ndarray
    bssids: np.ndarray
    t_s: np.ndarray
    walk_id: np.ndarray
    node: np.ndarray
    steps: dict[str, pd.DataFrame] | None = None
    extra: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.t_s)

    def aligned(self, bssids: np.ndarray) -> Query:
        """The same scans with columns in the order ``bssids`` (APs unknown to it dropped, new ones NaN)."""
        bssids = np.asarray(bssids, dtype=object)
        if len(bssids) == len(self.bssids) and np.array_equal(bssids, self.bssids):
            return self
        col = pd.Index(self.bssids).get_indexer(bssids)
        out = np.full((len(self), len(bssids)), np.nan, dtype=np.float32)
        ok = col >= 0
        out[:, ok] = self.rss_dbm[:, col[ok]]
        return Query(out, bssids, self.t_s, self.walk_id, self.node, self.steps, dict(self.extra))

    def subset(self, mask: np.ndarray) -> Query:
        """Rows where ``mask`` (bool (n,) or int index) selects; steps of walks no longer present dropped."""
        wid = self.walk_id[mask]
        steps = None
        if self.steps is not None:
            keep = set(map(str, wid))
            steps = {k: v for k, v in self.steps.items() if k in keep}
        return Query(self.rss_dbm[mask], self.bssids, self.t_s[mask], wid, self.node[mask], steps,
                     dict(self.extra))

    def walks(self) -> list[tuple[str, np.ndarray]]:
        """(walk_id, row indices in time order) per walk, in order of first appearance."""
        out = []
        ids, first = np.unique(self.walk_id.astype(str), return_index=True)
        for wid in ids[np.argsort(first)]:
            rows = np.flatnonzero(self.walk_id.astype(str) == wid)
            out.append((str(wid), rows[np.argsort(self.t_s[rows], kind="stable")]))
        return out

    @staticmethod
    def count(dataset: Dataset, walk_ids: list[str], unit: Literal["scan", "node"] = "scan") -> int:
        """How many queries :meth:`from_dataset` makes of these walks (before their table is allocated)."""
        wifi = dataset.wifi
        wifi = wifi[wifi["walk_id"].astype(str).isin(set(map(str, walk_ids)))]
        cols = ["walk_id", "t_s"] if unit == "scan" else ["walk_id", "node"]
        return int(wifi[cols].drop_duplicates().shape[0]) if len(wifi) else 0

    @staticmethod
    def from_dataset(
        dataset: Dataset,
        walk_ids: list[str],
        bssids: np.ndarray | None = None,
        unit: Literal["scan", "node"] = "scan",
    ) -> Query:
        """Queries from the Wi-Fi readings of ``walk_ids`` (rows ordered by walk, then time).

        ``unit="scan"``: readings sharing (walk, t_s) form one scan (mean per AP if an AP repeats);
        ``unit="node"``: readings attached to one node form one query (its fingerprint; t_s = mean time).
        Readings without a node are kept for scans (node -1). Steps come from :func:`steps_from_poses`.
        """
        wifi = dataset.wifi
        wifi = wifi[wifi["walk_id"].astype(str).isin(set(map(str, walk_ids)))]
        if bssids is None:
            bssids = np.array(sorted(wifi["bssid"].astype(str).unique()), dtype=object)
        bssids = np.asarray(bssids, dtype=object)
        order = {w: i for i, w in enumerate(map(str, walk_ids))}
        wk = wifi["walk_id"].astype(str).to_numpy()
        node = wifi["node"].to_numpy() if "node" in wifi else np.full(len(wifi), -1)
        node = np.where(pd.isna(node), -1, node).astype(np.int64)
        t = wifi["t_s"].to_numpy(dtype=np.float64)
        if unit == "scan":
            key = pd.DataFrame({"w": [order[w] for w in wk], "t": t})
        else:
            key = pd.DataFrame({"w": [order[w] for w in wk], "n": node})
        grp = key.groupby(list(key.columns), sort=True).ngroup().to_numpy()
        n_q = int(grp.max()) + 1 if len(grp) else 0
        col = pd.Index(bssids).get_indexer(wifi["bssid"].astype(str))
        ok = col >= 0
        m = len(bssids)
        flat = grp[ok] * m + col[ok]
        rss = wifi["rssi_dbm"].to_numpy(dtype=np.float64)[ok]
        # sums over the heard (query, AP) cells only: the dense table is written once, as float32
        cells, inv = np.unique(flat, return_inverse=True)
        flat_mean = np.full(n_q * m, np.nan, dtype=np.float32)
        flat_mean[cells] = np.bincount(inv, weights=rss, minlength=len(cells)) / np.bincount(inv, minlength=len(cells))
        mean = flat_mean.reshape(n_q, m)
        size = np.bincount(grp, minlength=n_q)
        t_q = np.bincount(grp, weights=t, minlength=n_q) / np.maximum(size, 1)
        first = np.full(n_q, -1, dtype=np.int64)
        first[grp[::-1]] = np.arange(len(grp))[::-1]
        w_q = wk[first].astype(object)
        node_q = node[first]
        steps = {w: steps_from_poses(dataset.poses[dataset.poses["walk_id"].astype(str) == w])
                 for w in map(str, walk_ids)}
        q = Query(mean, bssids, t_q, w_q, node_q, steps)
        o = np.lexsort((q.t_s, np.array([order[w] for w in q.walk_id])))
        return q.subset(o)


def steps_from_poses(poses: pd.DataFrame) -> pd.DataFrame:
    """Step table (:data:`STEP_COLUMNS`) of one walk from its per-step poses (own frame, sorted by step).

    Step k (k >= 1) goes from pose k-1 to pose k: its length is their distance, its heading the heading of
    pose k, its time pose k's time.
    """
    x = poses["x_m"].to_numpy(dtype=float)
    y = poses["y_m"].to_numpy(dtype=float)
    f = poses["step_freq_hz"].to_numpy(dtype=float) if "step_freq_hz" in poses else np.full(len(x), np.nan)
    return pd.DataFrame({
        "t_s": poses["t_s"].to_numpy(dtype=float)[1:],
        "step_length_m": np.hypot(np.diff(x), np.diff(y)),
        "heading_rad": poses["heading_rad"].to_numpy(dtype=float)[1:],
        "step_freq_hz": f[1:],
    })


@runtime_checkable
class Localizer(Protocol):
    """What every localizer offers. ``name`` is its registry name (also its key in reports)."""

    name: ClassVar[str]

    def fit(self, ref: RadioMap | ReferenceSet) -> Localizer: ...

    def predict(self, query: Query) -> np.ndarray: ...

    def summary(self) -> dict:
        """Figures about the last predict for the report (e.g. calibrated parameters); {} when none."""
        ...


def checked(cfg, default_cls: type):
    """``cfg`` (or ``default_cls()``), validated: a bad value is a one-line :class:`InputError`."""
    cfg = cfg or default_cls()
    try:
        cfg.validate()
    except ValueError as e:
        raise InputError(f"config: {e}") from None
    return cfg


def sub_config(cfg, name: str, cls: type):
    """A baseline's own config from ``cfg``: an instance of ``cls`` as is, the table ``name`` of an
    EvaluateConfig's ``baselines`` (or of a BaselinesConfig), else ``cls()``."""
    from rmbuild.config.evaluate import EvaluateConfig

    if cfg is None:
        return cls()
    if isinstance(cfg, cls):
        return cfg
    if isinstance(cfg, EvaluateConfig):
        cfg = cfg.baselines
    sub = getattr(cfg, name, None)
    return sub if isinstance(sub, cls) else cls()


def as_reference(ref: RadioMap | ReferenceSet, kind: str = "cells") -> ReferenceSet:
    """A :class:`ReferenceSet` from a RadioMap (its ``kind`` view: "cells" or "nodes") or as is."""
    if isinstance(ref, ReferenceSet):
        return ref
    return ref.reference_set(kind)


#: Registry: name -> "module:Class" (see :mod:`rmbuild.localize.registry`, which also describes each).
LOCALIZERS: dict[str, str] = {name: target for name, (target, _) in REGISTRY.items()}


def localizer_class(name: str) -> type:
    """The class registered under ``name``; an unknown name is an :class:`InputError`."""
    if name not in LOCALIZERS:
        raise InputError(f"unknown localizer {name!r} (known: {', '.join(sorted(LOCALIZERS))})")
    import importlib

    mod, cls = LOCALIZERS[name].split(":")
    return getattr(importlib.import_module(mod), cls)


def make_localizer(name: str, cfg=None):
    """A configured, unfitted localizer. ``cfg``: an EvaluateConfig (None = defaults)."""
    if cfg is None:
        from rmbuild.config.evaluate import EvaluateConfig

        cfg = EvaluateConfig()
    cls: Any = localizer_class(name)
    return cls.from_config(cfg)
