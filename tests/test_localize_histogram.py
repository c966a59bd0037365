"""RSS-histogram localizers (`hist`, `hist_dir`): scores against hand computation, the direction gain, the
walker's direction from PDR, and a seeded synthetic venue."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from rmbuild.baselines.config import HistogramLocConfig
from rmbuild.baselines.histogram import DirectionHistogramLocalizer, HistogramLocalizer
from rmbuild.config.radiomap import MapConfig
from rmbuild.errors import InputError
from rmbuild.localize.base import Query
from rmbuild.radiomap import build_radio_map


def _corridor_map():
    """Two 2 m cells on a corridor along x; walk e goes east, walk w west, through both. AP 'a' reads -50
    walking east and -60 walking west in cell A, the other way round in cell B; AP 'b' is -70 everywhere."""
    xy, walk, rows = [], [], []
    for wid, xs in (("e", [0.5, 1.5, 2.5, 3.5]), ("w", [3.5, 2.5, 1.5, 0.5])):
        for x in xs:
            node = len(xy)
            xy.append((x, 1.0))
            walk.append(wid)
            in_a = x < 2.0
            east = wid == "e"
            rows += [(node, float(node), "a", -50.0 if in_a == east else -60.0), (node, float(node), "b", -70.0)]
    wifi = pd.DataFrame(rows, columns=["node", "t_s", "bssid", "rssi_dbm"])
    return build_radio_map(wifi, np.array(xy), np.array(walk), MapConfig(cell_size_m=2.0), origin_xy=np.zeros(2))


def test_likelihood_scores_match_hand_computation():
    rm = _corridor_map()
    loc = HistogramLocalizer(HistogramLocConfig(smooth_db=0.0, floor_prob=0.01)).fit(rm)
    rss = np.array([[-50.0, -70.0], [-55.0, -70.0]], dtype=np.float32)
    ll = loc.log_likelihood(rss)
    # every cell: a has -50 twice, -60 twice (P = 0.5 per occupied bin), b -70 four times (P = 1)
    eps = 0.01
    want0 = np.log((0.5 + eps) / eps) + np.log((1.0 + eps) / eps)
    np.testing.assert_allclose(ll[0], want0)
    np.testing.assert_allclose(ll[1], np.log((1.0 + eps) / eps))  # -55 falls in an empty bin
    p = loc.predict_rss(rss)
    np.testing.assert_allclose(p[:, 1], 1.0) and np.testing.assert_allclose(p[:, 0], 2.0)  # ties: both cells


def test_direction_picks_the_cell_and_marks_follow_the_paper():
    rm = _corridor_map()
    rss = np.array([[-50.0, -70.0]], dtype=np.float32)
    d = DirectionHistogramLocalizer(HistogramLocConfig(smooth_db=0.0, k=1)).fit(rm)
    assert d.n_rp == 4 and sorted(d.rp_sector.tolist()) == [0, 0, 2, 2]
    np.testing.assert_allclose(d.predict_rss(rss, np.array([0]))[0], [1.0, 1.0])  # east, -50: cell A
    np.testing.assert_allclose(d.predict_rss(rss, np.array([2]))[0], [3.0, 1.0])  # west, -50: cell B
    ll = d.log_likelihood(rss, np.array([0]))[0]
    assert ll.max() - np.sort(ll)[-2] == pytest.approx(np.log(1.2))  # D is a prior gain of 1.2
    m = DirectionHistogramLocalizer(HistogramLocConfig(scoring="mark", smooth_db=0.0, mark_share=0.01)).fit(rm)
    mk = m.marks(rss, np.array([0]))
    # the RPs with -50 in their histogram: (A, east), (B, west): Pr = 1 for a and b, R = 1 -> mean 1, D 1.2
    lookup = {(tuple(m._xy[i]), int(m.rp_sector[i])): mk[0, i] for i in range(m.n_rp)}
    assert lookup[((1.0, 1.0), 0)] == pytest.approx(1.2) and lookup[((3.0, 1.0), 2)] == pytest.approx(1.0)
    # (A, west) and (B, east) match b only: 1 of 2 APs < 70 %: not candidates
    assert lookup[((1.0, 1.0), 2)] == 0 and lookup[((3.0, 1.0), 0)] == 0
    np.testing.assert_allclose(m.predict_rss(rss, np.array([0]))[0], [1.0, 1.0])


def test_walker_sectors_from_pdr_and_fixes():
    rm = _corridor_map()
    d = DirectionHistogramLocalizer().fit(rm)
    # the walk's PDR frame is the map frame rotated by +90 deg: PDR says +y, the fixes move along +x
    n = 8
    fixes = np.c_[np.arange(n) * 1.0, np.zeros(n)]
    pdr = np.c_[np.zeros(n), np.arange(n) * 1.0]
    sec = d.walker_sectors(fixes, pdr)
    assert sec[:2].tolist() == [-1, -1] and (sec[2:] == 0).all()  # unknown until 3 fixes, then east
    still = d.walker_sectors(fixes, np.zeros((n, 2)))
    assert (still == -1).all()


def test_histograms_need_a_radio_map():
    rm = _corridor_map()
    with pytest.raises(InputError):
        HistogramLocalizer().fit(rm.reference_set("cells"))


def test_hist_on_the_synthetic_venue():
    from tests.test_localize_slac import _synthetic

    rm, q, qxy = _synthetic((1.0, 0.0))
    e = {}
    for cls in (HistogramLocalizer, DirectionHistogramLocalizer):
        loc = cls().fit(rm)
        e[cls.name] = float(np.nanmean(np.hypot(*(loc.predict(q) - qxy).T)))
    from rmbuild.localize.knn import KnnLocalizer

    e_knn = float(np.nanmean(np.hypot(*(KnnLocalizer().fit(rm).predict(q) - qxy).T)))
    assert e["hist"] < e_knn and e["hist_dir"] < 1.1 * e_knn, (e, e_knn)
    q_none = Query(q.rss_dbm, q.bssids, q.t_s, q.walk_id, q.node, None)
    d = DirectionHistogramLocalizer().fit(rm)
    np.testing.assert_allclose(d.predict(q_none), d.predict_rss(q.aligned(d.bssids).rss_dbm))  # no D anywhere
    assert d.summary()["fallbacks"] == ["steps:none"]


def test_uji_histograms_beat_knn_across_a_device_change(shared_datasets):
    """UJI long-term month 25, floor 3: map from trn01 (Galaxy S3), tests tst06-07 (Galaxy A5)."""
    db = shared_datasets / "uji-longterm" / "db" / "25"
    if not db.is_dir():
        pytest.skip("uji-longterm not present")

    def read(name):
        rss = pd.read_csv(db / f"{name}rss.csv.gz", header=None).to_numpy(dtype=np.float32)
        crd = pd.read_csv(db / f"{name}crd.csv.gz", header=None).to_numpy(dtype=np.float64)
        rss[rss == 100] = np.nan
        return rss[crd[:, 2] == 3], crd[crd[:, 2] == 3, :2]

    bss = np.array([f"ap{j:03d}" for j in range(620)], dtype=object)
    m_rss, m_xy = read("trn01")
    r, c = np.nonzero(~np.isnan(m_rss))
    wifi = pd.DataFrame({"node": r, "t_s": 0.0, "bssid": bss[c], "rssi_dbm": m_rss[r, c].astype(float)})
    rm = build_radio_map(wifi, m_xy, np.array([f"s{i}" for i in range(len(m_xy))]), MapConfig(cell_size_m=0.5),
                         bssids=bss)
    t = [read(n) for n in ("tst06", "tst07")]
    rss, xy = np.vstack([a for a, _ in t]), np.vstack([b for _, b in t])
    q = Query(rss, bss, np.arange(len(rss), dtype=float), np.array(["q"] * len(rss), dtype=object),
              np.full(len(rss), -1, np.int64))
    from rmbuild.localize.knn import KnnLocalizer

    e_hist = float(np.nanmean(np.hypot(*(HistogramLocalizer().fit(rm).predict(q) - xy).T)))
    e_knn = float(np.nanmean(np.hypot(*(KnnLocalizer().fit(rm).predict(q) - xy).T)))
    assert e_hist < 0.75 * e_knn and e_hist < 3.0, (e_hist, e_knn)  # bench: 2.2 vs 3.9 m (all floors)
