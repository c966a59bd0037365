"""Floors stacked by their transitions (rmbuild/stages/building/frames.py): the frames' transform from the places
where walks changed floor, chained from the reference floor."""

from __future__ import annotations

import numpy as np
import pytest

from rmbuild.stages.building import frames as ff


def _rot(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def test_floors_are_chained_onto_the_reference(monkeypatch) -> None:
    """F2's frame is F1's turned 30° and shifted; F3 is tied to F2 at one place only (translation alone)."""
    rng = np.random.default_rng(0)
    in_f1 = np.array([[0.0, 0.0], [20.0, 5.0], [3.0, 15.0]])
    r12, t12 = _rot(30.0), np.array([4.0, -2.0])  # F1 = r12 @ F2 + t12
    in_f2 = (in_f1 - t12) @ r12  # the same places in F2's frame
    noise = rng.normal(0.0, 0.05, in_f2.shape)
    places = {("F1", "F2"): (in_f1, in_f2 + noise), ("F2", "F3"): (in_f2[:1], in_f2[:1] + np.array([1.0, 1.0]))}
    monkeypatch.setattr(ff, "_transition_places", lambda ws: places)
    monkeypatch.setattr(ff, "building_floors", lambda ws: {"F1": None, "F2": None, "F3": None})
    out = ff.floor_frames("ws")
    assert out is not None and out["reference"] == "F1"
    f2, f3 = out["floors"]["F2"], out["floors"]["F3"]
    assert f2["rotation_deg"] == pytest.approx(30.0, abs=0.5) and f2["transitions"] == 3
    assert (f2["dx_m"], f2["dy_m"]) == pytest.approx((4.0, -2.0), abs=0.2) and f2["rms_m"] < 0.2
    assert f2["rotation_known"] and not f3["rotation_known"]  # one place: F2 -> F3 not turned
    assert f3["rotation_deg"] == pytest.approx(30.0, abs=0.5)
    p3 = in_f2[0] + np.array([1.0, 1.0])  # the place in F3's frame maps onto where it is in F1's
    est = _rot(f3["rotation_deg"]) @ p3 + np.array([f3["dx_m"], f3["dy_m"]])
    assert est == pytest.approx(in_f1[0], abs=0.3)


def test_no_transitions_no_frames(monkeypatch) -> None:
    monkeypatch.setattr(ff, "_transition_places", lambda ws: {})
    assert ff.floor_frames("ws") is None
