"""Motion-capture readers and writers: round trips, units, gaps, bad files, real AnimFace data."""

from __future__ import annotations

import numpy as np
import pytest

from tests.conftest import data_path
from wface.io.mocap import MocapTake, read_c3d, read_csv, read_mocap, read_trc, write_mocap

_ROUND = 1e-9  # metres; text formats store repr(float), C3D stores float32 (see below)


def _take(frames=7, markers=4, gap=True, seed=0) -> MocapTake:
    rng = np.random.default_rng(seed)
    p = rng.normal(scale=0.05, size=(frames, markers, 3))
    if gap:
        p[2, 1] = np.nan
        p[5, 3] = np.nan
    return MocapTake(p, [f"M{i}" for i in range(markers)], 60.0, "mem")


def _refused(path, text: str, match: str) -> None:
    """A CSV holding ``text`` is refused with a message matching ``match``."""
    path.write_text(text)
    with pytest.raises(ValueError, match=match):
        read_csv(path)


@pytest.mark.parametrize("suffix", [".c3d", ".trc", ".csv"])
@pytest.mark.parametrize("units", ["mm", "cm", "m"])
def test_round_trip(tmp_path, suffix, units):
    take = _take()
    path = tmp_path / f"t{suffix}"
    write_mocap(take, path, units=units)
    back = read_mocap(path)
    assert back.marker_names == take.marker_names
    assert back.rate_hz == pytest.approx(60.0)
    assert np.array_equal(np.isnan(back.positions_m), np.isnan(take.positions_m))
    # C3D stores float32 in the file's units: relative error ~6e-8 of the value.
    tol = 1e-7 * 0.2 if suffix == ".c3d" else _ROUND
    np.testing.assert_allclose(back.positions_m, take.positions_m, atol=tol, rtol=0)


def test_csv_units_and_rate_from_time(tmp_path):
    path = tmp_path / "a.csv"
    path.write_text("time_s,A_x,A_y,A_z\n0.0,1,2,3\n0.01,4,,6\n0.02,7,8,9\n")
    take = read_csv(path, units="cm")
    assert take.rate_hz == pytest.approx(100.0)
    np.testing.assert_allclose(take.positions_m[0, 0], [0.01, 0.02, 0.03])
    assert np.isnan(take.positions_m[1, 0]).all()  # a gap in any coordinate voids the point


def test_csv_rate_from_rounded_times_byte_order_mark_and_bad_times(tmp_path):
    """Times written to 0.01 s or 1 ms gave 50 and 58.8 Hz for a 60 Hz take (the median step); a UTF-8
    byte-order mark (Excel's "CSV UTF-8") made the header unreadable; times that stop increasing divided by 0."""
    take = _take(frames=20)
    for decimals in (2, 3, 6):
        rows = [f"{f},{f / 60:.{decimals}f}," + ",".join(f"{v:.6f}" for v in take.positions_m[f].ravel() * 1e3)
                for f in range(20)]  # fmt: skip
        head = "frame,time_s," + ",".join(f"{n}_{a}" for n in take.marker_names for a in "xyz")
        path = tmp_path / f"t{decimals}.csv"
        path.write_text("# units: mm\n" + head + "\n" + "\n".join(rows) + "\n")
        assert read_csv(path).rate_hz == 60.0
    path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())
    back = read_csv(path)
    assert back.marker_names == take.marker_names and back.rate_hz == 60.0
    trc = tmp_path / "bom.trc"
    write_mocap(take, trc)
    trc.write_bytes(b"\xef\xbb\xbf" + trc.read_bytes())
    assert read_trc(trc).n_frames == 20
    flat = "# units: mm\nframe,time_s,A_x,A_y,A_z\n0,0.0,1,2,3\n1,0.1,1,2,3\n2,0.1,1,2,3\n"
    _refused(tmp_path / "flat.csv", flat, "flat.csv: CSV column 'time_s' does not increase at line 5.*# rate_hz: 60")
    word = "# units: mm\n# rate_hz: sixty\nA_x,A_y,A_z\n1,2,3\n"
    _refused(tmp_path / "word.csv", word, "word.csv: '# rate_hz: sixty' is not a number")


