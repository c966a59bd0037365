"""Placement (rmbuild/slam/placement/): refinement, fits, acceptance, merges, reference choice."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("gtsam")

from slam_venue import make_venue, walk_set  # noqa: E402

from rmbuild.config.optimize import OptimizeConfig, PlacementConfig  # noqa: E402
from rmbuild.evaluate.trajectory import trajectory_metrics  # noqa: E402
from rmbuild.slam import optimize  # noqa: E402
from rmbuild.slam.evidence.base import EvidenceSource, Links, RotationPriors  # noqa: E402
from rmbuild.slam.placement import fits, refine  # noqa: E402
from rmbuild.slam.placement.grow import SE2_MAX_COMPASS_DEV_RAD, _fit_both, window_lengths  # noqa: E402
from rmbuild.slam.placement.merge import merge_components, orient_components  # noqa: E402
from rmbuild.slam.placement.model import GrowState, Placement, WalkFit  # noqa: E402
from rmbuild.slam.problem import covered_m  # noqa: E402


def _rot_known(theta, known, sigma=np.inf):
    return RotationPriors(np.asarray(theta, float), np.asarray(known, bool), np.full(len(theta), sigma))


@pytest.mark.parametrize("iterative", [False, True])
def test_refine_walks_recovers_frames(iterative, monkeypatch):
    if iterative:  # the CG step of many walks gives the sparse LU's frames to rounding
        monkeypatch.setattr(refine, "ITERATIVE_SOLVE_MIN_VARS", 3)
    rng = np.random.default_rng(0)
    n_w, per = 4, 30
    raw = np.zeros((n_w * per, 3))
    walk_of = np.repeat(np.arange(n_w), per)
    truth = np.array([[0, 0, 0], [5, -3, 0.3], [-4, 6, -0.5], [10, 2, 1.0]], float)
    for w in range(n_w):
        raw[w * per:(w + 1) * per, :2] = rng.uniform(-10, 10, (per, 2))
    walks = walk_set(raw, walk_of)
    world = walks.world_xy(truth, np.arange(len(raw)))
    # pairs: nodes of different walks whose true positions are within 3 m, plus 30 % random false pairs
    d = np.linalg.norm(world[:, None] - world[None], axis=2)
    i, j = np.nonzero((d < 3) & (walk_of[:, None] < walk_of[None, :]))
    fi, fj = rng.integers(0, len(raw), len(i) // 3), rng.integers(0, len(raw), len(i) // 3)
    ok = walk_of[fi] != walk_of[fj]
    nk, nq = np.r_[i, fi[ok]], np.r_[j, fj[ok]]
    T0 = truth + np.c_[rng.normal(0, 2, (n_w, 2)), rng.normal(0, 0.1, n_w)]
    T0[0] = truth[0]
    T = refine.refine_walks(T0, np.ones(n_w, bool), nk, nq, walks, 0, np.full(n_w, np.nan), np.full(n_w, 0.1),
                            iterations=20)
    assert np.abs(T[:, :2] - truth[:, :2]).max() < 1.0
    assert np.abs(T[:, 2] - truth[:, 2]).max() < 0.1  # pairs are within 3 m, not coincident


def test_fit_to_scans_translation_and_se2():
    rng = np.random.default_rng(1)
    p = np.c_[np.linspace(0, 30, 15), np.zeros(15)]
    th, t = 0.4, np.array([3.0, -2.0])
    R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    x = p @ R.T + t + rng.normal(0, 0.5, p.shape)
    x[:4] += rng.uniform(-30, 30, (4, 2))  # outlier scans
    path = p[:, 0]
    cfg = PlacementConfig()
    f = fits.fit_to_scans(p, x, path, th, cfg, rng)
    assert f.method == "translation" and f.score >= 10 and np.allclose(f.t[:2], t, atol=1.0)
    f2 = fits.fit_to_scans(p, x, path, None, cfg, rng)
    assert f2.method == "se2" and abs(f2.t[2] - th) < 0.1
    assert covered_m(path[f.inliers]) >= 20


def test_grow_links_short_crossing_walks():
    """Many short walks (~60 steps) with known heading: most are linked and placed."""
    ds, fp = make_venue(n_walks=14, steps_per_walk=60, seed=11)
    r = optimize(ds, fp, OptimizeConfig())
    # 13 of 14 with min_lead = 0; the lead rule (false-pair robustness) rejects 3-vs-1 splits here; of the
    # 9 placed, the RF check leaves out w011, placed wrong (the others' landmark error 13.1 -> 8.0 m)
    assert r.walks["linked"].sum() >= 8
    linked = r.walks.loc[r.walks["linked"], "walk_id"].tolist()
    assert trajectory_metrics(r.poses, ds, fit_walks=linked)["landmark_error_fitted_walks_m"]["mean"] < 10.0
    lm = trajectory_metrics(r.poses, ds)["landmark_error_m"]
    raw = trajectory_metrics(ds.poses, ds)["landmark_error_m"]
    assert lm["mean"] < raw["mean"]
    assert set(r.placement_log["phase"]) >= {"pairs", "knn"} and r.placement_log["accepted"].any()


def test_accept_needs_lead_over_second_hypothesis():
    """A 4-vs-2 inlier split passes the ratio margin but not an absolute lead of 3 (chance alignments)."""
    f = WalkFit(np.zeros(3), 4, 2, 9.0, 1, "translation", np.ones(3, bool))
    assert fits.accept_pairs_fit(f, False, PlacementConfig(margin=1.5, min_lead=0))
    assert not fits.accept_pairs_fit(f, False, PlacementConfig(margin=1.5, min_lead=3))
    f.second = 0
    assert fits.accept_pairs_fit(f, False, PlacementConfig(margin=1.5, min_lead=3))
    g = WalkFit(np.zeros(3), 8, 0, 12.0, 2, "se2", np.ones(8, bool))
    assert not fits.accept_pairs_fit(g, True, PlacementConfig())  # min_shared_se2_m = 20
    assert fits.accept_pairs_fit(g, True, PlacementConfig(min_shared_se2_m=12.0))
    half = WalkFit(np.zeros(3), 6, 6, 9.0, 0, "translation", np.ones(6, bool))
    assert fits.accept_scans_fit(half, False, PlacementConfig())
    half.second = 7  # under half of the covered scans
    assert not fits.accept_scans_fit(half, False, PlacementConfig())


def test_window_lengths_cap_at_the_fit_window():
    raw = np.c_[np.r_[np.arange(0, 91.0), np.arange(0, 3.0)], np.zeros(94), np.zeros(94)]
    walks = walk_set(raw, np.repeat([0, 1], [91, 3]))
    assert np.allclose(window_lengths(walks, PlacementConfig()), [60.0, 2.0])
    assert np.allclose(window_lengths(walks, PlacementConfig(window_m=0.0)), [90.0, 2.0])


def _merge_case(consistent: bool):
    """Reference walk 0 (comp 0) along y = 0; walks 1 and 2 (comp 1, placed against each other) each meet
    it with 4 candidate pairs 3 m apart: too few for a walk alone (twice min_inliers: 6), enough pooled."""
    ref = np.c_[np.arange(0, 61.0), np.zeros(61), np.zeros(61)]
    own = np.c_[np.arange(0, 21.0), np.zeros(21), np.zeros(21)]
    walks = walk_set(np.vstack([ref, own, own]), np.repeat([0, 1, 2], [61, 21, 21]))
    true_T = np.array([[0, 0, 0], [5, 0, 0], [35, 0, 0]], float)  # pairs join coincident nodes
    world = walks.world_xy(true_T, np.arange(walks.n))
    nk, nq = [], []
    for w in (1, 2):
        for s in (2, 6, 10, 14):
            node = 61 + 21 * (w - 1) + s
            nk.append(int(np.argmin(np.linalg.norm(world[:61] - world[node, :2], axis=1))))
            nq.append(node)
    nk, nq = np.array(nk), np.array(nq)
    if not consistent:
        nk = np.random.default_rng(0).permutation(nk)
    # comp 1's own frame: walk 1 at the origin, walk 2 where it truly is relative to walk 1
    st = GrowState.empty(3, 0, np.zeros(3, bool))
    st.T[2] = true_T[2] - true_T[1]
    st.comp[:] = [0, 1, 1]
    return st, walks, nk, nq, true_T


@pytest.mark.parametrize("consistent", [True, False])
def test_merge_components_pools_a_groups_pairs(consistent):
    st, walks, nk, nq, true_T = _merge_case(consistent)
    out, merged = merge_components(st, walks, nk, nq, _rot_known(np.zeros(3), np.zeros(3)), PlacementConfig(), [])
    if consistent:
        assert merged and (out.comp == 0).all()
        assert np.abs(out.T[:, :2] - true_T[:, :2]).max() < 0.3
        assert np.abs(out.T[:, 2] - true_T[:, 2]).max() < 0.01
    else:  # pairs that disagree with any rigid placement: the group stays apart
        assert not merged and (out.comp == np.array([0, 1, 1])).all()


def test_orient_components_turns_a_component_to_its_compass():
    """A further component seeded in its own frame is rotated so its walks' compass rotations agree with
    the reference's; the reference's component and compass-less components stay."""
    rot = _rot_known([0.3, 1.2, 1.25, -0.4], [True, True, True, False])
    # comp 1 = walks 1, 2 placed in walk 1's own frame (walk 2 truly 0.05 rad from walk 1); comp 2 = walk 3
    st = GrowState.empty(4, 0, rot.known)
    st.T[2] = (4.0, 1.0, 0.05)
    st.comp[:] = [0, 1, 1, 2]
    out = orient_components(st, rot)
    assert np.allclose(out.T[0], 0) and np.allclose(out.T[3], 0)
    assert abs(out.T[1, 2] - 0.9) < 0.03 and abs(out.T[2, 2] - 0.95) < 0.03
    assert np.isclose(np.linalg.norm(out.T[2, :2] - out.T[1, :2]), np.hypot(4, 1))
    assert np.isclose(out.T[2, 2] - out.T[1, 2], 0.05)


class _Links(EvidenceSource):
    def __init__(self, k, q):
        self.warnings = []
        self._l = Links(np.asarray(k), np.asarray(q))

    def links(self):
        return self._l


def test_reference_reselected_when_its_component_is_small(monkeypatch):
    """The walk with the most links seeds a 1-walk component while 4 walks form another: growth restarts
    from the best-linked walk of the large component; a configured reference is kept as given."""
    import rmbuild.slam.placement as P

    n_walks, per = 5, 10
    raw = np.c_[np.tile(np.arange(per) * 0.7, n_walks), np.zeros(n_walks * per), np.zeros(n_walks * per)]
    walks = walk_set(raw, np.repeat(np.arange(n_walks), per))
    # walk 4 has the most cross links (look-alikes), then walk 2
    k = np.r_[np.full(32, 40), np.full(12, 20), np.full(5, 21)]
    q = np.r_[np.tile([5, 15, 25, 35], 8), np.full(12, 15), np.full(5, 31)]
    calls = []

    def fake_grow_from(ref, *args):
        calls.append(ref)
        comp = np.array([1, 1, 1, 1, 0]) if ref == 4 else np.array([0, 0, 0, 0, 1])
        return Placement(np.zeros((n_walks, 3)), comp, ref, np.zeros(n_walks, bool), np.full(n_walks, ""))

    monkeypatch.setattr(P, "_grow_from", fake_grow_from)
    res = P.place(walks, [_Links(k, q)], PlacementConfig(), None)
    assert calls == [4, 2]
    assert res.reference == 2 and res.linked[:4].all() and not res.linked[4]
    calls.clear()
    res = P.place(walks, [_Links(k, q)], PlacementConfig(), 1)
    assert calls == [1] and res.reference == 1


@pytest.mark.parametrize("short_walk_m", [0.0, 60.0])
def test_short_walk_keeps_compass_rotation_in_refinement(monkeypatch, short_walk_m):
    """A 39 m walk whose pairs say it is turned 10 deg from its compass rotation: the refinement follows
    the pairs (mostly) unless the walk counts as short, when it keeps the compass's."""
    monkeypatch.setattr(refine, "SHORT_WALK_M", short_walk_m)
    n = 40
    own = np.c_[np.arange(n, dtype=float), np.zeros(n), np.zeros(n)]  # walk 1 in its own frame
    th = np.deg2rad(10.0)
    true_xy = own[:, :2] @ np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]]).T + (5.0, 5.0)
    walks = walk_set(np.vstack([np.c_[true_xy, np.zeros(n)], own]), np.repeat([0, 1], n))
    T = np.array([[0.0, 0.0, 0.0], [5.0, 5.0, 0.0]])  # walk 1 placed at its compass rotation (0)
    T2 = refine.refine_placed(T, np.ones(2, bool), np.arange(n), np.arange(n) + n, walks, 0, np.zeros(2),
                              np.array([False, True]), np.full(2, 0.1), 4.0, walks.walk_lengths())
    got = np.rad2deg(T2[1, 2])
    if short_walk_m > 0:
        assert abs(got) < 1.0
    else:
        assert got > 5.0


