"""`rmbuild optimize --incremental`: the last optimize's outputs read back as the solution new walks are
placed against (:mod:`rmbuild.slam.incremental`), with the checks that it is one."""

from __future__ import annotations

from rmbuild.errors import InputError
from rmbuild.io.workspace import Workspace
from rmbuild.slam.incremental import PreviousSolution


def previous_solution(ws: Workspace, anchors_given: bool) -> PreviousSolution:
    """The last optimize's poses, walks, pairs and report. Raises InputError when there is none, when it ran
    on the workspace's current ingest (nothing was appended since) or when ``--anchors`` were given (the
    map's frame is the last run's)."""
    if anchors_given:
        raise InputError("--incremental keeps the last optimize's frame: --anchors apply to a full "
                         "`rmbuild optimize --force`")
    if not ws.has("optimize"):
        raise InputError("--incremental needs an earlier optimize of this workspace to add walks to; run "
                         "`rmbuild optimize` first", str(ws.root))
    if "ingest" not in ws.stale_inputs("optimize"):
        raise InputError("the last optimize already ran on this workspace's current walks: nothing to add "
                         "(append walks with `rmbuild ingest --append` first)", str(ws.root))
    return PreviousSolution(ws.read_table("optimize.poses"), ws.read_table("optimize.walks"),
                            ws.read_table("optimize.pairs"), ws.read_report("optimize") or {})
