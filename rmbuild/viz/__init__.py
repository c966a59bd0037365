"""Inspection: the viewer contract, the rerun bridge (the only place importing rerun) and the HTML report.

Stages take ``viewer=None`` and call :func:`ensure_viewer`; a :class:`NullViewer` does nothing, so stages
never test whether viewing is on. Nothing here imports rerun or matplotlib at import time.
"""

from __future__ import annotations

from rmbuild.viz.rerun_bridge import RerunViewer, default_target, has_display, open_viewer
from rmbuild.viz.viewer import NullViewer, Viewer, ViewTarget, ensure_viewer

__all__ = ["NullViewer", "RerunViewer", "ViewTarget", "Viewer", "default_target", "ensure_viewer", "has_display",
           "open_viewer"]
