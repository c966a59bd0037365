"""The second campaign's fuzz kinds (issue 40): extreme finite values followed through the stages, floor plans
and their images, gzip bombs, many distinct keys, hostile floor_info.json, venues files for `build`, outputs
aimed into a workspace, planted symbolic links. Each maker writes one case under ``root`` from the bases
(:func:`bench.fuzz.cases.make_bases`) and returns it (:class:`bench.fuzz.cases.Case`)."""

from __future__ import annotations

import gzip
import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd

from bench.fuzz.cases import FIXTURES, Case

#: extreme but finite (or just beyond a limit) values for numeric cells
EXTREMES = ["1e308", "-1e308", "1.7976931348623157e308", "1e30", "-1e30", "1e15", "2e9", "-2e9", "100000.5",
            "-100000.5", "99999.9", "5e4", "1e-300", "-1e-300", "4.9e-324"]
#: the stages an accepted input is followed through
CHAIN = (["optimize"], ["export-map"], ["evaluate"])


def _pick(rng: np.random.Generator, seq: list | tuple):
    return seq[int(rng.integers(len(seq)))]


def _chain(ws: Path, upto: int = 3) -> list[list[str]]:
    return [[c[0], "-w", str(ws), "-q"] for c in CHAIN[:upto]]


# ---------------------------------------------------------------------------------------------- extreme values
def extreme(kind: str, seed: int, base: Path, root: Path, rng: np.random.Generator) -> Case:
    """rmbuild's schema with extreme finite values in positions, times and readings (or one walk scaled far
    out), ingested and, when accepted, optimised, mapped and evaluated."""
    inp = root / "in"
    shutil.copytree(base / "schema", inp)
    case = Case(kind, seed, [], root, creates=root / "ws")
    targets = {"poses.csv": ["x_m", "y_m", "t_s", "heading_rad"], "fixes.csv": ["x_m", "y_m", "t_s"],
               "wifi.csv": ["t_s", "rssi_dbm"], "truth/poses.csv": ["x_m", "y_m"]}
    for _ in range(int(rng.choice([1, 1, 2, 3]))):
        name = str(_pick(rng, list(targets)))
        df = pd.read_csv(inp / name, dtype=str, keep_default_na=False)
        if rng.random() < 0.2 and "x_m" in df:  # one walk stretched: steps of km, positions near the limits
            w = str(_pick(rng, sorted(df["walk_id"].unique())))
            f = float(_pick(rng, [1e2, 1e3, 1e4, 3e4]))
            m = df["walk_id"] == w
            for c in ("x_m", "y_m"):
                df.loc[m, c] = (df.loc[m, c].astype(float) * f).map(repr)
            case.description.append(f"{name}: walk {w} x {f:g}")
        else:
            i, c = int(rng.integers(len(df))), str(_pick(rng, targets[name]))
            v = str(_pick(rng, EXTREMES))
            df.loc[i, c] = v
            case.description.append(f"{name}: row {i + 1} {c} = {v}")
        df.to_csv(inp / name, index=False)
    case.argv = ["ingest", str(inp), "-w", str(root / "ws"), "-q"]
    case.then = _chain(root / "ws")
    return case


# ---------------------------------------------------------------------------------------------- floor plans
def _circle(n: int, r: float = 30.0) -> list:
    a = 2 * np.pi * np.arange(n) / n
    ring = np.c_[20 + r * np.cos(a), 15 + r * np.sin(a)].round(3).tolist()
    return ring + ring[:1]


