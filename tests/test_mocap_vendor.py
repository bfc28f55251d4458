"""Marker files from capture systems: Vicon Nexus and OptiTrack Motive CSV, subject prefixes, units refused."""

from __future__ import annotations

import numpy as np
import pytest

from wface.io.mocap import MocapTake, read_mocap, strip_subject_prefix, write_mocap

_TOL_M = 1e-12  # values are written with repr(), so they come back to float64 round-off (x 1e-3 for mm)


def _take(n_frames=5, names=("Chin", "Nose", "Mouth_L")) -> MocapTake:
    rng = np.random.default_rng(3)
    p = rng.normal(0.0, 0.05, (n_frames, len(names), 3))
    p[2, 1] = np.nan  # a gap
    return MocapTake(p, list(names), 120.0)


def _vicon_text(take: MocapTake, unit="mm", scale=1e3, subject="Face") -> str:
    names = "".join(f",{subject}:{n},," for n in take.marker_names)
    lines = ["Devices", "1000", ",,Force", "Frame,Sub Frame,Fx", ",,N", "1,0,0.5", "", "Trajectories"]
    lines += [f"{take.rate_hz:g}", f",{names}", "Frame,Sub Frame," + ",".join("X,Y,Z" for _ in take.marker_names)]
    lines += [",," + ",".join(f"{unit},{unit},{unit}" for _ in take.marker_names)]
    for f, row in enumerate(take.positions_m * scale):
        cells = ["" if not np.isfinite(v) else repr(float(v)) for v in row.ravel()]
        lines.append(f"{f + 1},0," + ",".join(cells))
    lines += ["", "Model Outputs", "100", ",,Face:Angle", "Frame,Sub Frame,X", ",,deg", "1,0,3.0"]
    return "\r\n".join(lines) + "\r\n"


def _motive_text(take: MocapTake, units="Millimeters", scale=1e3, subject="Face") -> str:
    cols = [f"{subject}:{n}" for n in take.marker_names for _ in range(3)]
    head = (
        f"Format Version,1.23,Take Name,t,Capture Frame Rate,{take.rate_hz:f},Export Frame Rate,{take.rate_hz:f},"
        f"Total Frames in Take,{take.n_frames},Rotation Type,Quaternion"
        + (f",Length Units,{units}" if units else "")
        + ",Coordinate Space,Global"
    )
    n = len(cols)
    lines = [
        head,
        "",
        ",Type," + ",".join(["Marker"] * n) + ",Marker,Marker,Marker,Rigid Body,Rigid Body,Rigid Body",
        ",Name," + ",".join(cols) + ",Unlabeled 1003,Unlabeled 1003,Unlabeled 1003,Head,Head,Head",
        ",ID," + ",".join(["1"] * (n + 6)),
        ",Position," + ",".join(["Position"] * (n + 6)),
        "Frame,Time (Seconds)," + ",".join(["X,Y,Z"] * (len(take.marker_names) + 2)),
    ]
    for f, row in enumerate(take.positions_m * scale):
        cells = ["" if not np.isfinite(v) else repr(float(v)) for v in row.ravel()]
        lines.append(f"{f},{f / take.rate_hz:.6f}," + ",".join(cells) + ",9,9,9,1,1,1")
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(("unit", "scale"), [("mm", 1e3), ("cm", 1e2)])
def test_vicon_nexus_trajectories(tmp_path, unit, scale):
    take = _take()
    path = tmp_path / "vicon.csv"
    path.write_text(_vicon_text(take, unit, scale))
    got = read_mocap(path)
    assert got.marker_names == take.marker_names  # "Face:" stripped
    assert any("stripped the subject prefix 'Face:'" in n for n in got.meta["notices"])
    assert got.rate_hz == 120.0 and got.meta["format"] == "vicon-nexus-csv"
    np.testing.assert_allclose(got.positions_m, take.positions_m, atol=_TOL_M, equal_nan=True)
    assert np.isnan(got.positions_m[2, 1]).all()


def test_optitrack_motive(tmp_path):
    take = _take()
    path = tmp_path / "motive.csv"
    path.write_text(_motive_text(take))
    got = read_mocap(path)
    assert got.marker_names == take.marker_names
    assert got.meta["skipped"] == 2  # the unlabelled marker and the rigid body
    assert got.rate_hz == 120.0 and got.meta["units"] == "Millimeters"
    np.testing.assert_allclose(got.positions_m, take.positions_m, atol=_TOL_M, equal_nan=True)
    path.write_text(_motive_text(take, units="Meters", scale=1.0))
    np.testing.assert_allclose(read_mocap(path).positions_m, take.positions_m, atol=_TOL_M, equal_nan=True)


def test_units_are_read_or_refused(tmp_path):
    take = _take()
    csv = tmp_path / "plain.csv"
    write_mocap(take, csv, units="cm")
    text = csv.read_text()
    assert text.startswith("# units: cm")
    no_units = tmp_path / "no_units.csv"
    no_units.write_text(text.split("\n", 1)[1])  # drop the units line
    with pytest.raises(ValueError, match=r"no_units.csv: CSV gives no length units: add a line '# units: mm'"):
        read_mocap(no_units)
    motive = tmp_path / "motive.csv"
    motive.write_text(_motive_text(take, units=None))
    with pytest.raises(ValueError, match="has no 'Length Units'"):
        read_mocap(motive)
    vicon = tmp_path / "vicon.csv"
    vicon.write_text(_vicon_text(take, unit="furlong"))
    with pytest.raises(ValueError, match="unknown length units 'furlong'"):
        read_mocap(vicon)


def test_an_unknown_layout_names_the_formats_read(tmp_path):
    path = tmp_path / "odd.csv"
    path.write_text("time,a,b\n0,1,2\n")
    with pytest.raises(ValueError, match=r"odd.csv: .*Read: C3D \(.c3d\), TRC \(.trc\), and CSV .*Vicon Nexus.*Motive"):
        read_mocap(path)


@pytest.mark.parametrize("suffix", [".c3d", ".trc"])
def test_subject_prefixes_in_c3d_and_trc(tmp_path, suffix):
    pytest.importorskip("ezc3d")
    take = _take(names=("Face:Chin", "Face:Nose"))
    path = tmp_path / f"p{suffix}"
    write_mocap(take, path)
    got = read_mocap(path)
    assert got.marker_names == ["Chin", "Nose"] and got.meta["notices"]


def test_strip_subject_prefix_keeps_what_it_must():
    assert strip_subject_prefix(["A:x", "A:y", "z"]) == (
        ["x", "y", "z"],
        "stripped the subject prefix 'A:' from 2 marker names",
    )
    names, note = strip_subject_prefix(["A:x", "B:x"])
    assert names == ["A:x", "B:x"] and "2 subjects (A, B)" in note
    names, note = strip_subject_prefix(["A:x", "x"])
    assert names == ["A:x", "x"] and "would repeat" in note
    assert strip_subject_prefix(["x", "y"]) == (["x", "y"], None)
