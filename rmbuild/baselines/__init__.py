"""Paper baselines: the localizers rmbuild is compared against, kept apart from the two it offers (kNN and
distance-weighted kNN in :mod:`rmbuild.localize`).

SLAC and its baselines (MLL, PFL, SSD, SSR, offline device calibration), naive Bayes and SmartLocator's
fusion, the RSS-histogram matchers and Kalman smoothing of the subway-station paper, UILoc and its
self-building database. Each is registered in :mod:`rmbuild.localize.registry`, so ``rmbuild evaluate
--localizer NAME`` runs it beside kNN; their settings are :mod:`rmbuild.baselines.config`
(docs/baselines.md).
"""
