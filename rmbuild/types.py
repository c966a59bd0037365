"""The in-memory data model shared by every stage.

Tables are pandas DataFrames with fixed column names (units in the names); the column lists below are the
contract between readers, the workspace and the numerical core. A *node* is one pose of one walk; node ids
are the row positions of :attr:`Dataset.poses` (walks in order, steps in order within a walk).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

#: Per-walk metadata. ``role`` is "" (unspecified), "map" or "test" (evaluation split hint).
WALK_COLUMNS = ("walk_id", "device_id", "user_id", "role", "source")
#: Per-step poses in the walk's own frame. Node id = row position.
#: ``yaw_abs_rad``: an absolute (e.g. magnetometer-referenced) heading observation of this step in an
#: unknown-but-common world frame, NaN when the device has none; ``yaw_abs_sigma_rad`` its 1-sigma.
#: ``step_freq_hz``: step frequency at this step (NaN when unknown), for step models S = alpha f + beta.
POSE_COLUMNS = (
    "walk_id", "step", "t_s", "x_m", "y_m", "heading_rad", "yaw_abs_rad", "yaw_abs_sigma_rad", "step_freq_hz",
)
#: Wi-Fi readings; ``node`` = the pose node the reading is attached to (docs/data-format.md).
WIFI_COLUMNS = ("walk_id", "t_s", "bssid", "rssi_dbm", "freq_mhz", "ssid", "node")
#: BLE beacon readings: the Wi-Fi columns, ``bssid`` holding the beacon id (its MAC address) and ``ssid`` its
#: iBeacon identity ``uuid:major:minor`` ("" when unknown); ``freq_mhz`` NaN (docs/data-format.md).
BLE_COLUMNS = WIFI_COLUMNS
#: Ground-truth position fixes (landmarks / waypoints), building frame.
FIX_COLUMNS = ("walk_id", "t_s", "x_m", "y_m", "label")
#: True poses per step (synthetic data only), building frame.
TRUTH_POSE_COLUMNS = ("walk_id", "step", "t_s", "x_m", "y_m", "heading_rad")
#: Anchors: known building-frame positions of a walk at a time (optional; fix the map's frame).
ANCHOR_COLUMNS = ("walk_id", "t_s", "x_m", "y_m")
#: Gauges (what fixed the optimised map's frame) whose frame is the building's: known anchor positions, or
#: the floor plan. The other gauge, "se2", leaves the frame one walk's; comparisons to truth fit an SE(2).
BUILDING_FRAME_GAUGES = ("anchors", "floorplan")


@dataclass
class Dataset:
    """Everything ingest produces: walks, their poses, attached Wi-Fi (and BLE) readings and ground truth.

    ``poses`` is sorted by walk (in ``walks`` order) then step, with a RangeIndex: row i is node i.
    ``truth_poses`` (same row order as ``poses`` when present) and ``truth_aps`` exist for synthetic data.
    ``venue`` is an optional JSON-able description of the floor plan (walls as segments, bounds).
    ``ble``: BLE beacon readings with :data:`BLE_COLUMNS` attached to nodes like ``wifi``; None when the input
    had none.
    """

    walks: pd.DataFrame
    poses: pd.DataFrame
    wifi: pd.DataFrame
    fixes: pd.DataFrame
    truth_poses: pd.DataFrame | None = None
    truth_aps: pd.DataFrame | None = None
    venue: dict | None = None
    extra: dict = field(default_factory=dict)
    ble: pd.DataFrame | None = None

    @property
    def n_nodes(self) -> int:
        return len(self.poses)

    def walk_ids(self) -> list[str]:
        return list(self.walks["walk_id"])

    def walk_slices(self) -> dict[str, slice]:
        """walk_id -> slice of node ids (poses rows) of that walk."""
        out: dict[str, slice] = {}
        w = self.poses["walk_id"].to_numpy()
        if len(w) == 0:
            return out
        change = np.flatnonzero(w[1:] != w[:-1]) + 1
        starts = np.r_[0, change]
        ends = np.r_[change, len(w)]
        for s, e in zip(starts, ends):
            out[str(w[s])] = slice(int(s), int(e))
        return out

    def walk_index(self) -> np.ndarray:
        """int array (n_nodes,): index of each node's walk in ``walks`` order."""
        return pd.Index(self.walks["walk_id"]).get_indexer(self.poses["walk_id"]).astype(np.int64)


