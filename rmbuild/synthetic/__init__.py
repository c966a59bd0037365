"""The seeded synthetic venue: floor plan, access points, walkers with foot-IMU dead reckoning and
magnetometer, Wi-Fi scans, and the truth behind them. Pure, in memory; entry point :func:`simulate`."""

from __future__ import annotations

from rmbuild.config.simulate import PRESETS, SimulateConfig, preset_config
from rmbuild.synthetic.radio import RadioModel
from rmbuild.synthetic.simulate import SimulatedData, radio_field, simulate

__all__ = [
    "PRESETS", "RadioModel", "SimulateConfig", "SimulatedData", "preset_config", "radio_field", "simulate",
]
