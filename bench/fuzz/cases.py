"""The fuzz cases: valid base inputs of every kind (made once per run) and the seeded mutated case."""

from __future__ import annotations

import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from bench.fuzz.mutate import gzip_bytes, mutate_ids, mutate_text

REPO = Path(__file__).resolve().parents[2]
FIXTURES = REPO / "tests" / "fixtures"

#: case kind -> share of the cases of a run (the second campaign's kinds, from "extreme" on: extreme finite
#: values followed through the stages, floor plans and their images, gzip bombs, many distinct keys, hostile
#: floor_info.json, venues files for `build`, outputs aimed into a workspace, planted symbolic links)
KINDS = {"schema": 0.16, "schema_parquet": 0.05, "imu": 0.06, "ilc": 0.12, "ipin": 0.09, "config": 0.15,
         "anchors": 0.12, "extreme": 0.06, "plan": 0.05, "gzip_bomb": 0.02, "keys": 0.02, "floor_info": 0.03,
         "venues": 0.02, "outputs": 0.03, "links": 0.02}

#: the hostile TOML values a config mutation sets
TOML_VALUES = ["1e-300", "1e300", "-1", "0", "-4611686018427387904", "1e308", "nan", "inf", "-inf", "true", '"x"',
               "[]", "[1, 2, 3]", "{}", "1" + "0" * 400, "0.001", "1e9", "-1e9", "4611686018427387904", '""',
               "[" * 300 + "]" * 300, '"' + "a" * 100_000 + '"', "2.5", "[0.5, 1e9]", "[-1e9, 1]"]


@dataclass
class Case:
    """One mutated input and the command that reads it."""

    kind: str
    seed: int
    argv: list[str]
    root: Path                     # the case's directory: errors must name a path inside it
    description: list[str] = field(default_factory=list)
    creates: Path | None = None    # a workspace the command would create (must not exist after a failure)
    unchanged: Path | None = None  # a workspace that must be unchanged after a failure
    then: list[list[str]] = field(default_factory=list)  # commands run in turn while the previous ones exit 0
    victims: list[Path] = field(default_factory=list)    # files outside the case's outputs that must never change
    planted: list[Path] = field(default_factory=list)    # hostile entries the case planted (not leftovers)


# ---------------------------------------------------------------------------------------------- bases
def make_bases(base: Path) -> Path:
    """Write the valid base inputs under ``base`` (once per run): rmbuild schema tables, raw phone IMU,
    the ILC and IPIN fixtures, a workspace (ingested and optimised) with an anchors file, a full config."""
    from rmbuild.cli import main

    def cli(*args: object) -> None:
        try:
            main([str(a) for a in args])
        except SystemExit as e:
            if e.code:
                raise RuntimeError(f"rmbuild {args} exited {e.code}") from None

    base.mkdir(parents=True, exist_ok=True)
    cli("simulate", base / "sim", "--preset", "tiny", "--seed", "3", "-q", "--force")
    _trim_schema(base / "sim", base / "schema", walks=3, max_t=60.0)
    cli("simulate", base / "simimu", "--preset", "tiny", "--seed", "3", "--raw-imu", "-q", "--force")
    _trim_schema(base / "simimu", base / "imu", walks=1, max_t=25.0)
    (base / "ilc").mkdir(exist_ok=True)
    shutil.copy(FIXTURES / "msft_ilc" / "tiny_trace.txt", base / "ilc" / "trace.txt")
    (base / "ipin").mkdir(exist_ok=True)
    shutil.copy(FIXTURES / "ipin" / "tiny_logfile.txt", base / "ipin" / "logfile.txt")
    shutil.rmtree(base / "ws", ignore_errors=True)
    cli("ingest", base / "schema", "-w", base / "ws", "-q")
    cli("optimize", "-w", base / "ws", "-q")
    fixes = pd.read_csv(base / "schema" / "fixes.csv", dtype={"walk_id": str})
    fixes[["walk_id", "t_s", "x_m", "y_m"]].to_csv(base / "anchors.csv", index=False)
    from rmbuild.config import SECTIONS, to_toml

    (base / "config.toml").write_text("\n".join(to_toml(cls(), name) for name, cls in SECTIONS.items()))
    _second_campaign_bases(base, cli)
    return base


