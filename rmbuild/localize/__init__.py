"""Localizers behind one fit/predict protocol (see :mod:`rmbuild.localize.base`)."""

from rmbuild.localize.base import (
    LOCALIZERS,
    Localizer,
    Query,
    ReferenceSet,
    localizer_class,
    make_localizer,
    steps_from_poses,
)

__all__ = [
    "LOCALIZERS", "Localizer", "Query", "ReferenceSet", "localizer_class", "make_localizer", "steps_from_poses",
]