class _FakeRss:
    """RSS distance growing with the true distance between scans (dB): near pairs ~21 dB, 40 m apart ~45 dB;
    scans of the walk ``loud`` (another phone's gain) are ``gain_db`` further from everything."""

    def __init__(self, true_xy, walk_of, loud=-1, gain_db=0.0):
        self.xy, self.walk_of, self.loud, self.gain = true_xy, walk_of, loud, gain_db

    def block(self, rows, cols):
        d = np.linalg.norm(self.xy[rows][:, None] - self.xy[cols][None], axis=2)
        loud = (self.walk_of[rows] == self.loud)[:, None] | (self.walk_of[cols] == self.loud)[None, :]
        d = d * 0.6 + 20.0 + self.gain * loud
        return d.astype(np.float32), np.full(d.shape, 10.0)

    def pairs(self, i, j):
        d = np.linalg.norm(self.xy[i] - self.xy[j], axis=1) * 0.6 + 20.0
        d = d + self.gain * ((self.walk_of[i] == self.loud) | (self.walk_of[j] == self.loud))
        return d.astype(np.float32), np.full(len(d), 10.0)


PER = 30
# truth: walks 0, 1, 4 on one corridor; 2 and 3 on another, 40 m away; placement lays all on the first.
# Walk 4's phone reads 8 dB off: far from everything by RSS distance, yet placed right.
TRUE_T = np.array([[0, 0, 0], [0, 1, 0], [0, 40, 0], [0, 41, 0], [0, -1, 0]], float)
PLACED_T = np.array([[0, 0, 0], [0, 1, 0], [0, 0.5, 0], [0, 1.5, 0], [0, -1, 0]], float)


