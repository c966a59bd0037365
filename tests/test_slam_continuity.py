"""Session continuity (rmbuild/slam/evidence/continuity.py): consecutive walks of one device tied."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("gtsam")

from slam_venue import make_venue, split_walk, walk_set  # noqa: E402

from rmbuild.config.optimize import ContinuityConfig, OptimizeConfig  # noqa: E402
from rmbuild.evaluate.trajectory import trajectory_metrics  # noqa: E402
from rmbuild.slam import optimize  # noqa: E402
from rmbuild.slam.evidence.continuity import find_joins  # noqa: E402
from rmbuild.slam.rfmodel import RFModel  # noqa: E402


def test_joins_follow_time_within_one_device():
    walks = walk_set(np.zeros((12, 3)), np.repeat(np.arange(4), 3))
    walks.t_s = np.array([0, 1, 2, 30, 31, 32, 10, 11, 12, 200, 201, 202], float)
    walks.device = np.array(["a", "a", "a", "b"], dtype=object)
    seen: list[str] = []
    j = find_joins(walks, 60.0, seen)
    # walk 0 (0-2 s) -> walk 2 (10-12 s) -> walk 1 (30-32 s); walk 3 is another device
    assert list(zip(j.walk_a, j.walk_b)) == [(0, 2), (2, 1)] and np.allclose(j.gap_s, [8, 18])
    assert list(j.node_a) == [2, 8] and list(j.node_b) == [6, 3] and seen == []
    assert len(find_joins(walks, 10.0, seen).gap_s) == 1  # the 18 s gap is too long
    walks.t_s[6:9] = [1.5, 2.5, 3.5]  # walk 2 now overlaps walk 0: clocks not comparable
    assert len(find_joins(walks, 60.0, seen).gap_s) == 0 and seen == ["a"]


def test_rf_model_likelihood_ratio():
    m = RFModel(22.0, 3.0, 30.0, 4.0, 100, 100)
    assert m.log_lr(18.0) > 0 > m.log_lr(34.0)
    r = m.threshold_db()
    assert 22.0 < r < 30.0 and abs(m.log_lr(r)) < 1e-6
    assert m.threshold_db(np.log(3.0)) < r


@pytest.fixture(scope="module")
def session():
    """A venue whose first walk was recorded as three pieces by one device, 2 s apart; the middle piece has
    no Wi-Fi at all."""
    ds, fp = make_venue(n_walks=4, steps_per_walk=260, seed=3)
    ds = split_walk(ds, "w000", 3, 2.0)
    middle = np.flatnonzero(ds.poses["walk_id"].to_numpy() == "w000_1")
    return ds, fp.subset(~np.isin(fp.node, middle))


def test_a_walk_without_wifi_is_placed_by_its_neighbours_in_time(session):
    ds, fp = session
    on = optimize(ds, fp, OptimizeConfig())
    off = optimize(ds, fp, OptimizeConfig(continuity=ContinuityConfig(use=False)))
    w_on, w_off = on.walks.set_index("walk_id"), off.walks.set_index("walk_id")
    assert w_on.loc["w000_1", "linked"] and w_on.loc["w000_1", "placement"] == "continuity"
    assert not w_off.loc["w000_1", "linked"]
    assert on.stats["evidence"]["continuity"]["joins"] == 2 and on.stats["factors"]["continuity"] == 2
    # placed where it was (measured 1.1 m; 18 m where it is left without continuity), and the landmark
    # error of all walks falls (measured 2.80 -> 2.10 m)
    from rmbuild.geometry import align_se2

    def piece_error(r):
        m = r.poses["walk_id"].to_numpy() == "w000_1"
        xy, tru = r.poses[["x_m", "y_m"]].to_numpy(), ds.truth_poses[["x_m", "y_m"]].to_numpy()
        R, t = align_se2(xy[~m], tru[~m])
        return float(np.median(np.linalg.norm(xy[m] @ R.T + t - tru[m], axis=1)))

    assert piece_error(on) < 3.0 < 10.0 < piece_error(off)
    lm = [trajectory_metrics(r.poses, ds)["landmark_error_m"]["mean"] for r in (on, off)]
    assert lm[0] < 0.9 * lm[1]


def test_far_looking_join_is_not_kept():
    """A join whose two sides look far apart in Wi-Fi is dropped (the surveyor walked elsewhere); one whose
    sides look alike is kept; one without scans near the join is kept only when its gap is short."""
    from rmbuild.slam.evidence.continuity import ContinuitySource
    from rmbuild.slam.rss import RssMatrix
    from rmbuild.types import Fingerprints

    walks = walk_set(np.zeros((12, 3)), np.repeat(np.arange(4), 3))
    walks.t_s = np.array([0, 1, 2, 5, 6, 7, 10, 11, 12, 40, 41, 42], float)  # gaps 3, 3, 28 s
    walks.device = np.array(["a"] * 4, dtype=object)
    # scans at the joins: walk 0's end and walk 1's start alike, walk 1's end and walk 2's start very
    # different; walk 3 has no scan at all (a blind join after a 28 s gap)
    nodes = np.array([2, 3, 5, 6])
    rss = np.array([[-50, -60, np.nan, np.nan], [-51, -61, np.nan, np.nan],
                    [-50, -60, np.nan, np.nan], [np.nan, np.nan, -40, -45]], np.float32)
    fp = Fingerprints(nodes, np.array(["a", "b", "c", "d"], dtype=object), rss, (~np.isnan(rss)).astype(np.int32))
    rm = RssMatrix.from_fingerprints(fp, -110.0)
    src = ContinuitySource(walks, ContinuityConfig(), RFModel(20.0, 3.0, 30.0, 4.0), rm, nodes)
    j = src.joins
    assert list(zip(j.walk_a, j.walk_b)) == [(0, 1), (1, 2), (2, 3)]
    assert list(j.kept) == [True, False, False]
    assert np.isnan(j.rss_db[2]) and j.rss_db[0] < 5 < 40 < j.rss_db[1]
    ties = src.ties()
    assert len(ties) == 1 and ties.sigma_m[0] == pytest.approx(2.0 + 0.4 * 3.0)
