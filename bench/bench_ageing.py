"""A map that ages: UJI long-term (25 monthly collections of one library), a map from month 1 against the
tests of every later month, per-AP change detection, and an update rule from newer data.
Writes bench/results/ageing.json, ageing.md and ageing_aps.csv (the per-AP verdicts with their evidence).
Run: ``nice -n 10 python -m bench.bench_ageing`` (about seven minutes on the shared 2-core machine).

* **Map**: month 1's training data (15 sets: 48 surveyed points x 12 samples each, x 15; the 6 rows of
  ``trn14`` with floor 0, a known glitch, left out), one RP per point (:func:`point_map`); the floor is
  known (the data set's two floors are localized apart), kNN with K = 3 (24 RPs per floor) over the
  map's APs, missing readings at -110 dBm (evaluate's kNN otherwise).
* **Tests**: each month's test sets tst01-05 (Galaxy S3; month 25's tst06-10 were taken with a Galaxy A5 and
  are reported apart), 212 points x 6 samples.
* **Updates** (causal: the map used in month m has seen the training data of months < m only; each
  month's training set, trn01, is the "new walks"):
  - ``static``: month 1's map;
  - ``drop``: APs no new reading heard for the last ``GONE_AFTER`` months leave the map;
  - ``refresh_half``: each month, a random half of the points (seeded) are seen again: their RPs take the
    new fingerprint (the others keep theirs, however old);
  - ``refresh_half+drop``: both (the AP evidence is only what the half seen again heard);
  - ``refresh_all``: every point seen again every month (a full resurvey: the bound).
* **AP changes**: :func:`classify_aps` over the 25 monthly training sets, month 1 the reference.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from bench.common import RESULTS, write_result

SHARED = Path(__file__).resolve().parents[2] / "shared" / "datasets"
DB = SHARED / "uji-longterm" / "db"
MONTHS = range(1, 26)
FLOORS = (3, 5)
#: months an AP must go unheard (in the new data) before the update rule drops it
GONE_AFTER = 3
#: share of the points seen again each month by the partial refresh, and its seed
HALF, SEED = 0.5, 0
K = 3
#: month 25's sets taken with the other phone (Galaxy A5 2017)
A5_SETS = {25: ("trn02", "tst06", "tst07", "tst08", "tst09", "tst10")}


def load():
    from rmbuild.io.uji_longterm import read_set, set_names
    from rmbuild.radiomap.ageing import point_map

    trn, tst, a5 = {}, {}, None
    for m in MONTHS:
        names = [n for n in set_names(DB, m) if n not in A5_SETS.get(m, ())]
        sets = [read_set(DB, m, n) for n in names]
        t = [s for s in sets if s.name.startswith("trn")]
        rss = np.vstack([s.rss_dbm for s in t])
        xy = np.vstack([s.xy for s in t])
        fl = np.concatenate([s.floor for s in t])
        ok = np.isin(fl, FLOORS)
        trn[m] = point_map(rss[ok], xy[ok], fl[ok], t[0].bssids, m)
        tst[m] = [s for s in sets if s.name.startswith("tst")]
    a5 = [read_set(DB, 25, n) for n in A5_SETS[25] if n.startswith("tst")]
    return trn, tst, a5


def errors(pm, tests) -> np.ndarray:
    from rmbuild.config.evaluate import KnnConfig
    from rmbuild.localize.knn import KnnLocalizer

    out = []
    for s in tests:
        e = np.full(len(s), np.nan)
        for f in FLOORS:
            q = s.floor == f
            loc = KnnLocalizer(KnnConfig(k=K)).fit(pm.reference_set(f))
            p = loc.predict_rss(s.rss_dbm[q])
            e[q] = np.hypot(*(p - s.xy[q]).T)
        out.append(e)
    return np.concatenate(out)


def run_updates(trn, tst, gone_after: int = GONE_AFTER, share: float = HALF) -> tuple[dict, dict]:
    """Per variant and month: mean / median / p90 error (m), and the map's state (RP ages, APs).
    ``gone_after``: months unheard before an AP is dropped; ``share``: of the points seen again a month."""
    from rmbuild.radiomap.ageing import drop_aps, heard, refresh

    rng = np.random.default_rng(SEED)
    base = trn[1]
    n_pts = len(base)
    state = {"static": base, "drop": base, "refresh_half": base, "refresh_half+drop": base, "refresh_all": base}
    heard_hist: dict[str, list[np.ndarray]] = {"drop": [], "refresh_half+drop": []}
    curve: dict[str, dict[int, dict]] = {v: {} for v in state}
    info: dict[str, dict[int, dict]] = {v: {} for v in state}
    for m in MONTHS:
        if m > 1:
            new = trn[m - 1]
            half = new.rows(np.sort(rng.choice(len(new), int(round(share * n_pts)), replace=False)))
            state["refresh_all"] = refresh(state["refresh_all"], new)
            state["refresh_half"] = refresh(state["refresh_half"], half)
            heard_hist["drop"].append(heard(new))
            heard_hist["refresh_half+drop"].append(heard(half))
            for v, base_v in (("drop", base), ("refresh_half+drop", state["refresh_half"])):
                recent = heard_hist[v][-gone_after:]
                gone = ~np.any(recent, axis=0) if len(recent) == gone_after else np.zeros(len(base.bssids), bool)
                state[v] = drop_aps(base_v, gone)
        for v, pm in state.items():
            e = errors(pm, tst[m])
            curve[v][m] = {"mean": float(np.nanmean(e)), "median": float(np.nanmedian(e)),
                           "p90": float(np.nanpercentile(e, 90)), "n": int(np.isfinite(e).sum())}
            info[v][m] = {"aps_in_map": int(heard(pm).sum()), "rp_age_months_mean": float(np.mean(m - pm.month))}
    return curve, info


def sweep(trn, tst) -> dict:
    """Mean error (m) over months 2-10 and 11-25 of ``drop`` for several N and of ``refresh_half+drop`` for
    several shares of the points seen again a month (the choices of GONE_AFTER and HALF)."""

    def means(curve: dict) -> dict:
        return {p: round(float(np.mean([curve[m]["mean"] for m in r])), 3)
                for p, r in (("2-10", range(2, 11)), ("11-25", range(11, 26)))}

    out: dict = {"drop": {}, "refresh+drop": {}}
    for n in (1, 2, 3, 6):
        c, _ = run_updates(trn, tst, gone_after=n)
        out["drop"][f"N={n}"] = means(c["drop"])
    for share in (0.1, 0.25, 0.5):
        c, _ = run_updates(trn, tst, share=share)
        out["refresh+drop"][f"share={share}"] = {"refresh": means(c["refresh_half"]),
                                                 "refresh+drop": means(c["refresh_half+drop"])}
    return out


def md(out: dict) -> list[str]:
    c = out["curve"]
    vs = list(c)
    lines = ["# UJI long-term: the map from month 1, month by month", "",
             "kNN (K = 3) mean / median error (m) over each month's tests tst01-05 (Galaxy S3); the map used "
             "in month m has seen the training data of months < m only. `bench/bench_ageing.py`.", "",
             "| month | " + " | ".join(vs) + " |", "|---|" + "---|" * len(vs)]
    for m in MONTHS:
        lines.append(f"| {m} | " + " | ".join(f"{c[v][str(m)]['mean']:.2f} / {c[v][str(m)]['median']:.2f}"
                                               for v in vs) + " |")
    avg = {v: np.mean([c[v][str(m)]["mean"] for m in MONTHS if m >= 2]) for v in vs}
    lines.append("| mean 2-25 | " + " | ".join(f"{avg[v]:.2f}" for v in vs) + " |")
    lines += ["", "## Month 25, Galaxy A5 tests (tst06-10): a device change on top of two years", "",
              "| variant | mean | median |", "|---|---|---|"]
    for v, e in out["a5_month25"].items():
        lines.append(f"| {v} | {e['mean']:.2f} | {e['median']:.2f} |")
    sw = out["sweep"]
    lines += ["", "## The rule's two parameters (mean error in m, months 2-10 / 11-25)", "",
              "| drop APs unheard for N months (no refresh) | 2-10 | 11-25 |", "|---|---|---|"]
    lines += [f"| {k} | {v['2-10']:.2f} | {v['11-25']:.2f} |" for k, v in sw["drop"].items()]
    lines += ["", "| share of points seen again a month | refresh 2-10 | refresh 11-25 | refresh + drop (N = 3) "
              "11-25 |", "|---|---|---|---|"]
    lines += [f"| {k} | {v['refresh']['2-10']:.2f} | {v['refresh']['11-25']:.2f} | {v['refresh+drop']['11-25']:.2f} |"
              for k, v in sw["refresh+drop"].items()]
    s = out["ap_changes"]["counts"]
    lines += ["", "## AP changes: month 1 vs the last 3 months each AP was heard (monthly training sets)", "",
              "| status | APs |", "|---|---|"] + [f"| {k} | {n} |" for k, n in s.items()]
    rep = out["ap_changes"]["replaced"]
    lines += ["", f"{rep['gone_with_replacement']} of {rep['gone']} gone APs have a replacement (an AP first heard "
              "within a month of their last, its strongest readings within 5 m on the same floor); the month "
              f"the gone APs were last heard: {rep['last_month_counts']}.", "",
              "Examples per status (months heard; centre of the strongest readings, month 1 and late; "
              "RSS shift at the RPs heard in both):", "",
              "| AP | status | months heard | first (x, y, floor) | late (x, y, floor) | RSS shift dB | replaced by |",
              "|---|---|---|---|---|---|---|"]
    for r in out["ap_changes"]["examples"]:
        lines.append(f"| {r['bssid']} | {r['status']} | {r['months_heard']} | {_xy(r, 'first')} | {_xy(r, 'late')} "
                     f"| {_f(r['rss_shift_db'])} | {r['replaced_by'] or '-'} |")
    return lines


def _xy(r: dict, which: str) -> str:
    if r[f"{which}_x_m"] is None:
        return "-"
    return f"{r[which + '_x_m']:.1f}, {r[which + '_y_m']:.1f}, {r['floor_' + which]}"


def _f(x) -> str:
    return "-" if x is None or (isinstance(x, float) and not np.isfinite(x)) else f"{x:.1f}"


def main() -> None:
    from rmbuild.radiomap.ageing import classify_aps

    t0 = time.perf_counter()
    if not DB.is_dir():
        print("uji-longterm not present")
        return
    trn, tst, a5 = load()
    curve, info = run_updates(trn, tst)
    sw = sweep(trn, tst)
    aps = classify_aps(trn, gone_after=GONE_AFTER)
    counts = aps["status"].value_counts().to_dict()
    ex = (aps[aps["status"] != "stable"].assign(k=lambda d: d["status"].map(
        {"gone": 0, "moved": 1, "appeared": 2, "transient": 3})).sort_values(["k", "n_months"], ascending=[True, False])
          .groupby("status").head(3).drop(columns="k"))
    gone = aps[aps["status"] == "gone"]
    replaced = {"gone": len(gone), "gone_with_replacement": int((gone["replaced_by"] != "").sum()),
                "last_month_counts": {int(k): int(v)
                                      for k, v in gone["last_month"].value_counts().sort_index().items()}}
    a5_err = {}
    for v, pm in (("static", trn[1]), ("refresh_all (month 24)", trn[24])):
        e = errors(pm, a5)
        a5_err[v] = {"mean": float(np.nanmean(e)), "median": float(np.nanmedian(e))}
    out = {"setup": __doc__.split("\n\n")[1] if __doc__ else "", "k": K, "gone_after_months": GONE_AFTER,
           "curve": {v: {str(m): s for m, s in d.items()} for v, d in curve.items()},
           "map_state": {v: {str(m): s for m, s in d.items()} for v, d in info.items()},
           "a5_month25": a5_err, "sweep": sw,
           "ap_changes": {"counts": {str(k): int(n) for k, n in counts.items()},
                          "replaced": replaced, "examples": ex.replace({np.nan: None}).to_dict("records"),
                          "aps": "ageing_aps.csv (one row per AP, the columns of classify_aps)"},
           "time_s": round(time.perf_counter() - t0, 1)}
    p = write_result("ageing", out)
    aps.to_csv(RESULTS / "ageing_aps.csv", index=False, float_format="%.2f")
    (RESULTS / "ageing.md").write_text("\n".join(md(out)) + "\n")
    print("\n".join(md(out)))
    print(p)


if __name__ == "__main__":
    main()