def _second_campaign_bases(base: Path, cli) -> None:
    """The bases of the second campaign's kinds: a workspace with its map, the venue's plan in local metres
    with an image beside it, an MS ILC floor folder with its plan and floor_info.json, a venues file."""
    import json

    from PIL import Image

    from rmbuild.synthetic.venue import plan_geojson

    shutil.rmtree(base / "wsmap", ignore_errors=True)
    shutil.copytree(base / "ws", base / "wsmap")
    cli("export-map", "-w", base / "wsmap", "-q")
    (base / "plan").mkdir(exist_ok=True)
    venue = json.loads((base / "schema" / "truth" / "venue.json").read_text())
    Image.fromarray(np.full((40, 60, 3), 200, np.uint8)).save(base / "plan" / "floor.png")
    (base / "plan" / "plan.geojson").write_text(json.dumps({**plan_geojson(venue), "frame": "local_m",
                                                            "image": {"file": "floor.png"}}))
    floor = base / "ilcfloor" / "F1"
    (floor / "path_data_files").mkdir(parents=True, exist_ok=True)
    shutil.copy(FIXTURES / "msft_ilc" / "tiny_trace.txt", floor / "path_data_files" / "trace.txt")
    ring = [[116.0, 39.0], [116.0012, 39.0], [116.0012, 39.0009], [116.0, 39.0009], [116.0, 39.0]]
    (floor / "geojson_map.json").write_text(json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {}, "geometry": {"type": "Polygon", "coordinates": [ring]}}]}))
    (floor / "floor_info.json").write_text(json.dumps({"map_info": {"height": 100.0, "width": 100.0}}))
    (base / "venues.toml").write_text('[[venue]]\nname = "v1"\ninputs = ["schema"]\n\n'
                                      '[[venue]]\nname = "v2"\ninputs = ["ilc"]\nformat = "msft-ilc"\n')


def _trim_schema(src: Path, dst: Path, walks: int, max_t: float) -> None:
    """Keep the first ``walks`` walks and their first ``max_t`` seconds (small cases run fast)."""
    shutil.rmtree(dst, ignore_errors=True)
    (dst / "truth").mkdir(parents=True)
    keep = None
    for f in sorted(src.rglob("*.csv")):
        df = pd.read_csv(f, dtype={"walk_id": str})
        if "walk_id" in df:
            keep = keep if keep is not None else list(dict.fromkeys(df["walk_id"]))[:walks]
            df = df[df["walk_id"].isin(keep)]
            if "t_s" in df:
                t0 = df.groupby("walk_id")["t_s"].transform("min")
                df = df[df["t_s"] - t0 <= max_t]
        df.to_csv(dst / f.relative_to(src), index=False, float_format="%.6f")
    shutil.copy(src / "truth" / "venue.json", dst / "truth" / "venue.json")


# ---------------------------------------------------------------------------------------------- cases
def kind_of(index: int, seed: int) -> str:
    """The kind of case ``index`` of a run, drawn with the :data:`KINDS` shares."""
    rng = np.random.default_rng([seed, index, 1])
    names = list(KINDS)
    return names[int(rng.choice(len(names), p=np.array(list(KINDS.values())) / sum(KINDS.values())))]


def make_case(kind: str, seed: int, base: Path, root: Path, light: bool = False) -> Case:
    """Write case (kind, seed) under ``root`` (a fresh directory) and return it. ``light``: config files
    are only loaded (``rmbuild config``), not used by a stage (the test suite's quick campaign)."""
    rng = np.random.default_rng([seed, 7])
    root.mkdir(parents=True)
    if kind == "config":
        return _config(kind, seed, base, root, rng, light)
    from bench.fuzz import hostile

    return {"schema": _schema, "schema_parquet": _schema, "imu": _schema, "ilc": _trace, "ipin": _trace,
            "anchors": _anchors, **hostile.KIND_MAKERS}[kind](kind, seed, base, root, rng)


def _n_mutations(rng: np.random.Generator) -> int:
    return int(rng.choice([1, 1, 1, 2, 2, 3]))