def _two_corridors():
    """Five 30-scan walks along x and the scan locator of their true places (:data:`TRUE_T`)."""
    from types import SimpleNamespace

    from rmbuild.slam.rfmodel import RFModel

    raw = np.vstack([np.c_[np.linspace(0, 29, PER), np.zeros(PER)]] * 5)
    walk_of = np.repeat(np.arange(5), PER)
    walks = walk_set(np.c_[raw, np.zeros(len(raw))], walk_of)
    nodes = np.arange(len(raw))
    sim = SimpleNamespace(rss=_FakeRss(walks.world_xy(TRUE_T, nodes), walk_of, loud=4, gain_db=8.0), row_node=nodes,
                          min_common=3, rf=RFModel(22.0, 3.0, 32.0, 4.0))
    return walks, sim


def _placement(T):
    return Placement(T.copy(), np.zeros(5, np.int64), 0, np.zeros(5, bool), np.array([""] * 5, dtype=object))


def test_rf_check_refutes_walks_laid_over_a_place_that_looks_different():
    from rmbuild.slam.placement.rfcheck import refute

    walks, sim = _two_corridors()
    pl = _placement(PLACED_T)
    assert sorted(refute(pl, walks, sim)) == [2, 3]
    assert list(pl.component[[0, 1, 4]]) == [0, 0, 0] and pl.component[2] > 0 and pl.component[3] > 0
    assert list(pl.method[2:4]) == ["refuted", "refuted"]
    assert refute(_placement(TRUE_T), walks, sim) == []  # placed where they belong: nothing refuted


