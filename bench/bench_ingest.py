"""Ingest throughput on the `large` preset vs a bare pandas.read_csv of the same files (one run, ratios of
wall-clock and of CPU time: pandas' read_csv parses large files on several threads, so its wall time is below
its CPU time on an idle machine)."""

from __future__ import annotations

import logging
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from bench.common import write_result
from rmbuild.config import IngestConfig
from rmbuild.config.simulate import preset_config
from rmbuild.stages import ingest, simulate


def main(preset: str = "large", seed: int = 7, reps: int = 5) -> dict:
    tmp = Path(tempfile.mkdtemp(prefix="rmbuild-bench-ingest-"))
    quiet = logging.getLogger("rmbuild")
    level = quiet.level
    quiet.setLevel(logging.ERROR)  # the input's warnings would repeat once per repetition
    try:
        t0 = time.perf_counter()
        s = simulate.run(tmp / "input", preset_config(preset, seed))
        t_sim = time.perf_counter() - t0
        files = sorted((tmp / "input").rglob("*.csv"))  # every table ingest reads, truth/ included
        import pyarrow.parquet  # noqa: F401  (imports are not what we time)
        # warm-up on the tiny venue: module imports are a fixed per-process cost, not throughput
        simulate.run(tmp / "warm", preset_config("tiny", seed))
        ingest.run([tmp / "warm"], tmp / "warm_ws", IngestConfig())
        t_read, t_ingest, c_read, c_ingest = [], [], [], []
        for i in range(reps):  # interleaved: the shared machine's load changes between runs
            t0, c0 = time.perf_counter(), time.process_time()
            n_rows = sum(len(pd.read_csv(f)) for f in files)
            t_read.append(time.perf_counter() - t0)
            c_read.append(time.process_time() - c0)
            t0, c0 = time.perf_counter(), time.process_time()
            r = ingest.run([tmp / "input"], tmp / f"ws{i}", IngestConfig())
            t_ingest.append(time.perf_counter() - t0)
            c_ingest.append(time.process_time() - c0)
    finally:
        quiet.setLevel(level)
        shutil.rmtree(tmp, ignore_errors=True)
    ratios = [b / a for a, b in zip(t_read, t_ingest, strict=True)]
    cpu_ratios = [b / a for a, b in zip(c_read, c_ingest, strict=True)]
    res = {
        "preset": preset,
        "steps": s["steps"],
        "readings": r["readings"],
        "rows_read": n_rows,
        "repetitions": reps,
        "time_s": {"simulate": round(t_sim, 3), "pandas_read_csv": round(float(np.median(t_read)), 3),
                   "ingest": round(float(np.median(t_ingest)), 3)},
        "cpu_s": {"pandas_read_csv": round(float(np.median(c_read)), 3),
                  "ingest": round(float(np.median(c_ingest)), 3)},
        "ingest_readings_per_s": round(r["readings"] / float(np.median(t_ingest))),
        "ratio_ingest_to_read_csv": round(float(np.median(ratios)), 2),
        "ratio_each_run": [round(x, 2) for x in ratios],
        "ratio_cpu_ingest_to_read_csv": round(float(np.median(cpu_ratios)), 2),
        "ratio_cpu_each_run": [round(x, 2) for x in cpu_ratios],
        "target_ratio_max": 3.0,
    }
    write_result("ingest", res)
    print(f"ingest {preset}: {r['readings']} readings in {res['time_s']['ingest']:.2f} s "
          f"({res['ingest_readings_per_s']}/s); pandas.read_csv {res['time_s']['pandas_read_csv']:.2f} s; "
          f"ratio {res['ratio_ingest_to_read_csv']} (CPU time {res['ratio_cpu_ingest_to_read_csv']})")
    return res


if __name__ == "__main__":
    main()