def _schema(kind: str, seed: int, base: Path, root: Path, rng: np.random.Generator) -> Case:
    src = base / ("imu" if kind == "imu" else "schema")
    inp = root / "in"
    shutil.copytree(src, inp)
    case = Case(kind, seed, [], root, creates=root / "ws")
    files = sorted(p for p in inp.rglob("*.csv"))
    for _ in range(_n_mutations(rng)):
        f = files[int(rng.integers(len(files)))]
        data = f.read_bytes()
        header = data.split(b"\n", 1)[0].decode("utf-8", "replace").split(",")
        if rng.random() < 0.15 and "walk_id" in header:
            data, what = mutate_ids(data, rng, header.index("walk_id"))
        else:
            data, what = mutate_text(data, ",", rng, header.index("t_s") if "t_s" in header else None, header=True)
        f.write_bytes(data)
        case.description.append(f"{f.relative_to(inp)}: {what}")
    if kind == "schema_parquet":
        _to_parquet(inp, rng, case)
    elif rng.random() < 0.1:
        f = files[int(rng.integers(len(files)))]
        if f.exists():
            corrupt = bool(rng.random() < 0.5)
            f.with_name(f.name + ".gz").write_bytes(gzip_bytes(f.read_bytes(), corrupt, rng))
            f.unlink()
            case.description.append(f"{f.name} gzip'd{' and corrupted' if corrupt else ''}")
    case.argv = ["ingest", str(inp), "-w", str(root / "ws"), "-q"]
    return case


def _to_parquet(inp: Path, rng: np.random.Generator, case: Case) -> None:
    """Turn each CSV that still parses into Parquet; corrupt one Parquet file now and then."""
    for f in sorted(inp.glob("*.csv")):
        try:
            df = pd.read_csv(f, dtype={"walk_id": str, "bssid": str}, index_col=False)
            if df.shape[1] > 50:
                continue  # a mutated header: keep the (broken) CSV
        except Exception:
            continue  # the mutation broke it: it stays a (broken) CSV
        p = f.with_suffix(".parquet")
        df.to_parquet(p, index=False)
        f.unlink()
        if rng.random() < 0.15:
            data = p.read_bytes()
            n = int(rng.integers(len(data)))
            p.write_bytes(data[:n] + bytes(rng.integers(0, 256, 16, dtype=np.uint8)) + data[n + 16:])
            case.description.append(f"{p.name}: 16 random bytes at byte {n}")


def _trace(kind: str, seed: int, base: Path, root: Path, rng: np.random.Generator) -> Case:
    src = base / ("ilc" if kind == "ilc" else "ipin")
    f = root / "in" / ("trace.txt" if kind == "ilc" else "logfile.txt")
    f.parent.mkdir()
    data = (src / f.name).read_bytes()
    case = Case(kind, seed, [], root, creates=root / "ws")
    sep, tfield = ("\t", 0) if kind == "ilc" else (";", 1)
    for _ in range(_n_mutations(rng)):
        data, what = mutate_text(data, sep, rng, tfield)
        case.description.append(what)
    if rng.random() < 0.08:
        corrupt = bool(rng.random() < 0.5)
        data = gzip_bytes(data, corrupt, rng)
        f = f.with_name(f.name + ".gz")
        case.description.append(f"gzip'd{' and corrupted' if corrupt else ''}")
    f.write_bytes(data)
    fmt = ["--format", "msft-ilc" if kind == "ilc" else "ipin"] if rng.random() < 0.5 else []
    case.argv = ["ingest", str(f.parent), "-w", str(root / "ws"), "-q", *fmt]
    return case


