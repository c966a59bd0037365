"""A CSV file reads the same whether or not pandas' skipinitialspace runs: it runs only on files with a field
that starts with a space or a tab (after a comma or at a line start), found across chunk boundaries too."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from rmbuild.io.formats import rmbuild_schema
from rmbuild.io.formats.rmbuild_schema import SCHEMAS, _has_initial_space, read_located

ROWS = ["w1,0.5,aa:bb:cc:00:00:01,-60,2412,my net", "w1,0.5,aa:bb:cc:00:00:02,-71.5,5180,",
        "w2,1.0,aa:bb:cc:00:00:01,-55,2412,NA"]


def _write(p: Path, sep: str, lead: str = "") -> Path:
    head = sep.join(["walk_id", "t_s", "bssid", "rssi_dbm", "freq_mhz", "ssid"])
    p.write_text("\n".join([head] + [lead + sep.join(r.split(",")) for r in ROWS]) + "\n")
    return p


@pytest.mark.parametrize(("sep", "lead", "spaced"), [(",", "", False), (", ", "", True), (",\t", "", True),
                                                     (",", " ", True)])
def test_read_equals_the_always_skipping_read(tmp_path, monkeypatch, sep, lead, spaced):
    req, opt = SCHEMAS["wifi"]
    f = _write(tmp_path / "wifi.csv", sep, lead)
    assert _has_initial_space(f) is spaced
    got = read_located(f, req, opt).df
    monkeypatch.setattr(rmbuild_schema, "_has_initial_space", lambda p: True)  # the reading before the check
    pd.testing.assert_frame_equal(got, read_located(f, req, opt).df)
    if sep == ", ":
        assert got.columns.tolist()[1] == "t_s" and got["ssid"].tolist() == ["my net", "", "NA"]
    monkeypatch.setattr(rmbuild_schema, "_SCAN_CHUNK", 3)  # a comma and its space in different chunks
    assert _has_initial_space(f) is spaced
