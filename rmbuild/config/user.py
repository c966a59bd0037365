"""The settings a user changes: what `rmbuild config` prints by default (`--all` prints every setting).

Every other setting keeps its default unless a config file sets it (all are documented, typed and checked
alike); the split only decides what a first look at the configuration shows. `simulate` is a tool of its
own (the synthetic venue), so its settings are not among the pipeline's: `rmbuild simulate --print-config`
or `rmbuild config --stage simulate` prints them.
"""

from __future__ import annotations

#: section -> the dotted names (below the section) of its user settings, in the order a user meets them
USER_SETTINGS: dict[str, tuple[str, ...]] = {
    "ingest": (
        "attach", "max_attach_gap_s", "rssi_min_dbm", "rssi_max_dbm",
        "msft_ilc.max_wifi_age_s", "ipin.origin_lat_deg", "ipin.origin_lon_deg", "ipin.use_imui",
    ),
    "pdr": ("heading_source", "step_length_m"),
    "optimize": (
        "reference_walk",
        "odometry.sigma_x_m", "odometry.sigma_y_m", "odometry.mu", "odometry.estimate_scale",
        "wifi.d_max", "wifi.omega", "wifi.min_common_aps", "wifi.within_walk", "wifi.calibrate_devices",
        "compass.use", "compass.default_sigma_rad",
        "continuity.use", "continuity.max_gap_s",
        "anchors.sigma_m", "anchors.max_gap_s",
        "floorplan.use",
        "placement.method", "placement.gate_m", "placement.min_inliers",
        "solve.max_iterations", "solve.outer_iterations",
    ),
    "map": (
        "cell_size_m", "min_count", "min_scans", "heatmap_top_n", "include_unlinked_walks",
        "fill.method", "fill.max_distance_m",
    ),
    "evaluate": (
        "localizers", "split_every", "split_offset", "query", "floor_penalty_m",
        "knn.k", "knn.missing", "knn.fill_dbm", "knn.reference",
    ),
    "build": ("scheduler", "worker_memory_gb"),
}

#: sections that belong to a tool of their own, printed only when asked for by name or with --all
OWN_TOOL_SECTIONS = ("simulate",)


def user_keys(section: str) -> frozenset[str] | None:
    """The user settings of ``section`` (None: a section printed whole when asked for)."""
    keys = USER_SETTINGS.get(section)
    return None if keys is None else frozenset(keys)