def _rect_feature(x0: float, y0: float, x1: float, y1: float) -> dict:
    ring = [[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]
    return {"type": "Feature", "properties": {"type": "floor"}, "geometry": {"type": "Polygon", "coordinates": [ring]}}


def plan(kind: str, seed: int, base: Path, root: Path, rng: np.random.Generator) -> Case:
    """A floor plan (and the image it names) made hostile: numbers JSON has not, extreme or far vertices, deep
    nesting, many vertices, degenerate shapes, broken members, images outside its folder, broken images."""
    shutil.copytree(base / "plan", root / "plan")
    shutil.copytree(base / "schema", root / "in")
    f = root / "plan" / "plan.geojson"
    doc = json.loads(f.read_text())
    case = Case(kind, seed, [], root, creates=root / "ws")
    op = str(_pick(rng, ["nan", "inf", "e400", "extreme", "scale", "deep", "vertices", "degenerate", "no_geometry",
                         "wrong_type", "not_object", "image_out", "image_abs", "image_broken", "image_missing",
                         "image_link", "image_extent", "frame", "empty_features", "valid"]))
    text = None
    if op in ("nan", "inf", "e400"):
        ring = doc["features"][0]["geometry"]["coordinates"][0]
        ring[int(rng.integers(len(ring)))][0] = "@"
        text = json.dumps(doc).replace('"@"', {"nan": "NaN", "inf": "-Infinity", "e400": "1e400"}[op])
    elif op == "extreme":
        doc["features"].append(_rect_feature(*(float(_pick(rng, EXTREMES[:6])) * s for s in (-1, -1, 1, 1))))
    elif op == "scale":
        f_ = float(_pick(rng, [1e2, 1e3, 1e5, 1e7]))
        for feat in doc["features"]:
            g = feat["geometry"]
            g["coordinates"] = json.loads(json.dumps(g["coordinates"]), parse_float=lambda v: float(v) * f_,
                                          parse_int=lambda v: int(v) * f_)
    elif op == "deep":
        d = int(_pick(rng, [100, 1000, 100_000]))
        text = json.dumps(doc)[:-1] + ', "x": ' + "[" * d + "]" * d + "}"
    elif op == "vertices":
        n = int(_pick(rng, [2_000, 60_000, 99_000, 101_000, 400_000]))
        doc = {"type": "FeatureCollection", "frame": "local_m", "features": [
            {"type": "Feature", "properties": {"type": "floor"}, "geometry": {"type": "Polygon",
                                                                            "coordinates": [_circle(n)]}}]}
    elif op == "degenerate":
        doc["features"] = [_rect_feature(5, 5, 5, 5)]
    elif op == "no_geometry":
        doc["features"][0]["geometry"] = None
    elif op == "wrong_type":
        doc["features"][0]["geometry"]["coordinates"] = str(_pick(rng, ["x", "[[1]]", "5"]))
    elif op == "not_object":
        text = str(_pick(rng, ["[]", "5", '"plan"', "null", "{"]))
    elif op == "image_out":
        doc["image"] = {"file": str(_pick(rng, ["../../../../etc/passwd", "../in/poses.csv", "..", "."]))}
    elif op == "image_abs":
        doc["image"] = {"file": str(_pick(rng, ["/etc/hostname", "/dev/zero", str(root / "in" / "wifi.csv")]))}
    elif op == "image_broken":
        png = root / "plan" / "floor.png"
        data = png.read_bytes()
        k = int(rng.integers(len(data)))
        png.write_bytes(data[:k] + bytes(rng.integers(0, 256, 64, dtype=np.uint8)) + data[k + 64:])
    elif op == "image_missing":
        (root / "plan" / "floor.png").unlink()
    elif op == "image_link":
        (root / "plan" / "floor.png").unlink()
        (root / "plan" / "floor.png").symlink_to(str(_pick(rng, ["/etc/hostname", "/dev/zero",
                                                                  str(base / "plan" / "floor.png")])))
    elif op == "image_extent":
        doc["image"] = {"file": "floor.png", "extent": _pick(rng, [[0, 0, 0, 0], [1e308, 0, 2e308, 1], [0, 0, 1],
                                                                   [5, 5, 1, 1], ["a", 0, 1, 1]])}
    elif op == "frame":
        doc["frame"] = str(_pick(rng, ["wgs84", "", "local"]))
    elif op == "empty_features":
        doc["features"] = []
    case.description.append(f"plan: {op}")
    f.write_text(text if text is not None else json.dumps(doc, allow_nan=True))
    case.argv = ["ingest", str(root / "in"), "-w", str(root / "ws"), "--floorplan", str(f), "-q"]
    case.then = _chain(root / "ws", 2)
    return case


# ---------------------------------------------------------------------------------------------- gzip bombs
def _members(path: Path, head: bytes, filler: bytes, total: int) -> None:
    """``head`` then ``filler`` to ``total`` bytes, gzip'd as one member per MB (written in a moment)."""
    block = gzip.compress(filler * max(1, (1 << 20) // len(filler)), compresslevel=6)
    with path.open("wb") as fh:
        fh.write(gzip.compress(head))
        for _ in range(total >> 20):
            fh.write(block)


def gzip_bomb(kind: str, seed: int, base: Path, root: Path, rng: np.random.Generator) -> Case:
    """A compressed input expanding to 150 MB - 3 GB: an MS ILC trace, an IPIN logfile or a schema table."""
    which = str(_pick(rng, ["ilc", "ipin", "wifi", "poses"]))
    filler = bytes(_pick(rng, [b"#" + b"x" * 200 + b"\n", b"\n", b"x", b"\x00", b"1574559496500\tTYPE_WIFI\tN\t"
                               b"0a:00:00:00:00:01\t-50\t2412\t1574559496500\n",
                               b"w000,1.0,70:3a:0e:74:b7:10,-63.0,2437,x\n"]))
    total = int(_pick(rng, [150 << 20, 400 << 20, 3 << 30]))
    inp = root / "in"
    case = Case(kind, seed, [], root, creates=root / "ws")
    if which in ("ilc", "ipin"):
        inp.mkdir()
        src = FIXTURES / ("msft_ilc/tiny_trace.txt" if which == "ilc" else "ipin/tiny_logfile.txt")
        _members(inp / ("trace.txt.gz" if which == "ilc" else "logfile.txt.gz"), src.read_bytes(), filler, total)
    else:
        shutil.copytree(base / "schema", inp)
        f = inp / f"{which}.csv"
        _members(inp / f"{which}.csv.gz", f.read_bytes(), filler, total)
        f.unlink()
    case.description.append(f"{which}: gzip of {total >> 20} MB of {filler[:20]!r}")
    case.argv = ["ingest", str(inp), "-w", str(root / "ws"), "-q"]
    return case


# ---------------------------------------------------------------------------------------------- many keys
def keys(kind: str, seed: int, base: Path, root: Path, rng: np.random.Generator) -> Case:
    """Up to 1e6 Wi-Fi readings of up to 1e6 distinct BSSIDs on the schema's walks."""
    inp = root / "in"
    shutil.copytree(base / "schema", inp)
    case = Case(kind, seed, [], root, creates=root / "ws")
    n = int(_pick(rng, [10_000, 100_000, 300_000, 1_000_000]))
    distinct = max(1, int(n * float(_pick(rng, [1.0, 0.3, 0.01]))))
    poses = pd.read_csv(inp / "poses.csv", dtype={"walk_id": str})
    k = rng.integers(0, len(poses), n)
    order = np.lexsort((poses["t_s"].to_numpy()[k], poses["walk_id"].to_numpy()[k]))
    k = k[order]
    w, t = poses["walk_id"].to_numpy()[k], poses["t_s"].to_numpy()[k] + 0.01
    b = np.char.mod("%012x", np.arange(n) % distinct)
    rows = np.char.add(np.char.add(np.char.add(w.astype(str), ","), np.char.mod("%.3f", t)), ",")
    rows = np.char.add(np.char.add(rows, b), ",-60.0")
    body = "\n".join(pd.unique(rows))  # one reading per (walk, time, BSSID)
    (inp / "wifi.csv").write_text("walk_id,t_s,bssid,rssi_dbm\n" + body + "\n")
    case.description.append(f"{n:,} readings of {distinct:,} BSSIDs")
    case.argv = ["ingest", str(inp), "-w", str(root / "ws"), "-q"]
    case.then = _chain(root / "ws", 2) if n <= 100_000 else []
    return case


# ---------------------------------------------------------------------------------------------- floor_info.json
INFO_VALUES = ["1e400", "-5", "0", "1e308", "1e7", "2000.5", "1e-300", '"x"', "true", "null", "NaN", "Infinity", "[]",
               "{}", "150", "0.5"]


def floor_info(kind: str, seed: int, base: Path, root: Path, rng: np.random.Generator) -> Case:
    """An MS ILC floor folder whose floor_info.json (or geojson_map.json) is hostile."""
    shutil.copytree(base / "ilcfloor", root / "in")
    floor = root / "in" / "F1"
    case = Case(kind, seed, [], root, creates=root / "ws")
    r = rng.random()
    if r < 0.6:
        h, w = str(_pick(rng, INFO_VALUES)), str(_pick(rng, INFO_VALUES))
        (floor / "floor_info.json").write_text(f'{{"map_info": {{"height": {h}, "width": {w}}}}}')
        case.description.append(f"floor_info height {h} width {w}")
    elif r < 0.75:
        text = str(_pick(rng, ["", "{", "[]", '{"map_info": 5}', '{"map_info": {"width": 5}}', "[" * 100_000,
                               "[" * 5000 + "]" * 5000, '{"map_info": {"height": 10, "width": 10, "x": ' + "[" * 900
                               + "]" * 900 + "}}"]))
        (floor / "floor_info.json").write_text(text)
        case.description.append(f"floor_info {text[:30]!r}")
    else:
        g = floor / "geojson_map.json"
        v = str(_pick(rng, ["NaN", "1e400", "1e308", "-1e308", "181", "1e30"]))
        g.write_text(g.read_text().replace("116.0012", v, 1))
        case.description.append(f"geojson_map vertex {v}")
    case.argv = ["ingest", str(root / "in"), "-w", str(root / "ws"), "-q"]
    case.then = _chain(root / "ws", 2)
    return case


# ---------------------------------------------------------------------------------------------- build --venues
def venues(kind: str, seed: int, base: Path, root: Path, rng: np.random.Generator) -> Case:
    """A venues file for `build --venues` (serial), mutated: unknown keys, bad names, missing or outside inputs,
    unknown formats, hostile configs and plans, duplicate venues, broken TOML."""
    shutil.copytree(base / "schema", root / "schema")
    (root / "ilc").mkdir()
    shutil.copy(FIXTURES / "msft_ilc" / "tiny_trace.txt", root / "ilc" / "trace.txt")
    text = (base / "venues.toml").read_text()
    op = str(_pick(rng, ["unknown_key", "name", "inputs_missing", "inputs_outside", "format", "config",
                         "floorplan", "duplicate", "toml", "empty", "extreme_input", "valid"]))
    if op == "unknown_key":
        text += 'bogus = 1\n'
    elif op == "name":
        bad = str(_pick(rng, ["../x", ".hidden", "a" * 200, "", "a/b", "con"]))
        text = text.replace('name = "v1"', f"name = {json.dumps(bad)}")
    elif op == "inputs_missing":
        text = text.replace('inputs = ["schema"]', 'inputs = ["nowhere"]')
    elif op == "inputs_outside":  # not input files: a device, a folder of other files (inside the case: the
        # error must name a file of the case)
        (root / "other").mkdir()
        (root / "other" / "notes.conf").write_text("[x]\ny = 1\n")
        (root / "other" / "image.png").write_bytes(b"\x89PNG\r\n")
        where = str(_pick(rng, [str(root / "other"), "/dev/null"]))
        text = text.replace('inputs = ["schema"]', f"inputs = [{json.dumps(where)}]")
    elif op == "format":
        text = text.replace('format = "msft-ilc"', 'format = "bogus"')
    elif op == "config":
        (root / "c.toml").write_text(str(_pick(rng, ["[optimize]\nbogus = 1\n", "[map]\ncell_size_m = 0.001\n",
                                                     "deep = " + "[" * 5000 + "]" * 5000 + "\n",
                                                     "[map]\ncell_size_m = 4.0\n"])))
        text += 'config = "c.toml"\n'
    elif op == "floorplan":
        plans = ['{"type": "FeatureCollection", "features": [NaN]}', "[" * 100_000,
                 '{"type": "FeatureCollection", "frame": "local_m", "features": [], '
                 '"image": {"file": "/etc/hostname"}}']
        (root / "p.geojson").write_text(str(_pick(rng, plans)))
        text = text.replace('inputs = ["schema"]', 'inputs = ["schema"]\nfloorplan = "p.geojson"')
    elif op == "duplicate":
        text = text.replace('name = "v2"', 'name = "v1"')
    elif op == "toml":
        text = text[: int(rng.integers(len(text)))] + "\x00[[["
    elif op == "empty":
        text = ""
    elif op == "extreme_input":
        df = pd.read_csv(root / "schema" / "poses.csv", dtype=str, keep_default_na=False)
        df.loc[int(rng.integers(len(df))), "x_m"] = str(_pick(rng, EXTREMES[:6]))
        df.to_csv(root / "schema" / "poses.csv", index=False)
    (root / "venues.toml").write_text(text)
    case = Case(kind, seed, [], root)
    case.description.append(f"venues: {op}")
    case.argv = ["build", "--venues", str(root / "venues.toml"), "-o", str(root / "out"), "--scheduler", "serial",
                 *(["-q"] if rng.random() < 0.5 else [])]
    return case


# ---------------------------------------------------------------------------------------------- outputs
def outputs(kind: str, seed: int, base: Path, root: Path, rng: np.random.Generator) -> Case:
    """Outputs aimed into a workspace's own files (never written, even with --force), or where they belong."""
    ws = root / "ws"
    shutil.copytree(base / "wsmap", ws)
    (root / "q").mkdir()
    shutil.copy(base / "schema" / "wifi.csv", root / "q" / "wifi.csv")
    target = str(_pick(rng, ["map/radiomap.parquet", "data/wifi.parquet", "optimize/report.json", "map/new.csv",
                             "manifest.json", "data/stage.json", "report.html", "view.rrd", "map", "report/x.csv",
                             "../out.csv", "../.ws.lock", "optimize/tum/walks.csv", "building/x.json"]))
    out = ws / target
    cmd = str(_pick(rng, ["localize", "report", "view"]))
    if cmd == "localize":
        if target == "../.ws.lock":  # localize writes .csv/.parquet/.geojson only: another of the workspace's files
            out = ws / "map" / "radiomap.parquet"
        if not out.suffix or out.suffix not in (".csv", ".parquet", ".geojson"):
            out = out.with_name(out.name + ".csv")
        argv = ["localize", str(root / "q"), "-w", str(ws), "-o", str(out)]
    elif cmd == "report":
        argv = ["report", "-w", str(ws), "--out", str(out)]
    else:
        argv = ["view", "-w", str(ws), "--save", str(out)]
    case = Case(kind, seed, [*argv, *(["--force"] if rng.random() < 0.7 else []), "-q"], root)
    inside = out.resolve().parent == ws.resolve() and out.name in ("report.html", "view.rrd") or \
        not str(out.resolve()).startswith(str(ws.resolve()))
    case.unchanged = None if inside else ws
    case.description.append(f"{cmd} -> {target}")
    return case


# ---------------------------------------------------------------------------------------------- planted links
def links(kind: str, seed: int, base: Path, root: Path, rng: np.random.Generator) -> Case:
    """A symbolic link planted in or beside a workspace (its lock file, a stage directory, a backup a kill
    would leave, the report, the build state, the marker) pointing at a victim file or folder, then a
    command that writes the workspace: the victim never changes."""
    ws = root / "ws"
    shutil.copytree(base / "wsmap", ws)
    victim_dir = root / "victim"
    victim_dir.mkdir()
    (victim_dir / "precious.txt").write_text("precious")
    victim = root / "victim.txt"
    victim.write_text("precious")
    spot = str(_pick(rng, [".ws.lock", "map", "optimize", "data", ".map.old-1", ".map.new-1", ".ws.old-1",
                           "report.html", "report", "build_state.json", "view.rrd", "building"]))
    link = root / spot if spot.startswith(".ws.") else ws / spot
    if link.is_dir() and not link.is_symlink():
        shutil.rmtree(link)
    elif link.exists():
        link.unlink()
    to_dir = spot in ("map", "optimize", "data", ".map.old-1", ".map.new-1", ".ws.old-1", "report", "building")
    link.symlink_to(victim_dir if to_dir else victim, target_is_directory=to_dir)
    cmd = _pick(rng, [["optimize", "-w", str(ws), "--force"], ["export-map", "-w", str(ws), "--force"],
                      ["report", "-w", str(ws), "--force"], ["view", "-w", str(ws), "--save", str(ws / "view.rrd"),
                                                             "--force"],
                      ["ingest", str(base / "schema"), "-w", str(ws), "--force"],
                      ["build", str(base / "schema"), "-w", str(ws), "--force"]])
    case = Case(kind, seed, [*cmd, "-q"], root, victims=[victim, victim_dir / "precious.txt"], planted=[link])
    case.description.append(f"link {spot} -> victim, then {cmd[0]}")
    return case


KIND_MAKERS = {"extreme": extreme, "plan": plan, "gzip_bomb": gzip_bomb, "keys": keys, "floor_info": floor_info,
               "venues": venues, "outputs": outputs, "links": links}

