"""The held map of an incremental run: the walks the last optimize put in its map, kept as they are.

``optimize --incremental`` is the full method restricted: the held walks sit in the reference component from
the start (their frames the identity on their optimised poses), every evidence source is built knowing them
and contributes only what concerns the other walks, placement grows from them, and the solve keeps their
nodes fixed. Everything else (the new walks, and the old walks the last run could not link) is placed and
solved as in a full run.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from rmbuild.errors import InputError
from rmbuild.slam.problem import WalkSet
from rmbuild.types import OptimizeState


@dataclass(frozen=True)
class HeldMap:
    """The last optimize's state and its poses ``xyt`` (n_nodes, 3: x_m, y_m, heading_rad in the map frame;
    the first ``state.n_nodes`` nodes of the data set)."""

    state: OptimizeState
    xyt: np.ndarray


@dataclass(frozen=True)
class Holding:
    """What the sources and the solve are told of a held map: ``fixed`` (n_walks,) the held walks, ``old``
    (n_walks,) the walks the last optimize ran on, and its state (RF model, RSS exponent, frame)."""

    fixed: np.ndarray
    old: np.ndarray
    state: OptimizeState


def hold(walks: WalkSet, held: HeldMap) -> tuple[WalkSet, Holding]:
    """The walk set with the held walks' own-frame poses replaced by their optimised poses (identity frames
    in the map), and what is held. Raises InputError when the held map ran on other walks than this data
    set's first ones, when no walk was added, or when it holds no walk in a map."""
    st = held.state
    k = len(st.walk_ids)
    n_old = int(walks.ends[k - 1]) if 0 < k <= walks.n_walks else -1
    if k > walks.n_walks or list(walks.walk_ids[:k]) != list(st.walk_ids) or n_old != st.n_nodes \
            or len(held.xyt) != st.n_nodes:
        raise InputError("the last optimize ran on other walks than this workspace's earlier ingest; "
                         "--incremental only adds walks appended since (run a full `rmbuild optimize --force`)")
    if k == walks.n_walks:
        raise InputError("no new walks since the last optimize: --incremental places walks added with "
                         "`rmbuild ingest --append`")
    old = np.arange(walks.n_walks) < k
    linked = set(st.linked_walks)
    fixed = old & walks.keep & np.array([w in linked for w in walks.walk_ids])
    if not fixed.any():
        raise InputError("the last optimize placed no walk in a map: nothing to add to (run a full "
                         "`rmbuild optimize --force`)")
    raw = walks.raw.copy()
    nodes = np.flatnonzero(fixed[walks.walk_of[:n_old]])
    raw[nodes] = held.xyt[nodes]
    return replace(walks, raw=raw), Holding(fixed, old, st)


def reference(walks: WalkSet, h: Holding) -> int:
    """The held map's reference walk when it is held, else the longest held walk."""
    ref = h.state.reference_walk
    if ref in walks.walk_ids and h.fixed[walks.walk_ids.index(ref)]:
        return walks.walk_ids.index(ref)
    return int(np.argmax(np.where(h.fixed, walks.walk_lengths(), -1.0)))
