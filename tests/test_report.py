"""`rmbuild report`: a self-contained page whose images all decode, and that headless Chromium renders."""

from __future__ import annotations

import base64
import io
import re
import shutil
import subprocess
from pathlib import Path

import pytest
from cli_util import run_cli
from PIL import Image
from test_viz_util import build_workspace

from rmbuild.io.workspace import Workspace

CHROMIUM = Path("/usr/bin/chromium")  # Debian's `chromium` package (apt-get install -y chromium)
IMG_RE = re.compile(r'<img src="data:image/png;base64,([A-Za-z0-9+/=]+)"')


@pytest.fixture(scope="module")
def ws_report(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_workspace(tmp_path_factory.mktemp("report"), ("optimize", "export-map", "evaluate"))


def _decode_all(page: str) -> list[Image.Image]:
    out = []
    for b64 in IMG_RE.findall(page):
        im = Image.open(io.BytesIO(base64.b64decode(b64)))
        assert im.format == "PNG"
        im.load()
        out.append(im)
    return out


def test_report_is_self_contained(ws_report: Path, tmp_path: Path, capsys) -> None:
    ws = tmp_path / "ws"
    shutil.copytree(ws_report, ws)
    r = run_cli(capsys, "report", "-w", ws)
    assert r.code == 0, r.err
    page = (ws / "report.html").read_text()
    assert page.count("<img") == len(IMG_RE.findall(page)) >= 2  # every image is an embedded PNG
    images = _decode_all(page)
    assert all(im.width > 100 and im.height > 100 for im in images)
    pngs = sorted(p.name for p in (ws / "report").glob("*.png"))
    assert "walks.png" in pngs and "rf.png" in pngs and len(pngs) == len(images)
    assert "RF model. How the RSS distance" in page  # the data set's own RF model, plotted
    assert "src=\"http" not in page and "href=\"http" not in page  # nothing fetched from outside
    for needle in ("Key figures", "Configuration used", "[optimize]", "optimised ATE rmse"):
        assert needle in page
    assert "dashed grey: ground truth" in page  # the synthetic venue has true paths: the caption says so
    # the per-walk table: one row per walk, the real error against the true paths beside the predicted one
    block = page[page.index("<details><summary>Per walk"):]
    block = block[:block.index("</details>")]
    n_walks = len(Workspace.open(ws).read_table("data.walks"))
    assert f"Per walk: {n_walks} walks" in block and "error vs truth (m)" in block
    assert block.count("<tr>") == n_walks + 1
    errs = [float(c) for c in re.findall(r'<td class="num">([0-9.]+)</td><td>[^<]*</td></tr>', block)]
    assert len(errs) == n_walks and max(errs) < 5.0  # tiny venue, every walk linked: metres, not tens
    assert block.count("<td>placed ") + block.count("<td>reference walk:") == n_walks  # why, per walk


def test_captions_name_only_what_is_drawn(tmp_path: Path, capsys) -> None:
    from conftest import make_input_tables, write_tables

    assert run_cli(capsys, "ingest", write_tables(make_input_tables(n_walks=3, n_steps=40), tmp_path / "in"),
                   "-w", tmp_path / "ws", "-q").code == 0
    assert run_cli(capsys, "report", "-w", tmp_path / "ws").code == 0
    page = (tmp_path / "ws" / "report.html").read_text()
    assert "no true paths to draw" in page and "ground truth;" not in page and "floor plan" not in page


def test_report_ingest_only_and_out_option(tmp_path: Path, capsys) -> None:
    ws = build_workspace(tmp_path, stages=())
    out = tmp_path / "elsewhere" / "r.html"
    r = run_cli(capsys, "report", "-w", ws, "--out", out)
    assert r.code == 0, r.err
    page = out.read_text()
    assert len(_decode_all(page)) == 1  # the raw walks only
    assert "optimize has not run" in page and "export-map has not run" in page


def _chromium(*args: str, timeout: float = 45) -> subprocess.CompletedProcess:
    cmd = [str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
           "--disable-dev-shm-usage", "--hide-scrollbars", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)


@pytest.mark.skipif(not CHROMIUM.exists(), reason="needs Debian's chromium (/usr/bin/chromium)")
def test_report_renders_in_headless_chromium(ws_report: Path, tmp_path: Path, capsys) -> None:
    ws = tmp_path / "ws"
    shutil.copytree(ws_report, ws)
    assert run_cli(capsys, "report", "-w", ws).code == 0
    page = (ws / "report.html").read_text()
    n_img = page.count("<img")
    # a copy of the page that writes, once loaded, how many images decoded (naturalWidth > 0) into the DOM
    probe = ("<script>window.addEventListener('load',()=>{const im=[...document.images];"
             "const ok=im.filter(i=>i.complete&&i.naturalWidth>0).length;"
             "const p=document.createElement('pre');p.id='probe';p.textContent='IMAGES '+ok+'/'+im.length;"
             "document.body.appendChild(p);});</script>")
    probe_page = tmp_path / "probe.html"
    probe_page.write_text(page.replace("</body>", probe + "</body>"))
    dom = _chromium("--virtual-time-budget=10000", "--dump-dom", probe_page.as_uri())
    m = re.search(r"IMAGES (\d+)/(\d+)", dom.stdout)
    assert m, f"no probe output; chromium said: {dom.stderr[-800:]}"
    assert int(m.group(2)) == n_img and int(m.group(1)) == n_img
    shot = tmp_path / "report.png"
    _chromium("--window-size=1200,2600", f"--screenshot={shot}", (ws / "report.html").as_uri())
    im = Image.open(shot).convert("L")
    lo, hi = im.getextrema()
    assert hi - lo > 100  # not blank


# ------------------------------------------------------------------ a report that tells the truth at a glance
def _panels(ws_path: Path, unlink: tuple[str, ...] = ()):
    from rmbuild.viz.report_walks import walk_panels

    ws = Workspace.open(ws_path)
    ds = ws.read_dataset()
    walks = ws.read_table("optimize.walks")
    walks.loc[walks["walk_id"].astype(str).isin(unlink), "linked"] = False
    gauge = ws.read_report("optimize")["gauge"]
    return ws, ds, walks, walk_panels(ds, ws.read_table("optimize.poses"), walks, gauge, ds.fixes)


def test_before_and_after_are_drawn_under_the_fits_of_the_numbers(ws_report: Path) -> None:
    """Each panel is the walks under optimize's own single rigid fit (all walks before, the linked walks
    after), not each walk fitted on its own: the drawn positions give optimize's ATE figures exactly."""
    import numpy as np

    ws, ds, _, wp = _panels(ws_report)
    rep = ws.read_report("optimize")
    truth = ds.truth_poses[["x_m", "y_m"]].to_numpy(float)
    for (title, poses), key in zip(wp.panels, ("raw", "optimized"), strict=True):
        d = np.hypot(*(poses[["x_m", "y_m"]].to_numpy(float) - truth).T)
        assert d.mean() == pytest.approx(rep[key]["ate_m"]["mean"], rel=1e-6), title
    assert "one rigid fit of all walks" in wp.panels[0][0] and wp.building
    # a walk fitted on its own would look far better than the numbers say: the raw panel must not
    assert rep["raw"]["ate_m"]["mean"] > 5 * rep["optimized"]["ate_m"]["mean"]


def test_unlinked_walks_are_drawn_apart_and_never_in_the_legend_as_placed(ws_report: Path) -> None:
    from rmbuild.viz.report_walks import walk_caption, walk_style

    ws, ds, walks, wp = _panels(ws_report, unlink=("w001",))
    before, after = (p for _, p in wp.panels)
    assert "w001" in set(before["walk_id"]) and "w001" not in set(after["walk_id"])
    style = walk_style([str(w) for w in ds.walk_ids()], walks)
    labels = [label for label, _ in style.legend]
    assert "w001" not in style.rgb and "w001" not in labels and "w000" in labels
    assert any(label.startswith("grey: not linked") and "w001" in label for label in labels)
    assert "could not link (w001)" in walk_caption(wp, style, None, True, False, False)


def test_walk_colours_stay_distinct_past_twenty_walks() -> None:
    import matplotlib
    import pandas as pd

    from rmbuild.viz.colors import WALK_VALUE_CMAP
    from rmbuild.viz.report_walks import walk_style

    ids = [f"w{i:03d}" for i in range(25)]
    walks = pd.DataFrame({"walk_id": ids, "linked": [i != 3 for i in range(25)],
                          "predicted_error_m": [i / 2 for i in range(25)]})
    style = walk_style(ids, walks)
    assert style.colorbar is not None and style.colorbar[1:3] == (0.0, 12.0)
    top = matplotlib.colormaps[WALK_VALUE_CMAP](1.0)[:3]
    assert style.rgb["w024"] == pytest.approx(top) and "w003" not in style.rgb
    assert [label for label, _ in style.legend] == ["grey: not linked, not in the map (w003)"]
    few = walk_style(ids[:20], walks.iloc[:20])
    assert few.colorbar is None and len(set(few.rgb.values())) == len(few.rgb) == 19
    walks["predicted_error_m"] = [float(i) for i in range(24)] + [900.0]  # the scale stops at 16 m
    capped = walk_style(ids, walks)
    assert capped.colorbar is not None and capped.colorbar[1:3] == (0.0, 16.0) and "16 m or more" in capped.colorbar[3]
    assert capped.rgb["w024"] == pytest.approx(top) and capped.rgb["w020"] == pytest.approx(top)
    assert capped.rgb["w004"] != capped.rgb["w008"] != capped.rgb["w012"]


def test_colour_maps_are_colour_blind_safe() -> None:
    """No red-green scale: the error map runs blue -> red; the walk palette opens with Okabe-Ito's colours."""
    import colorsys

    import matplotlib

    from rmbuild.viz.colors import ERROR_CMAP, LINE_COLORS, SEQUENTIAL_CMAP, WALK_PALETTE, WALK_VALUE_CMAP

    lo, hi = matplotlib.colormaps[ERROR_CMAP](0.0), matplotlib.colormaps[ERROR_CMAP](1.0)
    assert lo[2] > lo[0] and hi[0] > hi[2]  # blue at 0, red at the top: never green against red
    for name in (ERROR_CMAP, SEQUENTIAL_CMAP, WALK_VALUE_CMAP):
        assert "Gn" not in name and name not in ("jet", "hsv", "rainbow")
    assert tuple(WALK_PALETTE[0]) == (230, 159, 0) and tuple(WALK_PALETTE[3]) == (0, 114, 178)
    hues = [colorsys.rgb_to_hsv(*matplotlib.colors.to_rgb(c))[0] * 360 for c in LINE_COLORS[:2]]
    assert not any(90 < h < 150 for h in hues)  # the first two lines (near / far) are not green


def test_report_shows_warnings_in_full_and_the_rf_caption_in_words(tmp_path: Path, capsys) -> None:
    import pandas as pd
    from conftest import make_input_tables, write_tables

    tables = make_input_tables(n_walks=3, n_steps=40)
    late = tables["wifi"].iloc[[0]].assign(t_s=10_000.0)  # a reading long after its walk: ingest warns
    tables["wifi"] = pd.concat([tables["wifi"], late], ignore_index=True)
    assert run_cli(capsys, "ingest", write_tables(tables, tmp_path / "in"), "-w", tmp_path / "ws").code == 0
    warning = Workspace.open(tmp_path / "ws").read_report("ingest")["warnings"][0]
    assert run_cli(capsys, "report", "-w", tmp_path / "ws").code == 0
    page = (tmp_path / "ws" / "report.html").read_text()
    section = page[page.index('<h2 id="warnings">'):page.index("<h2>Walks</h2>")]
    assert warning.replace("'", "&#x27;") in section and "values]" not in page


def test_rf_caption_names_the_offsets_in_words() -> None:
    from rmbuild.viz.report import _rf_caption

    text = _rf_caption({"device_offsets_db": {"PBCM10": 0.0, "SM-G": -6.25, "A5": 5.3}})
    assert "SM-G -6.2 dB, A5 +5.3 dB (the other 1 read alike)." in text and "{" not in text
    assert "read alike: no RSS offset removed" in _rf_caption({"device_offsets_db": {"a": 0.0, "b": 0.0}})


def test_heat_maps_show_one_access_point_per_radio() -> None:
    import pandas as pd

    from rmbuild.viz.figures import strongest_aps

    virtual = ["06:74:9c:2b:19:8b", "0a:74:9c:2b:19:8b", "0e:74:9c:2b:19:8b", "00:11:22:33:44:50",
               "00:11:22:33:44:51", "aa:bb:cc:dd:ee:ff", "not-a-mac"]
    cells = pd.DataFrame({"bssid": virtual, "rssi_mean_dbm": [-30.0, -31, -32, -40, -41, -50, -60]})
    assert list(strongest_aps(cells, 6).index) == ["06:74:9c:2b:19:8b", "00:11:22:33:44:50",
                                                   "aa:bb:cc:dd:ee:ff", "not-a-mac"]


def test_coverage_figure_spans_the_whole_plan() -> None:
    import numpy as np
    import pandas as pd

    from rmbuild.viz.figures import coverage_figure

    cells = pd.DataFrame({"ix": [0, 1], "iy": [0, 0], "x_m": [1.0, 3.0], "y_m": [1.0, 1.0], "n_scans": [2, 5]})
    walls = np.array([[-50.0, -20.0, 80.0, -20.0], [80.0, -20.0, 80.0, 60.0]])
    ax = coverage_figure(cells, 2.0, walls).axes[0]
    assert ax.get_xlim()[0] <= -50 and ax.get_xlim()[1] >= 80 and ax.get_ylim()[1] >= 60


def test_report_out_writes_everything_beside_the_page(ws_report: Path, tmp_path: Path, capsys) -> None:
    ws = tmp_path / "ws"
    shutil.copytree(ws_report, ws)
    before = sorted(p.relative_to(ws) for p in ws.rglob("*"))
    out = tmp_path / "elsewhere" / "r.html"
    assert run_cli(capsys, "report", "-w", ws, "--out", out).code == 0
    assert sorted(p.relative_to(ws) for p in ws.rglob("*")) == before  # nothing written into the workspace
    figs = sorted(p.name for p in (tmp_path / "elsewhere" / "r_figures").glob("*.png"))
    assert "walks.png" in figs and "coverage.png" in figs
    r = run_cli(capsys, "report", "-w", ws, "--out", out)
    assert r.code == 2 and "--force" in r.err


def test_walk_table_puts_the_doubtful_linked_walks_first() -> None:
    """Linked walks by predicted error, largest first (one without a figure last of them), then the walks
    left out in their order; every walk once."""
    import pandas as pd

    from rmbuild.viz.walk_table import walk_rows

    walks = pd.DataFrame({"walk_id": ["a", "b", "c", "d", "e", "f"],
                          "linked": [True, False, True, True, False, True],
                          "predicted_error_m": [2.0, float("nan"), 9.5, float("nan"), float("nan"), 4.0],
                          "placement": ["reference", "", "merge", "translation", "", "translation"]})
    _, rows = walk_rows(walks, None)
    assert [r[0] for r in rows] == ["c", "f", "a", "d", "b", "e"]
    assert [r[1] for r in rows] == ["yes"] * 4 + ["no"] * 2