def _config(kind: str, seed: int, base: Path, root: Path, rng: np.random.Generator, light: bool) -> Case:
    text = (base / "config.toml").read_text()
    lines = text.split("\n")
    case = Case(kind, seed, [], root)
    data = text.encode()
    for _ in range(_n_mutations(rng)):
        r = rng.random()
        if r < 0.6:
            keys = [i for i, ln in enumerate(lines) if " = " in ln and not ln.startswith("#")] or [0]
            i = keys[int(rng.integers(len(keys)))]
            value = TOML_VALUES[int(rng.integers(len(TOML_VALUES)))]
            lines[i] = lines[i].split(" = ")[0] + " = " + value
            case.description.append(f"line {i + 1}: {lines[i][:60]}")
        elif r < 0.7:
            i = int(rng.integers(len(lines)))
            lines.insert(i, "no_such_key = 1" if rng.random() < 0.5 else "[no_such_section]")
            case.description.append(f"unknown key/section at line {i + 1}")
        elif r < 0.75:
            depth = int(rng.choice([50, 500, 5000, 50_000]))
            lines.insert(1, "deep = " + "[" * depth + "]" * depth)
            case.description.append(f"array nested {depth} deep")
        data = "\n".join(lines).encode()
        if r >= 0.75:
            data, what = mutate_text(data, " = ", rng)
            lines = data.decode("utf-8", "replace").split("\n")
            case.description.append(what)
    cfg = root / "config.toml"
    cfg.write_bytes(data)
    use = 0.0 if light else rng.random()
    if use < 0.6:
        case.argv = ["config", "--config", str(cfg)]
    elif use < 0.75:
        shutil.copytree(base / "ws", root / "ws")
        case.unchanged = root / "ws"
        case.argv = ["export-map", "-w", str(root / "ws"), "--config", str(cfg), "-q"]
    elif use < 0.9:
        case.creates = root / "sim"
        case.argv = ["simulate", str(root / "sim"), "--preset", "tiny", "--config", str(cfg), "-q"]
    else:
        case.creates = root / "ws"
        case.argv = ["ingest", str(base / "schema"), "-w", str(root / "ws"), "--config", str(cfg), "-q"]
    return case


def _anchors(kind: str, seed: int, base: Path, root: Path, rng: np.random.Generator) -> Case:
    f = root / "anchors.csv"
    data = (base / "anchors.csv").read_bytes()
    case = Case(kind, seed, [], root)
    for _ in range(_n_mutations(rng)):
        r = rng.random()
        if r < 0.2:
            data, what = _anchor_nonsense(data, rng)
        else:
            data, what = mutate_text(data, ",", rng, 1, header=True)
        case.description.append(what)
    if rng.random() < 0.15:
        try:
            df = pd.read_csv(pd.io.common.BytesIO(data), dtype={"walk_id": str}, index_col=False)
            if df.shape[1] > 50:
                raise ValueError("mutated header")
            df.to_parquet(f.with_suffix(".parquet"))
            f = f.with_suffix(".parquet")
            case.description.append("as Parquet")
        except Exception:
            pass
    if f.suffix == ".csv":
        f.write_bytes(data)
    shutil.copytree(base / "ws", root / "ws")
    case.unchanged = root / "ws"
    cmd = "optimize" if rng.random() < 0.5 else "export-map"
    case.argv = [cmd, "-w", str(root / "ws"), "--anchors", str(f), "--force", "-q"]
    return case


def _anchor_nonsense(data: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    """Well-formed but absurd anchors: far away, contradictory, of unknown walks, outside the walk."""
    try:
        df = pd.read_csv(pd.io.common.BytesIO(data), dtype=str, keep_default_na=False, index_col=False)
    except Exception:
        return data, "(anchors already unreadable)"
    if not len(df) or not {"walk_id", "t_s", "x_m"} <= set(df.columns):
        return data, "(no rows to make absurd)"
    i = int(rng.integers(len(df)))
    what = int(rng.integers(4))
    if what == 0:
        df.loc[i, "x_m"] = repr(float(rng.choice([1e300, -1e12, 1e6])))
        desc = "anchor far away"
    elif what == 1:
        row = df.iloc[[i]].copy()
        x = pd.to_numeric(row["x_m"], errors="coerce").fillna(0.0)
        row["x_m"] = (x + float(rng.choice([3.0, 40.0, 500.0]))).map(repr)
        df = pd.concat([df, row], ignore_index=True)
        desc = "contradictory anchor (same walk and time)"
    elif what == 2:
        df.loc[i, "walk_id"] = "ghost"
        desc = "anchor of an unknown walk"
    else:
        df.loc[i, "t_s"] = repr(float(rng.choice([-1e6, 1e12, 1e9])))
        desc = "anchor time outside the walk"
    return df.to_csv(index=False).encode(), desc