def test_rf_check_sampled_at_a_venue_month_judges_as_the_full_check(monkeypatch):
    """From SAMPLED_MIN_ROWS rows the check samples offsets and neighbours: with samples covering everything
    its figures equal the full check's; with small samples it refutes the same walks."""
    from rmbuild.slam.placement import rfcheck

    walks, sim = _two_corridors()

    def judged(T):
        pl = _placement(T)
        return rfcheck.refute(pl, walks, sim), pl.rf_log_lr

    full = judged(PLACED_T)
    monkeypatch.setattr(rfcheck, "SAMPLED_MIN_ROWS", 1)
    monkeypatch.setattr(rfcheck, "OFFSET_SAMPLE_ROWS", PER)
    monkeypatch.setattr(rfcheck, "OVERLAP_MAX_NEIGHBOURS", 5 * PER)
    covering = judged(PLACED_T)
    assert covering[0] == full[0]
    np.testing.assert_allclose(covering[1], full[1], rtol=1e-5)
    monkeypatch.setattr(rfcheck, "OFFSET_SAMPLE_ROWS", 5)
    monkeypatch.setattr(rfcheck, "OFFSET_MAX_COLUMNS", 40)
    monkeypatch.setattr(rfcheck, "OVERLAP_MAX_NEIGHBOURS", 3)
    small = judged(PLACED_T)
    assert sorted(small[0]) == sorted(full[0]) == [2, 3]
    assert judged(TRUE_T)[0] == []


