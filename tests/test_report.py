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
    errs = [float(c) for c in re.findall(r'<td class="num">([0-9.]+)</td></tr>', block)]
    assert len(errs) == n_walks and max(errs) < 5.0  # tiny venue, every walk linked: metres, not tens


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
