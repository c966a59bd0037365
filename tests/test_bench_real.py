"""The scoring helpers of bench/bench_real.py (the real-floor benchmark must keep measuring the same thing)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from bench.bench_real import (
    aligned_errors,
    at_fix_times,
    fit_se2,
    linkable_walks,
    linked_walks,
    offset_split,
    shared_path_share,
)


def test_fit_se2_recovers_a_rigid_transform_and_errors_vanish():
    rng = np.random.default_rng(3)
    src = rng.uniform(-20, 20, (50, 2))
    th = 0.7
    r = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    dst = src @ r.T + np.array([5.0, -3.0])
    r_fit, t_fit = fit_se2(src, dst)
    assert np.allclose(r_fit, r, atol=1e-9) and np.allclose(t_fit, [5.0, -3.0], atol=1e-9)
    # fitted on the first half only, the second half (same transform) is still exact; a NaN stays NaN
    est = src.copy()
    est[-1] = np.nan
    fit = np.arange(50) < 25
    e = aligned_errors(est, dst, fit)
    assert np.nanmax(e) < 1e-9 and np.isnan(e[-1])


def test_at_fix_times_interpolates_within_a_walk_and_is_nan_outside():
    poses = pd.DataFrame({"walk_id": ["a", "a", "b", "b"], "t_s": [0.0, 10.0, 0.0, 4.0],
                          "x_m": [0.0, 10.0, 100.0, 100.0], "y_m": [0.0, 0.0, 0.0, 8.0]})
    fixes = pd.DataFrame({"walk_id": ["a", "a", "b", "c"], "t_s": [2.5, 11.0, 1.0, 1.0]})
    xy = at_fix_times(poses, fixes)
    assert np.allclose(xy[0], [2.5, 0.0]) and np.allclose(xy[2], [100.0, 2.0])
    assert np.isnan(xy[1]).all() and np.isnan(xy[3]).all()  # after the walk's last pose; unknown walk


def test_shared_path_share_counts_path_within_5m_of_another_walk():
    t = np.arange(5.0)
    fixes = pd.concat([
        pd.DataFrame({"walk_id": "a", "t_s": t, "x_m": 10.0 * t, "y_m": 0.0}),
        pd.DataFrame({"walk_id": "b", "t_s": t, "x_m": 10.0 * t, "y_m": 3.0}),  # 3 m beside a: shared
        pd.DataFrame({"walk_id": "c", "t_s": t, "x_m": 20.0 + 5.0 * t, "y_m": 20.0}),  # 17 m from b: not
    ])
    share = shared_path_share(fixes)
    assert share["a"] == 1.0 and share["b"] == 1.0 and share["c"] == 0.0


def test_linked_walks_reads_the_walk_table_then_the_poses_then_assumes_all():
    poses = pd.DataFrame({"walk_id": ["a", "b"], "linked": [True, False]})
    walks = pd.DataFrame({"walk_id": ["a", "b"], "linked": [False, True]})
    assert linked_walks(walks, poses) == {"b"}
    assert linked_walks(None, poses) == {"a"}
    assert linked_walks(walks.drop(columns="linked"), poses.drop(columns="linked")) == {"a", "b"}


def test_linkable_walks_joins_by_shared_path_and_by_a_device_continuing_nearby():
    t = np.arange(5.0)
    fixes = pd.concat([
        pd.DataFrame({"walk_id": "a", "t_s": t, "x_m": 10.0 * t, "y_m": 0.0}),
        pd.DataFrame({"walk_id": "b", "t_s": t, "x_m": 10.0 * t, "y_m": 6.0}),  # 40 m within 8 m of a
        pd.DataFrame({"walk_id": "c", "t_s": 100 + t, "x_m": 40.0, "y_m": 100.0 + 10 * t}),  # far from both
        pd.DataFrame({"walk_id": "d", "t_s": 150 + t, "x_m": 40.0, "y_m": 143.0 + 10 * t}),  # starts 3 m on
    ])
    poses = fixes[["walk_id", "t_s"]]
    assert linkable_walks(fixes, None, poses, 8.0) == 2  # a-b only
    assert linkable_walks(fixes, None, poses, 5.0) == 1  # 6 m apart: not within 5 m
    walks = pd.DataFrame({"walk_id": ["a", "b", "c", "d"], "device_id": ["p", "q", "r", "r"]})
    assert linkable_walks(fixes, walks, poses, 8.0) == 2  # c-d joined too: two groups of two
    walks["device_id"] = ["p", "r", "r", "r"]  # b ends at (40, 6), c starts 94 m away: no join
    assert linkable_walks(fixes, walks, poses, 8.0) == 2
    fixes.loc[fixes["walk_id"] == "c", "y_m"] -= 94.0  # c now starts at b's end (gap 96 s > 60 s): no join
    assert linkable_walks(fixes, walks, poses, 8.0) == 2
    fixes.loc[fixes["walk_id"] == "c", "t_s"] -= 50.0  # gap 46 s: b-c joined (c-d 97 m apart)
    assert linkable_walks(fixes, walks, fixes[["walk_id", "t_s"]], 8.0) == 3


def test_offset_split_separates_where_a_walk_sits_from_its_shape():
    wp = pd.DataFrame({"walk_id": ["a"] * 4 + ["b"] * 2 + ["c"] * 2, "linked": [True] * 6 + [False] * 2,
                       "dx_opt": [3.0, 3.0, 3.0, 3.0, 1.0, -1.0, 50.0, 50.0],  # a: shifted 5 m; b: 1 m either side
                       "dy_opt": [4.0, 4.0, 4.0, 4.0, 0.0, 0.0, 0.0, 0.0]})
    split = offset_split(wp)
    assert split == {"offset_m": 2.5, "shape_m": 0.5}  # offsets 5 and 0; shapes 0 and 1; c is not linked
    assert offset_split(wp.assign(linked=False)) is None


def test_leave_one_floor_out_chooses_on_the_other_floors(tmp_path) -> None:
    """bench.lofo: each floor's candidate is the one best on the *other* floors (geometric-mean kNN ratio)."""
    import json

    from bench import lofo

    ratios = {"a": {"F1": 1.0, "F2": 3.0, "F3": 3.0}, "b": {"F1": 4.0, "F2": 1.5, "F3": 1.5}}
    specs = []
    for name, per_floor in ratios.items():
        rows = [{"floor": f, "walks": 10, "linked": 5, "knn": {"ratio": r},
                 "landmark_m": {"linked_walks": {"mean": 2.0}}} for f, r in per_floor.items()]
        p = tmp_path / f"{name}.json"
        p.write_text(json.dumps({"floors": rows}))
        specs.append(f"{name}={p}")
    results = lofo.load(specs)
    floors = ["F1", "F2", "F3"]
    assert lofo.choose(results, floors, "F1") == "b"  # F2 and F3 favour b
    assert lofo.choose(results, floors, "F2") == "a"  # F1, F3: a 1.73 vs b 2.45
    md = lofo.table(results)
    assert "| F1 | 5/10, 2.0, 1.00 | 5/10, 2.0, 4.00 | b | 4.00 |" in md
    # the last line: each candidate's geometric mean, then the held-out floors' (b on F1, a on F2 and F3)
    assert md.splitlines()[-1].endswith(f"| leave one floor out | {lofo.geomean([4.0, 3.0, 3.0]):.2f} |")