def test_rf_check_judges_a_walk_by_the_map_it_was_placed_onto():
    """Four walks of a corridor 40 m away placed together onto a map of two corridors (walks 0-1 and 2-3):
    each has more of its wrong companions near it than of the map, so judged against all the others they
    vouch for each other and outvote a right walk; judged against the walks placed before them (the order
    of placement) they are refuted and the map's walks kept."""
    from types import SimpleNamespace

    from rmbuild.slam.placement.rfcheck import refute
    from rmbuild.slam.rfmodel import RFModel

    per, n = 30, 8
    line = np.c_[np.linspace(0, 29, per), np.zeros(per)]
    walk_of = np.repeat(np.arange(n), per)
    walks = walk_set(np.c_[np.vstack([line] * n), np.zeros(n * per)], walk_of)
    true_y = np.array([0, 1, 80, 81, 40, 41, 40.5, 39.5])
    true_T = np.c_[np.zeros(n), true_y, np.zeros(n)]
    placed_T = true_T - np.c_[np.zeros(n), 40.0 * (np.arange(n) >= 4), np.zeros(n)]
    nodes = np.arange(n * per)
    sim = SimpleNamespace(rss=_FakeRss(walks.world_xy(true_T, nodes), walk_of), row_node=nodes, min_common=3,
                          rf=RFModel(22.0, 3.0, 32.0, 4.0))

    def placement(order):
        return Placement(placed_T.copy(), np.zeros(n, np.int64), 0, np.zeros(n, bool),
                         np.array([""] * n, dtype=object), order=order)

    assert refute(placement(None), walks, sim) == [1]  # without the order the group outvotes the map
    pl = placement(np.array([1, 2, 2, 2, 3, 3, 3, 3]))  # walks 4-7 placed in one round after the others
    assert sorted(refute(pl, walks, sim)) == [4, 5, 6, 7]
    assert (pl.component[:4] == 0).all() and (pl.component[4:] > 0).all()


