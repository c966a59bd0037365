"""The per-walk report of optimize: the predicted placement error (rmbuild.slam.uncertainty) on a hand-built set
of straight walks, and the warning that names the unlinked walks."""

from __future__ import annotations

import numpy as np
import pytest

from rmbuild.slam import uncertainty
from rmbuild.slam.evidence.base import Ties
from rmbuild.slam.problem import WalkSet

STEPS = 21  # poses per walk, 1 m apart


def three_walks() -> WalkSet:
    """Three parallel 20 m walks along x, 2 m apart in y, each in its own frame (world = own frame)."""
    x = np.arange(STEPS, dtype=float)
    raw = np.vstack([np.c_[x, np.full(STEPS, 0.0), np.zeros(STEPS)] for _ in range(3)])
    walk_of = np.repeat(np.arange(3), STEPS)
    starts, ends = np.arange(3) * STEPS, np.arange(1, 4) * STEPS
    path = np.tile(x, 3)
    n = len(raw)
    return WalkSet(["a", "b", "c"], raw, walk_of, starts, ends, path, np.arange(n, dtype=float),
                   np.tile(np.arange(STEPS), 3), np.ones(3, bool), np.full(n, np.nan), np.full(n, 0.1), None)


def poses_of(walks: WalkSet) -> np.ndarray:
    xyt = walks.raw.copy()
    xyt[:, 1] += 2.0 * walks.walk_of  # walk w at y = 2 w
    return xyt


def pairs(walks: WalkSet) -> tuple[np.ndarray, np.ndarray]:
    """a-b linked along the whole walk, b-c only at three nodes near one end."""
    s = walks.starts
    ab = np.arange(STEPS)
    bc = np.arange(3)
    return np.r_[s[0] + ab, s[1] + bc], np.r_[s[1] + ab, s[2] + bc]


def no_ties() -> Ties:
    return Ties(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))


def predict(rf_log_lr=None, placed=(True, True, True)) -> np.ndarray:
    walks = three_walks()
    pk, pq = pairs(walks)
    return uncertainty.predicted_errors(walks, poses_of(walks), np.array(placed), pk, pq, no_ties(),
                                        np.zeros(3, bool), rf_log_lr)


def test_a_walk_held_by_little_evidence_is_predicted_worse():
    pred = predict()
    assert np.isfinite(pred).all() and (pred > 0).all()
    # c hangs on three pairs at one end of b (its rotation is barely held): ~2x the others (9.6, 9.4, 18.7 m)
    assert pred[2] > 1.5 * max(pred[0], pred[1])
    assert pred[0] == pytest.approx(pred[1], rel=0.1)


def test_unplaced_walks_get_nan():
    pred = predict(placed=(True, True, False))
    assert np.isnan(pred[2]) and np.isfinite(pred[:2]).all()


def test_rf_disagreement_raises_the_prediction_and_support_leaves_it():
    base = predict()
    llr = np.array([np.nan, uncertainty.RF_LOG_LR_TRUSTED + 1.0, uncertainty.RF_LOG_LR_TRUSTED - 5.0])
    pred = predict(llr)
    np.testing.assert_allclose(pred[:2], base[:2], rtol=1e-12)  # not judged / well supported: unchanged
    assert pred[2] == pytest.approx(base[2] * np.exp(5.0 * uncertainty.RF_INFLATION), rel=1e-9)


