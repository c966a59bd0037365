"""How densely the walks were scanned: optimize reports it and warns when the scans are too sparse to place
walks by; bench/bench_scan_rate.py thins real traces the way throttled phones scan."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("gtsam")

from slam_venue import make_venue  # noqa: E402

from bench.bench_scan_rate import keeper, thin_lines  # noqa: E402
from rmbuild.config.optimize import OptimizeConfig  # noqa: E402
from rmbuild.slam import optimize  # noqa: E402
from rmbuild.slam.evidence.wifi import sparse_scans_warning  # noqa: E402
from rmbuild.slam.problem import WalkSet  # noqa: E402

STEP_M = 0.7


@pytest.fixture(scope="module")
def venue():
    return make_venue(n_walks=4, steps_per_walk=200, seed=2, step_m=STEP_M)


def every_nth_scan(fp, n: int):
    return fp.subset(np.arange(len(fp)) % n == 0)


def density(ds, fp) -> tuple[float, float]:
    walks, _ = WalkSet.from_dataset(ds, fp, "skip", 0.25)
    return walks.scan_density()


def test_scan_density_is_metres_walked_between_scans_and_scans_per_walk(venue):
    ds, fp = venue
    spacing, per_walk = density(ds, fp)  # one scan per step
    assert spacing == pytest.approx(STEP_M, rel=0.1) and per_walk == pytest.approx(200, abs=2)
    assert sparse_scans_warning(spacing, per_walk) is None
    spacing, per_walk = density(ds, every_nth_scan(fp, 10))
    assert spacing == pytest.approx(10 * STEP_M, rel=0.1) and per_walk == pytest.approx(20, abs=1)


def test_sparse_or_few_scans_get_a_warning_naming_both_figures():
    line = sparse_scans_warning(6.9, 5.0)
    assert line is not None and "6.9 m" in line and "5 per walk" in line and "throttling" in line
    assert sparse_scans_warning(6.9, 30.0) is not None  # far apart, though many
    assert sparse_scans_warning(2.5, 4.0) is not None  # close together, but few per walk
    assert sparse_scans_warning(2.5, 14.0) is None
    assert sparse_scans_warning(float("nan"), float("nan")) is None


def test_optimize_reports_the_density_and_warns_on_thinned_scans(venue):
    ds, fp = venue
    dense = optimize(ds, every_nth_scan(fp, 3), OptimizeConfig())
    sparse = optimize(ds, every_nth_scan(fp, 12), OptimizeConfig())
    assert dense.stats["vicinity"]["scan_spacing_m"] == pytest.approx(3 * STEP_M, rel=0.1)
    assert sparse.stats["vicinity"]["scan_spacing_m"] == pytest.approx(12 * STEP_M, rel=0.1)
    assert not any("sparse" in w for w in dense.stats["warnings"])
    assert sum("Wi-Fi scans are sparse" in w for w in sparse.stats["warnings"]) == 1


def test_the_bench_policies_keep_what_a_throttled_phone_would():
    t_s = np.arange(0.0, 300.0, 2.0)  # a scan every 2 s for 5 minutes, two readings each
    ilc = ["1\tTYPE_ACCELEROMETER\t0.1\t0.2\t9.8\n"] + [
        f"{int(t * 1000)}\tTYPE_WIFI\tssid\tap{k}\t-60\t2412\t{int(t * 1000)}\n" for t in t_s for k in range(2)]
    out, kept, total = thin_lines(ilc, "every_10s", "msft-ilc")
    assert (kept, total) == (30, 150) and len(out) == 1 + 2 * 30 and out[0].startswith("1\tTYPE_ACC")
    _, kept, _ = thin_lines(ilc, "android9", "msft-ilc")
    assert kept == 12  # four in each of the three 120-s windows that start within 300 s
    ipin = [f"WIFI;{t:.3f};{t:.3f};ssid;ap;2412;-60\n" for t in t_s] + ["ACCE;1.0;1.0;0.1;0.2;9.8;3\n"]
    out, kept, _ = thin_lines(ipin, "every_5s", "ipin")
    assert kept == 50 and out[-1].startswith("ACCE")
    with pytest.raises(ValueError):
        keeper("hourly")