def test_a_walk_its_compass_misplaces_is_left_unlinked_not_placed_wrong():
    """A walk whose compass is 90 deg off is fitted with that rotation ~60 m from where it was (the others'
    error stays 0.7 m): the RF check leaves it unlinked, reported as refuted, instead of in the map."""
    import dataclasses

    ds, fp = make_venue(n_walks=5, steps_per_walk=260, seed=1)
    poses = ds.poses.copy()
    one = poses["walk_id"] == "w001"
    poses.loc[one, "heading_rad"] = poses.loc[one, "heading_rad"] + np.pi / 2
    r = optimize(dataclasses.replace(ds, poses=poses), fp, OptimizeConfig())
    w = r.walks.set_index("walk_id")
    assert not w.loc["w001", "linked"] and w.loc["w001", "placement"] == "refuted"
    assert w["linked"].sum() == 4 and r.stats["refuted_walks"] == ["w001"]
    assert w.loc["w001", "rf_log_lr"] < -0.5 and w.loc["w001", "rf_overlap_scans"] >= 5  # the figure that refuted it
    judged = w[w["linked"] & w["rf_log_lr"].notna()]
    assert len(judged) >= 2 and (judged["rf_log_lr"] > -0.5).all()
    assert any("RF check" in m and "w001" in m for m in r.stats["warnings"])
    others = [f"w00{i}" for i in (0, 2, 3, 4)]
    assert trajectory_metrics(r.poses, ds, fit_walks=others)["landmark_error_fitted_walks_m"]["mean"] < 1.5


def test_an_se2_fallback_that_contradicts_the_walks_compass_does_not_place_it():
    """The compass-rotation fit fails; the SE(2) fit is accepted on its own figures. With a compass it places
    the walk only when its rotation lies within SE2_MAX_COMPASS_DEV_RAD of the compass rotation."""
    def fit_turned_by(dev: float):
        def fit(rot: float | None) -> WalkFit:
            if rot is not None:  # the compass-rotation fit: too few inliers
                return WalkFit(np.array([0.0, 0.0, rot]), 2, 1, 5.0, 1, "translation", np.zeros(0, bool))
            return WalkFit(np.array([3.0, 4.0, 0.5 + dev]), 9, 4, 30.0, 2, "se2", np.zeros(0, bool))
        return fit

    def accept(f: WalkFit | None, se2: bool) -> bool:
        return f is not None and f.score >= 6
    near, far = 0.8 * SE2_MAX_COMPASS_DEV_RAD, 1.2 * SE2_MAX_COMPASS_DEV_RAD
    for dev, placed in ((near, True), (-near, True), (far, False), (-far, False), (np.pi, False)):
        f, ok = _fit_both(fit_turned_by(dev), accept, 0.5)
        assert ok is placed, dev
        if ok:
            assert f is not None and f.method == "se2" and np.isclose(f.t[2], 0.5 + dev)
    f, ok = _fit_both(fit_turned_by(np.pi), accept, float("nan"))  # no compass: nothing to contradict
    assert ok and f is not None and f.method == "se2"