def test_a_walk_placed_by_a_continuity_tie_keeps_the_ties_uncertainty():
    """c's component was attached by a device's continuity tie: its figure is combined with the median tie
    sigma (root sum of squares); the walks placed by their own radio keep theirs; without ties, unchanged."""
    walks = three_walks()
    pk, pq = pairs(walks)
    s = walks.starts
    ties = Ties(np.array([s[1] + STEPS - 1, s[0]]), np.array([s[2], s[2] + 5]), np.array([6.0, 10.0]))
    args = (walks, poses_of(walks), np.ones(3, bool), pk, pq, ties, np.zeros(3, bool), None)
    base = uncertainty.predicted_errors(*args)
    pred = uncertainty.predicted_errors(*args, np.array([False, False, True]))
    np.testing.assert_allclose(pred[:2], base[:2], rtol=1e-12)
    assert pred[2] == pytest.approx(np.hypot(base[2], 8.0), rel=1e-9)  # the median of 6 and 10 m
    no_tie = uncertainty.predicted_errors(walks, poses_of(walks), np.ones(3, bool), pk, pq, no_ties(),
                                          np.zeros(3, bool), None, np.array([False, False, True]))
    np.testing.assert_allclose(no_tie, predict(), rtol=1e-12)


def test_unlinked_warning_names_the_groups_of_unlinked_walks():
    """Unlinked walks placed against each other are one group each (their component): the warning counts
    them, largest first, and says nothing of groups when every unlinked walk is alone."""
    import pandas as pd

    from rmbuild.slam.report import unlinked_warning

    walks = three_walks()
    walks.walk_ids, walks.keep = ["r", "a", "b", "c", "d", "e"], np.ones(6, bool)
    table = pd.DataFrame({"linked": [True, False, False, False, False, False], "anchored": False,
                          "component": [0, 1, 2, 2, 2, 1]})
    line = unlinked_warning(walks, table, 0, plan_used=False)
    assert line is not None and line.startswith("5 of 6 walk(s) not linked to the reference walk r (a, b, c, d, e)")
    assert "5 of them form 2 group(s) placed against each other (3, 2 walks)" in line
    assert "a floor plan" in line and "a floor plan" not in unlinked_warning(walks, table, 0, plan_used=True)
    table["component"] = [0, 1, 2, 3, 4, 5]
    assert "group" not in unlinked_warning(walks, table, 0, plan_used=False)
    table["linked"] = True
    assert unlinked_warning(walks, table, 0, plan_used=False) is None


def test_uncertain_placement_warning_fires_on_the_median_predicted_error_of_linked_walks():
    """The warning reads the linked walks' predicted errors only: a median above DOUBTFUL_MEDIAN_ERROR_M fires
    it (with the count over 8 m), a lower one or unlinked walks' large errors do not; too few walks, none."""
    import pandas as pd

    from rmbuild.slam.report import DOUBTFUL_MEDIAN_ERROR_M, uncertain_placement_warning

    table = pd.DataFrame({"linked": [True, True, True, True, False],
                          "predicted_error_m": [2.0, 3.0, 4.0, 12.0, 40.0]})
    assert uncertain_placement_warning(table) is None  # median 3.5 m; the unlinked 40 m is not counted
    table["predicted_error_m"] = [6.0, 9.0, 12.0, 3.0, np.nan]
    line = uncertain_placement_warning(table)
    assert line is not None and line.startswith("the linked walks' median predicted error is 7.5 m (2 of 4 over 8 m)")
    assert "--anchors" in line
    table["predicted_error_m"] = [DOUBTFUL_MEDIAN_ERROR_M] * 4 + [np.nan]
    assert uncertain_placement_warning(table) is None  # at the threshold: not above it
    assert uncertain_placement_warning(table.iloc[:1].assign(predicted_error_m=30.0)) is None  # one walk