@dataclass
class Fingerprints:
    """Per-node fingerprints: the per-AP mean RSSI of the readings attached to each node (docs/data-format.md).

    ``node``: int64 (n,) node ids that have at least one reading, ascending.
    ``bssids``: (n_ap,) AP identifiers, column order of the matrices.
    ``rss_dbm``: float32 (n, n_ap) mean RSSI in dBm, NaN where the AP was not seen at that node.
    ``count``: int32 (n, n_ap) number of readings averaged.
    """

    node: np.ndarray
    bssids: np.ndarray
    rss_dbm: np.ndarray
    count: np.ndarray

    def __len__(self) -> int:
        return len(self.node)

    def subset(self, mask: np.ndarray) -> Fingerprints:
        """Rows where ``mask`` (bool over rows) is true."""
        return Fingerprints(self.node[mask], self.bssids, self.rss_dbm[mask], self.count[mask])

    @staticmethod
    def from_readings(wifi: pd.DataFrame, bssids: np.ndarray | None = None) -> Fingerprints:
        """Average readings per (node, bssid). ``wifi`` needs columns node, bssid, rssi_dbm."""
        if bssids is None:
            col, uniq = pd.factorize(wifi["bssid"], sort=True)
            bssids = np.asarray(uniq, dtype=object)
        else:
            col = pd.Index(bssids).get_indexer(wifi["bssid"])
        keep = col >= 0
        node_raw = wifi["node"].to_numpy(dtype=np.int64)[keep]
        col = col[keep]
        rss = wifi["rssi_dbm"].to_numpy(dtype=np.float64)[keep]
        nodes, row = np.unique(node_raw, return_inverse=True)
        n, m = len(nodes), len(bssids)
        # sums over the detected (node, AP) cells only: the dense (n, m) tables are written once
        cells, inv = np.unique(row * m + col, return_inverse=True)
        sums = np.bincount(inv, weights=rss, minlength=len(cells))
        cnt_c = np.bincount(inv, minlength=len(cells))
        mean = np.full(n * m, np.nan, dtype=np.float32)
        mean[cells] = sums / cnt_c
        cnt = np.zeros(n * m, dtype=np.int32)
        cnt[cells] = cnt_c
        return Fingerprints(nodes, np.asarray(bssids, dtype=object), mean.reshape(n, m), cnt.reshape(n, m))

    def to_long(self) -> pd.DataFrame:
        """Long table: node, bssid, rssi_dbm, count (one row per detected (node, AP))."""
        flat = np.flatnonzero(self.count.ravel() > 0)  # row-major, as np.nonzero: half its time
        r, c = np.divmod(flat, self.count.shape[1])
        return pd.DataFrame({
            "node": self.node[r],
            # dictionary-encoded: 10x faster to build and to write than one Python string per row
            "bssid": pd.Categorical.from_codes(c, categories=pd.Index(self.bssids.astype(str))),
            "rssi_dbm": self.rss_dbm.ravel()[flat].astype(np.float32),
            "count": self.count.ravel()[flat].astype(np.int32),
        })

    @staticmethod
    def from_long(df: pd.DataFrame) -> Fingerprints:
        bssids = np.array(sorted(df["bssid"].unique()), dtype=object)
        nodes = np.unique(df["node"].to_numpy(dtype=np.int64))
        r = np.searchsorted(nodes, df["node"].to_numpy(dtype=np.int64))
        c = pd.Index(bssids).get_indexer(df["bssid"])
        rss = np.full((len(nodes), len(bssids)), np.nan, dtype=np.float32)
        cnt = np.zeros((len(nodes), len(bssids)), dtype=np.int32)
        rss[r, c] = df["rssi_dbm"].to_numpy(dtype=np.float32)
        cnt[r, c] = df["count"].to_numpy(dtype=np.int32)
        return Fingerprints(nodes, bssids, rss, cnt)


#: version of :class:`OptimizeState`'s file (optimize/state.json); a file of another version is refused
OPTIMIZE_STATE_VERSION = 1


@dataclass(frozen=True)
class OptimizeState:
    """What later stages need from the last ``optimize``, typed (``report.json`` is for people and tools).

    ``walk_ids``: the walks it ran on, in node order, and ``n_nodes`` their poses (a prefix of the dataset's
    while walks are only appended); ``linked_walks``: the walks placed in the map's frame (by Wi-Fi links
    or anchors); ``reference_walk``; ``frame`` ("reference walk", "floorplan", "anchors") and ``gauge``
    ("se2", "floorplan", "anchors"); ``device_offsets_db``: per device, the RSS offset (dB) the Wi-Fi
    evidence took off; ``rss_exponent``: the powed representation's exponent; ``rf_model``: the RF model
    (near_mu, near_sigma, far_mu, far_sigma, dB) the Wi-Fi evidence calibrated; ``predicted_error_m``: per
    linked walk, its predicted placement error (m); ``rf_typical_match_db``: the RF check's typical walk (the
    median over walks of their scans' median RSS distance to the best match in another walk, dB; None when
    not measured), which an incremental run measures its new walks' phone offsets against."""

    walk_ids: tuple[str, ...]
    n_nodes: int
    linked_walks: tuple[str, ...]
    reference_walk: str
    frame: str
    gauge: str
    device_offsets_db: dict[str, float]
    rss_exponent: float
    rf_model: tuple[float, float, float, float]
    predicted_error_m: dict[str, float]
    rf_typical_match_db: float | None = None
    version: int = OPTIMIZE_STATE_VERSION

    def to_json(self) -> dict:
        return {"version": self.version, "walk_ids": list(self.walk_ids), "n_nodes": self.n_nodes,
                "linked_walks": list(self.linked_walks), "reference_walk": self.reference_walk,
                "frame": self.frame, "gauge": self.gauge, "device_offsets_db": dict(self.device_offsets_db),
                "rss_exponent": self.rss_exponent, "rf_model": list(self.rf_model),
                "predicted_error_m": dict(self.predicted_error_m), "rf_typical_match_db": self.rf_typical_match_db}

    @staticmethod
    def from_json(doc: dict) -> OptimizeState:
        """Raises KeyError / TypeError / ValueError on a malformed document (the workspace names the file)."""
        rf = tuple(float(v) for v in doc["rf_model"])
        if len(rf) != 4:
            raise ValueError("rf_model: 4 numbers expected")
        return OptimizeState(
            tuple(str(w) for w in doc["walk_ids"]), int(doc["n_nodes"]), tuple(str(w) for w in doc["linked_walks"]),
            str(doc["reference_walk"]), str(doc["frame"]), str(doc["gauge"]),
            {str(k): float(v) for k, v in doc["device_offsets_db"].items()}, float(doc["rss_exponent"]),
            (rf[0], rf[1], rf[2], rf[3]), {str(k): float(v) for k, v in doc["predicted_error_m"].items()},
            None if doc.get("rf_typical_match_db") is None else float(doc["rf_typical_match_db"]), int(doc["version"]))
