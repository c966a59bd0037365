"""Inspection: the rerun bridge (the only place importing rerun) and the HTML report (matplotlib).

Stages take ``viewer=None`` and call :func:`ensure_viewer`; a :class:`NullViewer` does nothing, so stages
never test whether viewing is on. Nothing here imports rerun or matplotlib at import time.
"""

from __future__ import annotations

from rmbuild.viz.rerun_bridge import NullViewer, Viewer, ViewTarget, default_target, has_display, open_viewer


def ensure_viewer(viewer: Viewer | NullViewer | None) -> Viewer | NullViewer:
    """``viewer`` itself, or a :class:`NullViewer` when None."""
    return NullViewer() if viewer is None else viewer


__all__ = ["NullViewer", "ViewTarget", "Viewer", "default_target", "ensure_viewer", "has_display", "open_viewer"]