def test_every_walk_says_why_it_is_placed_or_left_out():
    """The walk table's reason names the evidence of each kind of placement; a merge or continuity join
    names the group it moved (from the placement's log), a walk left out says so."""
    import pandas as pd

    from rmbuild.slam.report import placement_reasons, placement_summary

    table = pd.DataFrame({
        "placement": ["reference", "translation", "merge", "continuity", "refuted", ""],
        "linked": [True, True, True, True, False, False], "component": [0, 0, 0, 0, 1, 2],
        "placement_inliers": [0, 12, 5, 4, 6, 0], "n_partner_walks": [3, 4, 2, 1, 2, 0],
        "n_cross_pairs": [30, 20, 8, 3, 9, 0], "shared_path_m": [40.0, 22.0, 10.0, 5.0, 8.0, 0.0],
        "predicted_error_m": [1.0, 2.5, 6.0, 11.0, np.nan, np.nan],
        "rf_log_lr": [np.nan, 1.5, 0.2, np.nan, -1.2, np.nan], "rf_overlap_scans": [0, 10, 7, 0, 9, 0]})
    log = [{"phase": "merge", "accepted": True, "members": [2], "walks": 3, "score": 9, "shared_m": 14.0},
           {"phase": "continuity", "accepted": False, "members": [2], "walks": 1, "sigma_m": 50.0},
           {"phase": "continuity", "accepted": True, "members": [3], "walks": 2, "sigma_m": 7.5}]
    r = placement_reasons(table, log)
    assert r[0].startswith("reference walk")
    assert "on 12 scans; shares 22 m of path with 4 other walk(s)" in r[1]
    assert "log-LR +1.50" in r[1] and "2.5 m" in r[1]
    assert "group of 3 walk(s)" in r[2] and "fitted on 9 scans over 14 m" in r[2]
    assert "continuity tie" in r[3] and "sigma 7.5 m" in r[3] and "11.0 m" in r[3]
    assert r[4].startswith("left out: where Wi-Fi placed it") and "-1.20" in r[4]
    assert r[5].startswith("left out: no verified link")
    kinds = placement_summary(table)
    assert kinds["wifi"] == {"walks": 1, "median_predicted_error_m": 2.5}
    assert kinds["left out"] == {"walks": 2, "median_predicted_error_m": None}


def _information(rng, groups: list[int], isolated: int) -> np.ndarray:
    """A dense information of walk frames: random position-difference pairs inside each group of walks (a
    translation-invariant Jacobian), a compass on every other walk, and ``isolated`` walks with no evidence."""
    n = sum(groups) + isolated
    H = np.zeros((3 * n, 3 * n))
    first = 0
    for size in groups:
        for _ in range(12 * size):
            a, b = rng.choice(np.arange(first, first + size), 2, replace=False)
            j = np.zeros((2, 3 * n))
            j[:, 3 * a:3 * a + 2], j[:, 3 * b:3 * b + 2] = np.eye(2), -np.eye(2)
            j[:, 3 * a + 2], j[:, 3 * b + 2] = rng.normal(0, 5, 2), rng.normal(0, 5, 2)
            H += j.T @ j
        first += size
    H[np.arange(2, 3 * sum(groups), 6), np.arange(2, 3 * sum(groups), 6)] += 100.0
    return H


def test_marginal_blocks_are_the_pseudo_inverses_blocks():
    """Groups of walks apart from each other and a placed walk without evidence: the blocks from one
    Cholesky factorisation equal those of numpy's pseudo-inverse (the gauge of each group left free)."""
    import scipy.sparse as sp

    H = _information(np.random.default_rng(5), [6, 4], isolated=1)
    C = np.linalg.pinv(H, rcond=1e-9, hermitian=True)
    got = uncertainty.marginal_blocks(sp.csr_matrix(H))
    want = np.stack([C[3 * w:3 * w + 3, 3 * w:3 * w + 3] for w in range(len(H) // 3)])
    np.testing.assert_allclose(got, want, atol=1e-9 * np.abs(want).max())


def test_beyond_the_exact_size_each_walk_is_held_by_its_own_block(monkeypatch):
    import scipy.sparse as sp

    H = _information(np.random.default_rng(6), [8], isolated=0)
    monkeypatch.setattr(uncertainty, "EXACT_MAX_WALKS", 4)
    got = uncertainty.marginal_blocks(sp.csr_matrix(H))
    np.testing.assert_allclose(got[3], np.linalg.inv(H[9:12, 9:12]), rtol=1e-10)
    exact = np.linalg.pinv(H, rcond=1e-9, hermitian=True)[9:12, 9:12]
    assert np.trace(got[3]) == pytest.approx(np.trace(exact), rel=0.5)  # a walk held by many: close to it
    assert np.isfinite(predict()).all()
