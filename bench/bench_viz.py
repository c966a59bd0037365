"""Logging a `large` workspace to a rerun recording vs the optimisation of the same workspace (one run).

Writes bench/results/viz.json: optimise time, view (.rrd) time and size, report time, and the ratio
view / optimise (target: well under 1). Run with `python -m bench.bench_viz`.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path

from bench.common import peak_rss_mb, write_result
from rmbuild.config import IngestConfig, OptimizeConfig
from rmbuild.config.simulate import preset_config
from rmbuild.stages import ingest, optimize, simulate
from rmbuild.stages import report as report_stage
from rmbuild.stages import view as view_stage
from rmbuild.viz import ViewTarget


def main(preset: str = "large", seed: int = 7) -> dict:
    tmp = Path(tempfile.mkdtemp(prefix="rmbuild-bench-viz-"))
    try:
        simulate.run(tmp / "input", preset_config(preset, seed))
        ingest.run([tmp / "input"], tmp / "ws", IngestConfig())
        t0 = time.perf_counter()
        o = optimize.run(tmp / "ws", OptimizeConfig())
        t_opt = time.perf_counter() - t0
        rrd = tmp / "ws" / "view.rrd"
        t0 = time.perf_counter()
        v = view_stage.run(tmp / "ws", ViewTarget("save", rrd))
        t_view = time.perf_counter() - t0
        size_mb = rrd.stat().st_size / 1e6
        t0 = time.perf_counter()
        rep = report_stage.run(tmp / "ws")
        t_report = time.perf_counter() - t0
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    res = {
        "preset": preset,
        "walks": o["walks"],
        "poses": o["poses"],
        "vicinity_factors": o["factors"]["vicinity"],
        "time_s": {"optimize": round(t_opt, 3), "view_rrd": round(t_view, 3), "report": round(t_report, 3),
                   "view_phases": v["time_s"]},
        "rrd_mb": round(size_mb, 2),
        "logged": v["logged"],
        "counts": v["counts"],
        "report_figures": rep["figures"],
        "ratio_view_to_optimize": round(t_view / t_opt, 3),
        "target_ratio_max": 0.25,
        "peak_rss_mb": round(peak_rss_mb(), 1),
    }
    write_result("viz", res)
    print(f"viz {preset}: optimise {t_opt:.2f} s; log to .rrd {t_view:.2f} s ({size_mb:.1f} MB), "
          f"ratio {res['ratio_view_to_optimize']}; report {t_report:.2f} s")
    return res


if __name__ == "__main__":
    main()