def test_frames_slice():
    take = _take(frames=10)
    sub = take.frames(2, 9, 3)
    assert sub.n_frames == 3 and sub.first_frame == 2 and sub.rate_hz == pytest.approx(20.0)
    np.testing.assert_array_equal(sub.positions_m, take.positions_m[2:9:3])
    np.testing.assert_allclose(sub.times_s, [2 / 60, 5 / 60, 8 / 60], rtol=1e-12)
    with pytest.raises(ValueError, match="empty"):
        take.frames(20, 30)


def test_bad_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.c3d"):
        read_mocap(tmp_path / "nope.c3d")
    bad = tmp_path / "bad.c3d"
    bad.write_bytes(b"\x02P" + b"\x00" * 30)
    with pytest.raises(ValueError, match="bad.c3d"):
        read_c3d(bad)
    # Truncated C3D: the first half of a valid file.
    good = tmp_path / "good.c3d"
    write_mocap(_take(frames=50, markers=6), good)
    trunc = tmp_path / "trunc.c3d"
    trunc.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(ValueError, match="trunc.c3d"):
        read_c3d(trunc)
    _refused(tmp_path / "cols.csv", "time_s,A_x,A_y\n0,1,2\n", "cols.csv.*multiple of 3")
    ragged = "# rate_hz: 60\nA_x,A_y,A_z\n1,2,3\n1,2\n"
    _refused(tmp_path / "ragged.csv", ragged, "ragged.csv: CSV line 4 has 2 columns")  # the file's own line number
    _refused(tmp_path / "nomark.csv", "frame,time_s\n0,0\n", "no marker columns")
    trc = tmp_path / "t.trc"
    write_mocap(_take(frames=8), trc)
    text = trc.read_text().splitlines()
    (tmp_path / "short.trc").write_text("\n".join(text[:-2]) + "\n")
    with pytest.raises(ValueError, match="short.trc.*truncated"):
        read_trc(tmp_path / "short.trc")
    _refused(
        tmp_path / "u.csv",
        "# units: furlong\n# rate_hz: 60\nA_x,A_y,A_z\n1,2,3\n",
        "u.csv: unknown length units 'furlong'",
    )
    with pytest.raises(ValueError, match="unknown motion-capture format"):
        read_mocap(tmp_path / "x.bvh")


def test_c3d_invalid_points_become_nan(tmp_path):
    import ezc3d

    take = _take(gap=False)
    path = tmp_path / "r.c3d"
    write_mocap(take, path)
    c = ezc3d.c3d(str(path))
    pts = c["data"]["points"]
    res = c["data"]["meta_points"]["residuals"]
    res[0, 0, 3] = -1.0  # residual < 0: invalid
    pts[:3, 2, 4] = 0.0  # exact zeros: invalid
    c["data"]["points"] = pts
    c["data"]["meta_points"]["residuals"] = res
    c.write(str(path))
    back = read_c3d(path)
    assert np.isnan(back.positions_m[3, 0]).all() and np.isnan(back.positions_m[4, 2]).all()
    assert np.isfinite(back.positions_m).all(axis=2).sum() == take.n_frames * take.n_markers - 2


def test_animface_jaw_take():
    take = read_c3d(data_path("animface", "JawMoCap.c3d"))
    assert take.positions_m.shape == (1590, 41, 3)
    assert take.rate_hz == 60.0 and "Rcheek_up" in take.marker_names and "Mouth_Lend" in take.marker_names
    assert np.isfinite(take.positions_m).all()
    # millimetres -> metres: a human face spans roughly 0.1-0.2 m.
    span = np.ptp(take.positions_m[0], axis=0)
    assert 0.08 < span.max() < 0.3