def test_refine_iterative_and_sparse_steps_agree(monkeypatch):
    import scipy.sparse as sp

    rng = np.random.default_rng(1)
    J = sp.random(400, 90, density=0.05, random_state=2) + sp.identity(90, format="csr")[rng.integers(0, 90, 400)]
    A = (J.T @ J + sp.identity(90) * 1e-6).tocsc()
    b = rng.normal(size=90)
    sparse = refine._solve(A, b)
    monkeypatch.setattr(refine, "ITERATIVE_SOLVE_MIN_VARS", 3)
    np.testing.assert_allclose(refine._solve(A, b), sparse, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(A @ sparse, b, atol=1e-8)
    # the gauge's stiff diagonal (1e9 on the reference walk) is what the 3 x 3 blocks precondition away
    A = (A + sp.diags(np.r_[1e9, 1e9, 1e9, np.zeros(87)])).tocsc()
    np.testing.assert_allclose(refine._solve(A, b), sp.linalg.spsolve(A, b), rtol=1e-7, atol=1e-9)


def test_block_jacobi_cg_says_when_it_does_not_converge():
    import scipy.sparse as sp

    rng = np.random.default_rng(3)
    J = sp.random(300, 60, density=0.1, random_state=4) + sp.identity(60, format="csr")[rng.integers(0, 60, 300)]
    A = (J.T @ J + sp.identity(60) * 1e-6).tocsr()
    assert refine.block_jacobi_cg(A, rng.normal(size=60), 1e-12, 2) is None


def test_rf_check_offsets_from_the_upper_triangle_equal_the_full_pass(monkeypatch):
    """The offsets pass of a venue-month computes each pair of rows once; it finds the same best matches."""
    from types import SimpleNamespace

    from rmbuild.slam.placement import rfcheck
    from rmbuild.slam.rfmodel import RFModel

    rng = np.random.default_rng(3)
    walk_of = np.repeat(np.arange(6), 25)
    walks = walk_set(np.c_[rng.uniform(0, 30, (150, 2)), np.zeros(150)], walk_of)
    nodes = np.arange(150)
    sim = SimpleNamespace(rss=_FakeRss(walks.raw[:, :2], walk_of, loud=2, gain_db=6.0), row_node=nodes,
                          min_common=3, rf=RFModel(22.0, 3.0, 32.0, 4.0))
    monkeypatch.setattr(rfcheck, "OFFSET_BLOCK_ELEMS", 150 * 20)  # blocks of 20 rows
    full = rfcheck.OverlapCheck(walks, sim)
    monkeypatch.setattr(rfcheck, "SYMMETRIC_MIN_ROWS", 1)
    sym = rfcheck.OverlapCheck(walks, sim)
    np.testing.assert_array_equal(sym._best_other_walk_match(), full._best_other_walk_match())
    np.testing.assert_array_equal(sym.offset_db, full.offset_db)
    assert full.offset_db[2] > 3.0  # the loud phone's walk


def test_knn_merge_keeps_every_neighbour_within_threshold_as_the_full_block():
    """The kNN merge's screened block (grow._within, eq. 9 only where the screen keeps an entry) leaves each
    scan the same neighbours within its threshold, at the same distances, as the whole block ranked."""
    from rmbuild.slam.placement.grow import KNN_K, _keep_nearest, _within
    from rmbuild.slam.rss import RssMatrix

    rng = np.random.default_rng(3)
    n, m = 600, 40
    seen = rng.random((n, m)) < 0.4
    a = np.where(seen, rng.uniform(5, 60, (n, m)), 0).astype(np.float32)
    b = seen.astype(np.float32)
    rss = RssMatrix(a, b, np.einsum("ij,ij->i", a, a, dtype=np.float64), b.sum(axis=1, dtype=np.float64))
    rows, cols = np.arange(200), np.arange(200, n)
    full, common = rss.block(rows, cols)
    full[common < 3] = np.inf
    thr = np.quantile(full[np.isfinite(full)], 0.03) * rng.uniform(0.5, 1.5, len(rows))
    best_d = np.full((n, KNN_K), np.inf, np.float32)
    best_c = np.full((n, KNN_K), -1, np.int64)
    for part in np.array_split(cols, 4):  # new scans merged in rounds, as growth does
        bound = np.minimum(thr, best_d[rows, KNN_K - 1])
        dot, com = rss.products(rows, part)
        i, j = _within(rss, rows, part, dot, com, bound, 3)
        r, c = rows[i], part[j]
        d = rss.distance(rss.cnt[r], rss.cnt[c], rss.sq[r], rss.sq[c], dot[i, j], com[i, j])
        ok = d <= bound[i]
        _keep_nearest(best_d, best_c, rows, i[ok], c[ok], d[ok])
    assert (best_d[rows] < np.inf).any()
    for k in range(len(rows)):
        order = np.argsort(full[k], kind="stable")[:KNN_K]
        want = {(int(cols[o]), float(full[k, o])) for o in order if full[k, o] < thr[k]}
        got = {(int(c), float(d)) for c, d in zip(best_c[k], best_d[k]) if d < thr[k]}
        assert got == want
