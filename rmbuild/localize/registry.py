"""The localizer registry: name -> implementing class and a one-line description; the localizers rmbuild
offers (kNN, distance-weighted kNN) apart from the paper baselines of :mod:`rmbuild.baselines`.

No heavy imports here (the CLI builds its ``--localizer`` choices and help from it); classes are imported
only when :func:`rmbuild.localize.base.localizer_class` asks for one. Each class provides
``from_config(cfg: EvaluateConfig)`` returning a configured, unfitted instance.
"""

from __future__ import annotations

#: name -> ("module:Class", what it is): the localizers rmbuild offers. Explicit: a new one is one line here.
LOCALIZERS_OFFERED: dict[str, tuple[str, str]] = {
    "knn": ("rmbuild.localize.knn:KnnLocalizer", "FL / kNN: mean of the K RPs nearest in RSS space"),
    "wknn": ("rmbuild.localize.knn:WeightedKnnLocalizer", "distance-weighted kNN"),
}

#: the paper baselines (:mod:`rmbuild.baselines`), runnable by name beside them (docs/baselines.md)
BASELINES: dict[str, tuple[str, str]] = {
    "uiloc": ("rmbuild.baselines.uiloc:UilocLocalizer",
              "UILoc: kNN and least-squares multilateration fused by exp(-distance) weights"),
    "nb": ("rmbuild.baselines.bayes:NaiveBayesLocalizer", "naive Bayes, Gaussian kernel per AP (SmartLocator)"),
    "ssd": ("rmbuild.baselines.ssd:SsdLocalizer", "signal-strength differences between APs (offset-free)"),
    "ssr": ("rmbuild.baselines.ssd:SsrLocalizer", "signal-strength ratios between APs (gain-free)"),
    "hist": ("rmbuild.baselines.histogram:HistogramLocalizer", "RSS-histogram fingerprints, mark selection"),
    "hist_dir": ("rmbuild.baselines.histogram:DirectionHistogramLocalizer",
                 "direction-aware RSS-histogram fingerprints (uses steps)"),
    "mll": ("rmbuild.baselines.mll:MllLocalizer", "maximum likelihood of Wi-Fi and walked distance over a window"),
    "pfl": ("rmbuild.baselines.pfl:PflLocalizer", "particle filter: PDR steps + kNN fixes"),
    "slac": ("rmbuild.baselines.slac:SlacLocalizer", "SLAC: joint localization and device/step calibration"),
    "smartloc": ("rmbuild.baselines.smartloc:SmartLocator", "SmartLocator: auto-adaptive fusion of fixes and PDR"),
    "smartloc_static": ("rmbuild.baselines.smartloc:StaticSmartLocator",
                        "SmartLocator's static-weight fusion (the paper's comparison)"),
    "offline_cal": ("rmbuild.baselines.calibration:OfflineCalibrated",
                    "a localizer on scans mapped by a device model k, b fitted offline"),
    "knn_kf": ("rmbuild.baselines.smoothing:KnnKalman", "kNN, Kalman-smoothed with PDR"),
    "nb_kf": ("rmbuild.baselines.smoothing:NaiveBayesKalman", "naive Bayes, Kalman-smoothed with PDR"),
    "ssd_kf": ("rmbuild.baselines.smoothing:SsdKalman", "SSD, Kalman-smoothed with PDR"),
    "slac_kf": ("rmbuild.baselines.smoothing:SlacKalman", "SLAC, Kalman-smoothed with PDR"),
}

#: every name ``--localizer`` takes
REGISTRY: dict[str, tuple[str, str]] = {**LOCALIZERS_OFFERED, **BASELINES}


def localizer_names() -> list[str]:
    """Registered names, in registry order."""
    return list(REGISTRY)


def describe() -> str:
    """The offered localizers with what they are, then the baselines' names, for help texts."""
    offered = "; ".join(f"{n}: {d}" for n, (_, d) in LOCALIZERS_OFFERED.items())
    return f"{offered}; paper baselines (docs/baselines.md): {', '.join(BASELINES)}"
