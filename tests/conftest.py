"""Shared fixtures: a small hand-made valid input in rmbuild's schema, and CLI helpers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

SHARED_DATASETS = Path(__file__).resolve().parents[2] / "shared" / "datasets"


def make_input_tables(n_walks: int = 2, n_steps: int = 30, seed: int = 0) -> dict[str, pd.DataFrame]:
    """A tiny valid input: straight-ish walks, a scan every 4 steps hearing 4 APs."""
    rng = np.random.default_rng(seed)
    poses, wifi, walks, fixes = [], [], [], []
    aps = [f"00:11:22:33:44:{i:02x}" for i in range(6)]
    for w in range(n_walks):
        wid = f"walk{w}"
        t = 100.0 * w + 0.5 * np.arange(n_steps)
        heading = np.cumsum(rng.normal(0, 0.02, n_steps))
        heading[0] = 0.0
        x = np.r_[0.0, np.cumsum(0.7 * np.cos(heading[1:]))]
        y = np.r_[0.0, np.cumsum(0.7 * np.sin(heading[1:]))]
        poses.append(pd.DataFrame({"walk_id": wid, "t_s": t, "x_m": x, "y_m": y, "heading_rad": heading}))
        for k in range(0, n_steps, 4):
            for j, ap in enumerate(aps[w: w + 4]):
                wifi.append((wid, t[k] + 0.1, ap, float(-40 - 5 * j - k % 7), 2437.0, f"net{j}"))
        walks.append((wid, f"dev{w % 2}", f"user{w}", ""))
        fixes.append((wid, t[n_steps // 2], 5.0 + w, 2.0, "L1"))
    return {
        "walks": pd.DataFrame(walks, columns=["walk_id", "device_id", "user_id", "role"]),
        "poses": pd.concat(poses, ignore_index=True),
        "wifi": pd.DataFrame(wifi, columns=["walk_id", "t_s", "bssid", "rssi_dbm", "freq_mhz", "ssid"]),
        "fixes": pd.DataFrame(fixes, columns=["walk_id", "t_s", "x_m", "y_m", "label"]),
    }


def write_tables(tables: dict[str, pd.DataFrame], folder: Path, fmt: str = "csv") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for name, df in tables.items():
        if fmt == "parquet":
            df.to_parquet(folder / f"{name}.parquet", index=False)
        else:
            df.to_csv(folder / f"{name}.csv", index=False)
    return folder


@pytest.fixture
def small_input(tmp_path: Path) -> Path:
    return write_tables(make_input_tables(), tmp_path / "input")


@pytest.fixture
def shared_datasets() -> Path:
    if not SHARED_DATASETS.is_dir():
        pytest.skip("../shared/datasets not present")
    return SHARED_DATASETS
