"""The walk-to-map initialisation (rmbuild/slam/grow.py): refinement, fits, short walks that only cross."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

pytest.importorskip("gtsam")

from rmbuild.config.optimize import InitConfig, OptimizeConfig  # noqa: E402
from rmbuild.evaluate.trajectory import trajectory_metrics  # noqa: E402
from rmbuild.slam import optimize  # noqa: E402
from rmbuild.slam.grow import _fit_offsets, covered_m, refine_walks, world_xy  # noqa: E402
from rmbuild.slam.testing import make_venue  # noqa: E402


def test_refine_walks_recovers_frames():
    rng = np.random.default_rng(0)
    n_w, per = 4, 30
    raw = np.zeros((n_w * per, 3))
    walk_of = np.repeat(np.arange(n_w), per)
    truth = np.array([[0, 0, 0], [5, -3, 0.3], [-4, 6, -0.5], [10, 2, 1.0]], float)
    for w in range(n_w):
        raw[w * per:(w + 1) * per, :2] = rng.uniform(-10, 10, (per, 2))
    world = world_xy(raw, truth, walk_of, np.arange(len(raw)))
    # pairs: nodes of different walks whose true positions are within 3 m, plus 30 % random false pairs
    d = np.linalg.norm(world[:, None] - world[None], axis=2)
    i, j = np.nonzero((d < 3) & (walk_of[:, None] < walk_of[None, :]))
    fi, fj = rng.integers(0, len(raw), len(i) // 3), rng.integers(0, len(raw), len(i) // 3)
    ok = walk_of[fi] != walk_of[fj]
    nk, nq = np.r_[i, fi[ok]], np.r_[j, fj[ok]]
    T0 = truth + np.c_[rng.normal(0, 2, (n_w, 2)), rng.normal(0, 0.1, n_w)]
    T0[0] = truth[0]
    prior = np.full(n_w, np.nan)
    T = refine_walks(T0, np.ones(n_w, bool), nk, nq, raw, walk_of, 0, prior, np.full(n_w, 0.1), InitConfig(),
                     iterations=20)
    assert np.abs(T[:, :2] - truth[:, :2]).max() < 1.0
    assert np.abs(T[:, 2] - truth[:, 2]).max() < 0.1  # pairs are within 3 m, not coincident


def test_fit_offsets_translation_and_se2():
    rng = np.random.default_rng(1)
    p = np.c_[np.linspace(0, 30, 15), np.zeros(15)]
    th, t = 0.4, np.array([3.0, -2.0])
    R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    x = p @ R.T + t + rng.normal(0, 0.5, p.shape)
    x[:4] += rng.uniform(-30, 30, (4, 2))  # outlier scans
    path = p[:, 0]
    icfg = InitConfig()
    f = _fit_offsets(p, x, path, th, icfg, rng)
    assert f.method == "translation" and f.score >= 10 and np.allclose(f.t[:2], t, atol=1.0)
    f2 = _fit_offsets(p, x, path, None, icfg, rng)
    assert f2.method == "se2" and abs(f2.t[2] - th) < 0.1
    assert covered_m(path[f.inliers]) >= 20


def test_grow_links_short_crossing_walks():
    """Many short walks (~60 steps) with known heading: most are linked and placed."""
    ds, fp = make_venue(n_walks=14, steps_per_walk=60, seed=11)
    r = optimize(ds, fp, OptimizeConfig())
    # 13 of 14 with grow_min_lead = 0; the lead rule (false-pair robustness) rejects 3-vs-1 splits here
    assert r.walks["linked"].sum() >= 9
    lm = trajectory_metrics(r.poses, ds)["landmark_error_m"]
    raw = trajectory_metrics(ds.poses, ds)["landmark_error_m"]
    assert lm["mean"] < raw["mean"]


def test_grow_evidence_variants_run():
    ds, fp = make_venue(n_walks=4, steps_per_walk=150, seed=2)
    for ev in ("pairs", "knn"):
        cfg = OptimizeConfig()
        cfg = dataclasses.replace(cfg, init=dataclasses.replace(cfg.init, grow_evidence=ev))
        r = optimize(ds, fp, cfg)
        assert r.walks["linked"].sum() >= 2
        assert r.walks["linked"].to_numpy()[r.walks["reference"].to_numpy()].all()


def test_accept_needs_lead_over_second_hypothesis():
    """A 4-vs-2 inlier split passes the ratio margin but not an absolute lead of 3 (chance alignments)."""
    from rmbuild.slam.grow import WalkFit, _accept

    f = WalkFit(np.zeros(3), 4, 2, 9.0, 1, "translation", np.ones(3, bool))
    assert _accept(f, InitConfig(grow_margin=1.5, grow_min_lead=0), se2=False)
    assert not _accept(f, InitConfig(grow_margin=1.5, grow_min_lead=3), se2=False)
    f.second = 0
    assert _accept(f, InitConfig(grow_margin=1.5, grow_min_lead=3), se2=False)


def test_accept_spread_and_untrusted_se2_path():
    """The spread rule rejects a short walk's translation fit whose inliers cluster at one place (off by
    default, long walks exempt); an SE(2) fit of a walk without a trusted heading uses its own path minimum."""
    from rmbuild.slam.grow import WalkFit, _accept, _walk_lengths

    f = WalkFit(np.zeros(3), 6, 0, 9.0, 2, "translation", np.ones(6, bool), span_m=4.0)
    assert _accept(f, InitConfig(), se2=False, walk_len=30.0)  # default: rule off
    cfg = InitConfig(grow_min_span_frac=0.3, grow_span_max_walk_m=40.0)
    assert not _accept(f, cfg, se2=False, walk_len=30.0)
    assert _accept(f, cfg, se2=False, walk_len=50.0)  # long walk: exempt
    f.span_m = 10.0
    assert _accept(f, cfg, se2=False, walk_len=30.0)
    g = WalkFit(np.zeros(3), 8, 0, 12.0, 2, "se2", np.ones(8, bool), span_m=12.0)
    assert not _accept(g, InitConfig(), se2=True, untrusted=True)  # refit_rotation_min_path_m = 20
    assert _accept(g, InitConfig(grow_se2_min_shared_m=12.0), se2=True, untrusted=True)
    assert not _accept(g, InitConfig(grow_se2_min_shared_m=12.0), se2=True, untrusted=False)
    wl = _walk_lengths(np.array([0.0, 5.0, 90.0, 1.0, 3.0]), np.array([0, 0, 0, 1, 1]), 3, InitConfig())
    assert np.allclose(wl, [60.0, 2.0, 0.0])
    with pytest.raises(ValueError):
        InitConfig(grow_min_span_frac=1.5).validate()


def _merge_case(consistent: bool):
    """Reference walk 0 (comp 0) along y = 0; walks 1 and 2 (comp 1, placed against each other) each meet
    it with 4 candidate pairs 3 m apart: too few for a walk alone (grow_min_inliers_se2 = 6), enough pooled."""
    from rmbuild.slam.grow import GrowResult

    ref = np.c_[np.arange(0, 61.0), np.zeros(61), np.zeros(61)]
    own = np.c_[np.arange(0, 21.0), np.zeros(21), np.zeros(21)]
    raw = np.vstack([ref, own, own])
    walk_of = np.repeat([0, 1, 2], [61, 21, 21])
    path = np.r_[ref[:, 0], own[:, 0], own[:, 0]]
    true_T = np.array([[0, 0, 0], [5, 0, 0], [35, 0, 0]], float)  # pairs join coincident nodes
    world = world_xy(raw, true_T, walk_of, np.arange(len(raw)))
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
    T = np.zeros((3, 3))
    rel = true_T[2] - true_T[1]
    c, s = np.cos(-true_T[1, 2]), np.sin(-true_T[1, 2])
    T[2] = [c * rel[0] - s * rel[1], s * rel[0] + c * rel[1], rel[2]]
    g = GrowResult(T, np.array([0, 1, 1]), 0, np.array([0, 0, 1]), np.zeros(3, np.int64), np.zeros(3),
                   np.array(["seed", "seed", "se2"], dtype=object), np.zeros(3, bool))
    return g, raw, path, walk_of, nk, nq, true_T


@pytest.mark.parametrize("consistent", [True, False])
def test_merge_components_pools_a_groups_pairs(consistent):
    from rmbuild.slam.grow import merge_components

    g, raw, path, walk_of, nk, nq, true_T = _merge_case(consistent)
    icfg = InitConfig()
    no = np.zeros(3, bool)
    out = merge_components(g, raw, path, walk_of, nk, nq, np.zeros(3), no, np.full(3, np.inf), icfg)
    if consistent:
        assert (out.component == 0).all()
        assert np.abs(out.world_T_walk[:, :2] - true_T[:, :2]).max() < 0.3
        assert np.abs(out.world_T_walk[:, 2] - true_T[:, 2]).max() < 0.01
    else:  # pairs that disagree with any rigid placement: the group stays apart
        assert (out.component == np.array([0, 1, 1])).all()


def test_orient_components_turns_a_component_to_its_compass():
    """A further component seeded in its own PDR frame is rotated so its walks' magnetometer rotations
    agree with the reference's; the reference's component and heading-less components stay."""
    from rmbuild.slam.grow import GrowResult, orient_components

    rot_abs = np.array([0.3, 1.2, 1.25, -0.4])  # each walk frame's compass rotation
    known = np.array([True, True, True, False])
    # comp 1 = walks 1, 2 placed in walk 1's own frame (walk 2 truly 0.05 rad from walk 1); comp 2 = walk 3
    T = np.array([[0, 0, 0], [0, 0, 0], [4.0, 1.0, 0.05], [0, 0, 0]])
    g = GrowResult(T, np.array([0, 1, 1, 2]), 0, np.zeros(4, int), np.zeros(4, np.int64), np.zeros(4),
                   np.array(["seed"] * 4, dtype=object), known.copy())
    out = orient_components(g, rot_abs, known)
    assert np.allclose(out.world_T_walk[0], 0)
    assert np.allclose(out.world_T_walk[3], 0)  # no compass: left alone
    # walks 1 and 2 now sit at their compass rotation relative to the reference, within the 0.05 rad they
    # disagree by, and keep their relative placement
    assert abs(out.world_T_walk[1, 2] - 0.9) < 0.03 and abs(out.world_T_walk[2, 2] - 0.95) < 0.03
    assert np.isclose(np.linalg.norm(out.world_T_walk[2, :2] - out.world_T_walk[1, :2]), np.hypot(4, 1))
    assert np.isclose(out.world_T_walk[2, 2] - out.world_T_walk[1, 2], 0.05)


@pytest.mark.parametrize("reselect", [True, False])
def test_reference_reselected_when_its_component_is_small(monkeypatch, reselect):
    """The walk with the most candidates seeds a 1-walk component while 4 walks form another: with
    ``init.reselect_reference`` growth restarts from the best-connected walk of the large component."""
    import pandas as pd

    import rmbuild.slam.pipeline as P
    from rmbuild.slam.init import InitResult

    n_walks, per = 5, 10
    walk_of = np.repeat(np.arange(n_walks), per)
    path = np.tile(np.arange(per) * 0.7, n_walks)
    # walk 4 has the most cross candidates (look-alikes), then walk 2
    k = np.r_[np.full(32, 40), np.full(12, 20), np.full(5, 21)]
    q = np.r_[np.tile([5, 15, 25, 35], 8), np.full(12, 15), np.full(5, 31)]
    cand = pd.DataFrame({"node_k": k, "node_q": q})
    calls = []

    def fake_grow_from(ref, *args):
        calls.append(ref)
        comp = np.array([1, 1, 1, 1, 0]) if ref == 4 else np.array([0, 0, 0, 0, 1])
        return InitResult(np.zeros((n_walks, 3)), comp, comp == 0, ref, [], np.zeros(n_walks, bool),
                          np.zeros(n_walks))

    monkeypatch.setattr(P, "_grow_from", fake_grow_from)
    cfg = OptimizeConfig()
    cfg = dataclasses.replace(cfg, init=dataclasses.replace(cfg.init, reselect_reference=reselect))
    args = (np.zeros((len(walk_of), 3)), path, walk_of, n_walks, cand, np.zeros(n_walks), np.zeros(n_walks, bool),
            np.zeros(n_walks), cfg)
    rest = (np.ones(n_walks, bool), None, None, None)
    res = P._grow_init(*args, None, *rest)
    if reselect:
        assert calls == [4, 2]
        assert res.reference == 2 and res.linked[:4].all() and not res.linked[4]
    else:
        assert calls == [4]
        assert res.reference == 4
    calls.clear()
    res = P._grow_init(*args, 1, *rest)  # a configured reference is kept as given
    assert calls == [1] and res.reference == 1


@pytest.mark.parametrize("short_walk_m", [0.0, 60.0])
def test_short_walk_keeps_magnetometer_rotation_in_refinement(short_walk_m):
    """A 39 m walk whose pairs say it is turned 10 deg from its magnetometer rotation: the refinement
    follows the pairs (mostly) unless the walk counts as short, when it keeps the magnetometer's."""
    from rmbuild.slam.grow import _refine_placed

    n = 40
    own = np.c_[np.arange(n, dtype=float), np.zeros(n), np.zeros(n)]  # walk 1 in its own frame
    th = np.deg2rad(10.0)
    true_xy = own[:, :2] @ np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]]).T + (5.0, 5.0)
    raw = np.vstack([np.c_[true_xy, np.zeros(n)], own])  # walk 0 (reference, identity frame) lies on walk 1
    walk_of = np.repeat([0, 1], n)
    nk, nq = np.arange(n), np.arange(n) + n
    T = np.array([[0.0, 0.0, 0.0], [5.0, 5.0, 0.0]])  # walk 1 placed at its magnetometer rotation (0)
    icfg = dataclasses.replace(InitConfig(), short_walk_m=short_walk_m)
    path = np.r_[np.arange(n), np.arange(n)].astype(float)
    from rmbuild.slam.grow import _walk_lengths

    wl = _walk_lengths(path, walk_of, 2, icfg)
    # the reference walk without a heading prior: its frame is held fixed, only walk 1 turns
    T2 = _refine_placed(T, np.ones(2, bool), nk, nq, raw, walk_of, 0, np.zeros(2), np.array([False, True]),
                        np.full(2, 0.1), icfg, wl)
    got = np.rad2deg(T2[1, 2])
    if short_walk_m > 0:
        assert abs(got) < 1.0
    else:
        assert got > 5.0
