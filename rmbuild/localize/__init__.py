"""Localizers behind one fit/predict protocol (see :mod:`rmbuild.localize.base`).

The names below are imported on first use, so that importing :mod:`rmbuild.localize.registry` (the CLI
does, for its ``--localizer`` choices) stays free of numpy and pandas.
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = [
    "LOCALIZERS", "Localizer", "Query", "ReferenceSet", "localizer_class", "make_localizer", "steps_from_poses",
]


def __getattr__(name: str) -> Any:
    if name in __all__:
        return getattr(importlib.import_module("rmbuild.localize.base"), name)
    raise AttributeError(f"module 'rmbuild.localize' has no attribute {name!r}")
