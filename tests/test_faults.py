"""Fault injection: bad input gets a clear error, nothing is silently wrong, no frame is lost or mixed.

Each class of fault is asserted by exit code and message through ``wface.cli.main`` (or the library
call behind it): kills during frames and during the final writes followed by ``--resume`` (results
identical to an uninterrupted run), frames of another provenance, truncated and corrupted files of
every kind wface reads, impossible capture samples, out-of-range options, models that lack what a
command needs, and the top-level handler's exit codes (2 usage, 1 failure, 130 interrupt, 141
closed pipe).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from wface.cli import main
from wface.files import FileFormatError, atomic_path, load_npz, read_json, save_npz
from wface.takes.store import (
    claim_take_dir,
    frame_path,
    load_take,
    read_frame,
    read_report,
    resume_plan,
    write_frame,
)

ROOT = Path(__file__).resolve().parents[1]
TETS = "1000"  # the smallest built-in face: every test here is about files and messages, not accuracy
FRAMES = "4"
DEMO = ["demo", "--tets", TETS, "--frames", FRAMES, "--no-pictures", "--seed", "2"]


def _cli(args, capsys) -> tuple[int, str]:
    code = main([str(a) for a in args])
    cap = capsys.readouterr()
    return code, cap.out + cap.err


def _controls(out: Path) -> dict:
    return load_npz(out / "controls.npz")


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """An uninterrupted demo take (the results every resumed run must reproduce)."""
    out = tmp_path_factory.mktemp("faults") / "reference"
    assert main([*DEMO, "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def model_path(tmp_path_factory):
    from wface.faces.builtin import build_face
    from wface.model import save_model

    path = tmp_path_factory.mktemp("model") / "face.npz"
    save_model(build_face(int(TETS)), path)
    return path


def _copy(src: Path, dst: Path) -> Path:
    import shutil

    shutil.copytree(src, dst)
    return dst


# ---------------------------------------------------------------------- kills and --resume
def _spawn(args, env_extra=None) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(ROOT), **(env_extra or {}))
    return subprocess.Popen(
        [sys.executable, "-m", "wface", *args], cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )


def _wait_for(pred, proc, timeout_s=300.0) -> None:
    t0 = time.monotonic()
    while not pred():
        if proc.poll() is not None:
            raise AssertionError(f"process ended before the fault: {proc.stderr.read().decode()[-2000:]}")
        if time.monotonic() - t0 > timeout_s:
            proc.kill()
            raise AssertionError("timed out waiting for the fault point")
        time.sleep(0.05)


def test_kill_during_frames_then_resume_is_bit_identical(reference, tmp_path, capsys):
    out = tmp_path / "killed"
    proc = _spawn([*DEMO, "--out", str(out)])
    _wait_for(lambda: len(list((out / "survey").glob("frame_*.npz"))) >= 2, proc)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (out / "controls.npz").exists()
    code, text = _cli([*DEMO, "--out", out, "--resume"], capsys)
    assert code == 0, text
    done = int(re.search(r"resume \(first pass\): reusing (\d) of 4 frames", text).group(1))
    assert done >= 2, text  # the first-pass frames written before the kill
    a, b = _controls(reference), _controls(out)
    np.testing.assert_array_equal(a["activations"], b["activations"])  # bitwise: PARDISO is reproducible
    np.testing.assert_array_equal(a["bones"], b["bones"])


_KILL_AT_REPLACE = """
import os, signal, sys
from pathlib import Path
target = sys.argv[1]
real = os.replace
def replace(src, dst):
    if Path(dst).name == target:
        os.kill(os.getpid(), signal.SIGKILL)  # die with the new file written but not yet renamed
    return real(src, dst)
os.replace = replace
from wface.cli import main
sys.exit(main(sys.argv[2:]))
"""


@pytest.mark.parametrize("victim", ["controls.npz", "report.json"])
def test_kill_during_final_writes_leaves_no_torn_file(reference, tmp_path, capsys, victim):
    out = _copy(reference, tmp_path / "final")
    for name in ("controls.npz", "controls.csv", "report.json"):
        (out / name).unlink()
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    args = [sys.executable, "-c", _KILL_AT_REPLACE, victim, *DEMO, "--out", str(out), "--resume"]
    proc = subprocess.run(args, cwd=ROOT, env=env, capture_output=True, timeout=600)
    assert proc.returncode == -signal.SIGKILL, proc.stderr.decode()[-2000:]
    assert not (out / victim).exists()  # never a 0-byte or torn file under the real name
    assert list(out.glob(f".{Path(victim).stem}.part-*"))  # the killed writer's temporary file
    code, text = _cli([*DEMO, "--out", out, "--resume"], capsys)
    assert code == 0, text
    assert f"reusing {FRAMES} of {FRAMES} frames; {FRAMES} second-pass frames on disk" in text, text
    assert not list(out.glob(".*.part-*"))  # the claim of the resumed run removed the leftover
    np.testing.assert_array_equal(_controls(reference)["activations"], _controls(out)["activations"])
    assert read_report(out)["frames"] == int(FRAMES)


def test_exception_during_a_write_keeps_the_old_file(tmp_path):
    path = save_npz(tmp_path / "a.npz", x=np.arange(3))
    with pytest.raises(RuntimeError), atomic_path(path) as tmp:
        tmp.write_bytes(b"half")
        raise RuntimeError("disk full")
    np.testing.assert_array_equal(load_npz(path)["x"], np.arange(3))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npz"]


# ---------------------------------------------------------------------- provenance
def test_resume_into_another_take_is_refused(reference, tmp_path, capsys):
    out = _copy(reference, tmp_path / "other_seed")
    args = [a if a != "2" else "3" for a in DEMO]  # another demo seed
    code, text = _cli([*args, "--out", out, "--resume"], capsys)
    assert code == 1
    assert "holds another take" in text and "--overwrite" in text
    assert "another input (seed differ" in text  # what differs, where the two descriptions may read alike
    assert _controls(out)["activations"].shape[0] == int(FRAMES)  # nothing was touched


def test_resume_with_another_model_is_refused(reference, tmp_path, capsys):
    out = _copy(reference, tmp_path / "other_model")
    args = ["demo", "--tets", "1200", "--frames", FRAMES, "--no-pictures", "--seed", "2"]
    code, text = _cli([*args, "--out", out, "--resume"], capsys)
    assert code == 1 and "holds another take" in text


def test_overwrite_replaces_another_take(reference, tmp_path, capsys):
    out = _copy(reference, tmp_path / "replaced")
    args = [a if a != "2" else "3" for a in DEMO]
    code, text = _cli([*args, "--out", out, "--overwrite", "--prior", "off"], capsys)
    assert code == 0, text
    assert "removed the earlier results" in text
    assert json.loads((out / "provenance.json").read_text())["source"]["seed"] == 3
    assert not (out / "survey").exists()  # nothing stale of the old take survives


def _tracked(tmp_path, name="lib"):
    """A small take tracked through the library (one pass) into a directory, with its inputs."""
    from wface.faces.builtin import build_face
    from wface.tracking.estimator import TrackOptions
    from wface.tracking.rig import FaceRig
    from wface.tracking.sequence import embed_model_markers, track_sequence, tracking_provenance
    from wface.tracking.synthetic import synthesize_performance

    model = build_face(int(TETS))
    markers = embed_model_markers(model)
    perf = synthesize_performance(FaceRig(model), markers, frames=3, seed=1)
    opts = TrackOptions(prior="temporal")
    run = tracking_provenance(model, markers, options=opts, source={"test": name})
    out = tmp_path / name
    claim_take_dir(out, run)
    kw = dict(marker_names=model.marker_names, markers=markers, options=opts, out_dir=out, provenance=run)
    recs = track_sequence(model, perf.markers_m, **kw)
    return model, markers, perf, run, out, recs, kw


def test_resume_reuses_only_matching_frames_and_says_why(tmp_path):
    from wface.tracking.sequence import track_sequence

    model, markers, perf, run, out, recs, kw = _tracked(tmp_path)
    frames = range(3)
    assert resume_plan(out, frames, perf.markers_m, run).reused == [0, 1, 2]
    # frame 1's file replaced by frame 2's: a valid file under another frame's name
    frame_path(out, 1).write_bytes(frame_path(out, 2).read_bytes())
    # frame 2 written without provenance (an older wface)
    rec = read_frame(frame_path(out, 2))
    rec.provenance = None
    write_frame(out, rec)
    plan = resume_plan(out, frames, perf.markers_m, run)
    assert plan.reused == [0]
    assert plan.redo == {1: "the file holds frame 2", 2: "no provenance recorded"}
    assert "reusing 1 of 3 frames" in plan.summary() and "redoing 2" in plan.summary()
    again = track_sequence(model, perf.markers_m, resume=True, **kw)
    for a, b in zip(recs, again, strict=True):
        np.testing.assert_array_equal(a.controls, b.controls)  # frame 0's stored state continues bit for bit
    # other marker data for a frame (e.g. a re-exported capture): that frame is redone
    data = perf.markers_m.copy()
    data[2, 0] += 1e-4
    assert resume_plan(out, frames, data, run).redo == {2: "other marker data for this frame"}


@pytest.mark.parametrize("damage", ["truncate", "flip", "empty"])
def test_damaged_frame_files_are_redone(tmp_path, damage):
    _, _, perf, run, out, _, _ = _tracked(tmp_path)
    p = frame_path(out, 1)
    data = p.read_bytes()
    if damage == "truncate":
        p.write_bytes(data[: len(data) // 2])
    elif damage == "flip":
        b = bytearray(data)
        b[len(b) // 3] ^= 0xFF
        p.write_bytes(bytes(b))
    else:
        p.write_bytes(b"")
    with pytest.raises(FileFormatError, match=p.name):
        read_frame(p)
    assert resume_plan(out, range(3), perf.markers_m, run).redo == {1: "unreadable (torn or corrupted) file"}


def test_other_options_redo_frames(tmp_path):
    from wface.tracking.estimator import TrackOptions
    from wface.tracking.sequence import tracking_provenance

    model, markers, perf, run, out, _, _ = _tracked(tmp_path)
    other = tracking_provenance(
        model, markers, options=TrackOptions(prior="temporal", robust_mm=5.0), source=run["source"]
    )
    plan = resume_plan(out, range(3), perf.markers_m, other)
    assert plan.reused == [] and set(plan.redo.values()) == {"other options (track)"}
    assert claim_take_dir(out, other, resume=True) == ""  # the same take: options may change


def test_rerun_without_resume_keeps_finished_frames_and_overwrite_leaves_no_stale_ones(tmp_path):
    """A plain rerun of the same take (after Ctrl-C, say) is refused while frames are done, naming
    them and both ways on; --overwrite then clears every pass's frames."""
    from wface.takes.store import TakeDirectoryError

    _, _, _, run, out, _, _ = _tracked(tmp_path)
    (out / "controls.npz").write_bytes(b"")
    shutil.copytree(out / "frames", out / "survey")  # a first pass's frames (they used to go uncounted)
    with pytest.raises(
        TakeDirectoryError, match=r"finished frames \(3 in survey/, 3 in frames/\).*--resume.*--overwrite"
    ):
        claim_take_dir(out, run)
    assert len(list((out / "frames").glob("*.npz"))) == 3 and (out / "controls.npz").exists()
    note = claim_take_dir(out, run, overwrite=True)
    assert "--overwrite: removed the earlier results" in note
    assert not (out / "frames").exists() and not (out / "survey").exists() and not (out / "controls.npz").exists()


def test_edit_into_a_tracked_take_is_refused(reference, tmp_path, capsys):
    out = _copy(reference, tmp_path / "edit_into")
    args = ["edit", "blend", "--tets", TETS, "--from", "smile", "--to", "surprise", "--frames", "2", "--no-pictures"]
    code, text = _cli([*args, "--out", out], capsys)
    assert code == 1 and "holds another take" in text and "wface demo" in text


def test_mixed_frames_are_not_used_as_reference(reference, tmp_path):
    from wface.faces.builtin import build_face

    out = _copy(reference, tmp_path / "mixed")
    rec = read_frame(frame_path(out, 1))
    rec.provenance = dict(rec.provenance, run=dict(rec.provenance["run"], fingerprint="0" * 16))
    write_frame(out, rec)
    with pytest.warns(UserWarning, match="another run than controls.npz"):
        take = load_take(out, build_face(int(TETS)))
    assert take.reference_positions_m is None


# ---------------------------------------------------------------------- truncated and corrupted files
@pytest.mark.parametrize("damage", ["empty", "truncate", "flip", "text"])
def test_damaged_model_file_is_named(model_path, tmp_path, capsys, damage):
    data = model_path.read_bytes()
    bad = tmp_path / "bad.npz"
    if damage == "empty":
        bad.write_bytes(b"")
    elif damage == "truncate":
        bad.write_bytes(data[: len(data) // 2])
    elif damage == "flip":
        b = bytearray(data)
        b[2000] ^= 0xFF  # inside the first array's bytes: a bad CRC
        bad.write_bytes(bytes(b))
    else:
        bad.write_text("not a model\n")
    code, text = _cli(["model", "info", bad], capsys)
    assert code == 1
    assert text.startswith("wface model info: error: ") and str(bad) in text and "Traceback" not in text
    expected = {"empty": "file is empty", "truncate": "not an .npz archive", "flip": "bad checksum", "text": "not an"}
    assert expected[damage] in text


def test_zero_byte_take_outputs_are_named_or_recovered(reference, tmp_path):
    from wface.faces.builtin import build_face

    model = build_face(int(TETS))
    out = _copy(reference, tmp_path / "zero")
    (out / "report.json").write_bytes(b"")
    with pytest.raises(FileFormatError, match="report.json: file is empty"):
        read_report(out)
    (out / "report.json").unlink()
    (out / "controls.npz").write_bytes(b"")
    with pytest.warns(UserWarning, match="controls.npz: file is empty"):
        take = load_take(out, model)  # recovered from the frame files
    np.testing.assert_array_equal(take.activations, model.clip_activations(_controls(reference)["activations"]))
    import shutil

    shutil.rmtree(out / "frames")
    with pytest.raises(FileFormatError, match="controls.npz"):
        load_take(out, model)


def test_bad_json_names_line_and_column(tmp_path):
    p = tmp_path / "report.json"
    p.write_text('{"frames": 3,\n "x": }\n')
    with pytest.raises(FileFormatError, match=r"report.json: .*line 2, column 7"):
        read_json(p)


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ('["Chin"]', "expected a JSON object {name: vertex index} or {name: [x, y, z]}, got a list"),
        ("{}", "holds no landmarks"),
        ('{"Chin": 999999}', "landmark 'Chin': vertex index 999999 is not in [0, 100)"),
        ('{"Chin": true}', "landmark 'Chin': True is not a vertex index"),
        ('{"browDown_L": "3"}', "landmark 'browDown_L': '3' is not a vertex index"),  # ICT's vertex_indices.json
        ("Chin 12", "not valid JSON at line 1, column 1"),
    ],
)
def test_bad_landmark_files_are_named(tmp_path, text, words):
    from wface.files import read_landmarks

    p = tmp_path / "lm.json"
    p.write_text(text)
    with pytest.raises(FileFormatError) as info:
        read_landmarks(p, n_vertices=100, points=True)
    assert str(info.value).startswith(str(p)) and words in str(info.value), str(info.value)
    p.write_text('{"Chin": 12, "Nose": [1, 2.5, 3]}')
    assert read_landmarks(p, n_vertices=100, points=True) == {"Chin": 12, "Nose": [1.0, 2.5, 3.0]}


@pytest.mark.parametrize("kind", ["c3d", "trc", "csv"])
def test_damaged_capture_files_are_named(tmp_path, capsys, kind):
    from wface.io.mocap import MocapTake, write_mocap

    take = MocapTake(np.random.default_rng(0).normal(size=(5, 4, 3)) * 0.05, ["a", "b", "c", "d"], 60.0)
    good = tmp_path / f"good.{kind}"
    if kind == "c3d":
        pytest.importorskip("ezc3d")
    write_mocap(take, good)
    data = good.read_bytes()
    for bad_bytes, what in ((b"", "empty"), (data[: len(data) // 2], None)):
        bad = tmp_path / f"bad.{kind}"
        bad.write_bytes(bad_bytes)
        code, text = _cli(["track", "--mocap", bad, "--out", tmp_path / "o", "--tets", TETS], capsys)
        assert code == 1 and str(bad) in text and "Traceback" not in text, text
        if what:
            assert what in text


def test_corrupted_basis_is_named(tmp_path):
    from wface.basis.core import load_basis

    bad = tmp_path / "basis.npz"
    bad.write_bytes(b"PK\x03\x04 truncated")
    with pytest.raises(FileFormatError, match="basis.npz"):
        load_basis(bad)


# ---------------------------------------------------------------------- impossible capture samples
def _capture(tmp_path, positions_m, names, rate_hz=30.0, kind="csv"):
    from wface.io.mocap import MocapTake, write_mocap

    path = tmp_path / f"take.{kind}"
    write_mocap(MocapTake(positions_m, list(names), rate_hz), path)
    return path


@pytest.fixture(scope="module")
def synthetic_capture():
    """Clean markers of a short synthetic take on the smallest face, neutral first."""
    from wface.faces.builtin import build_face
    from wface.tracking.rig import FaceRig
    from wface.tracking.sequence import embed_model_markers
    from wface.tracking.synthetic import synthesize_performance

    model = build_face(int(TETS))
    markers = embed_model_markers(model)
    perf = synthesize_performance(FaceRig(model), markers, frames=4, seed=6)
    rest = markers.positions(model.rest_positions_m)[None]
    return np.concatenate([rest, perf.clean_markers_m]), list(model.marker_names)


def test_impossible_samples_become_missing_and_are_counted(synthetic_capture, tmp_path, capsys):
    pos, names = synthetic_capture
    pos = pos.copy()
    pos[2, 3] = 1e19  # corrupted data bytes
    pos[3, 5] += [0.3, 0.0, 0.0]  # 30 cm off the head
    pos[2, 7] += [0.08, 0.0, 0.0]  # a one-frame jump of 8 cm at 30 Hz: 2.4 m/s
    pos[4, 9] = 1e200  # overflowed the frame's rigid fit, which then took every marker of frame 4
    path = _capture(tmp_path, pos * 1.0, names)
    out = tmp_path / "run"
    code, text = _cli(
        ["track", "--mocap", path, "--out", out, "--tets", TETS, "--no-pictures", "--prior", "off"], capsys
    )
    assert code == 0, text
    assert "capture check: 4 impossible samples made missing" in text and "overflow" not in text
    check = read_report(out)["capture_check"]
    assert check["per_marker"][names[9]]["far"] == 1
    assert check["per_marker"][names[3]]["far"] == 1
    assert check["per_marker"][names[5]]["far"] == 1
    assert check["per_marker"][names[7]]["jumps"] == 1
    assert len(check["per_marker"]) == 4  # nothing else: the face's own motion is possible
    assert read_report(out)["marker_max_mm"] < 50  # nothing tracked toward 1e19 m


def test_a_ghost_sample_in_the_neutral_frame_is_not_blamed_on_units(synthetic_capture, tmp_path, capsys):
    """One marker 0.5 m off in the neutral frame used to pull the alignment to scale 0.2 and stop the run with
    'check the file's length units'; it is an impossible sample, made missing, and that marker left out."""
    pos, names = synthetic_capture
    pos = pos.copy()
    pos[0, 5] += [0.5, 0.0, 0.0]
    path = _capture(tmp_path, pos, names)
    args = ["track", "--mocap", path, "--out", tmp_path / "ghost", "--tets", TETS, "--no-pictures", "--prior", "off"]
    code, text = _cli(args, capsys)
    assert code == 0 and "units" not in text, text
    assert (
        "1 impossible samples made missing" in text
        and f"rest place (--neutral-frame picks another frame): {names[5]}" in text
    )


def test_capture_check_finds_nothing_on_real_takes():
    from tests.conftest import data_path
    from wface.io.mocap import read_mocap
    from wface.tracking.capture import check_capture

    take = read_mocap(data_path("animface", "JawMoCap.c3d"))
    assert check_capture(take.positions_m, take.marker_names, rate_hz=take.rate_hz).removed == 0


def test_wrong_units_are_refused(synthetic_capture, tmp_path, capsys):
    pos, names = synthetic_capture
    small = _capture(tmp_path, pos * 0.01, names)  # a metre file read as centimetres: 100x too small
    code, text = _cli(["track", "--mocap", small, "--out", tmp_path / "b", "--tets", TETS], capsys)
    assert code == 1 and "scale" in text and "units" in text, text
    assert not (tmp_path / "b").exists()


def test_names_that_match_nothing_without_a_shape_match_are_refused(tmp_path, capsys):
    from tests.conftest import data_path
    from wface.io.mocap import read_mocap

    take = read_mocap(data_path("animface", "JawMoCap.c3d")).frames(0, 3)
    path = _capture(tmp_path, take.positions_m, [f"m{i}" for i in range(take.n_markers)], rate_hz=take.rate_hz)
    code, text = _cli(["track", "--mocap", path, "--out", tmp_path / "a", "--tets", TETS], capsys)
    assert code == 1 and "marker names match the model's" in text, text


def test_a_frame_with_too_few_markers_is_carried(synthetic_capture, tmp_path, capsys):
    pos, names = synthetic_capture
    pos = pos.copy()
    pos[2, 2:] = np.nan  # frame 2 keeps 2 markers
    pos[3] = np.nan  # frame 3 keeps none
    path = _capture(tmp_path, pos, names)
    out = tmp_path / "carried"
    args = ["track", "--mocap", path, "--out", out, "--tets", TETS, "--no-pictures", "--prior", "off"]
    code, text = _cli(args, capsys)
    assert code == 0, text
    assert "2 frames had too few usable markers" in text and "Mean of empty slice" not in text
    report = read_report(out)
    assert report["carried_frames"] == [2, 3] and report["frames"] == len(pos)
    assert report["marker_rms_mm"][3] is None and np.isfinite(report["marker_rms_mm_mean"])  # was NaN
    json.loads((out / "report.json").read_text(), parse_constant=lambda c: pytest.fail(f"{c} in report.json"))
    c = _controls(out)["activations"]
    np.testing.assert_array_equal(c[2], c[1])  # held from the frame before
    np.testing.assert_array_equal(c[3], c[1])
    code, text = _cli([*args, "--resume"], capsys)
    assert code == 0 and f"reusing {len(pos)} of {len(pos)}" in text


def test_a_take_without_usable_frames_is_an_error(synthetic_capture, tmp_path, capsys):
    pos, names = synthetic_capture
    pos = pos.copy()
    pos[1:, 3:] = np.nan  # only the neutral frame 0 is complete
    path = _capture(tmp_path, pos, names)
    args = ["track", "--mocap", path, "--frames", "1:", "--neutral-frame", "0", "--out", tmp_path / "none"]
    code, text = _cli([*args, "--tets", TETS], capsys)
    assert code == 1 and "usable markers a frame needs" in text, text


def test_markers_without_a_rest_place_or_samples_are_left_out_by_name(synthetic_capture, tmp_path, capsys):
    """A marker missing in the neutral frame has no rest place on the skin, and one missing from every tracked
    frame nothing to fit: both are left out with their names (the first used to stop the tracker with
    "Eigenvalues did not converge", the second to fail at the USD after the whole take was tracked)."""
    pos, names = synthetic_capture
    pos = pos.copy()
    pos[0, 4] = np.nan  # missing in the neutral frame only
    pos[:, 6] = np.nan  # never seen
    path = _capture(tmp_path, pos, names)
    out = tmp_path / "left_out"
    code, text = _cli(
        ["track", "--mocap", path, "--out", out, "--tets", TETS, "--no-pictures", "--prior", "off"], capsys
    )
    assert code == 0, text
    assert f"rest place (--neutral-frame picks another frame): {names[4]}" in text
    assert f"left out of the fit, no samples in the frames tracked: {names[6]}" in text
    assert (out / "animation.usdc").exists()
    report = read_report(out)
    assert names[4] not in report["marker_stats"] and names[6] not in report["marker_stats"]
    assert np.isfinite(report["marker_rms_mm_mean"])


def test_options_that_would_be_ignored_or_mislead_are_said(tmp_path, capsys):
    """--neutral-frame without --markers was ignored; --frames past the take's end tracked 5 frames without a word;
    waters on a head read in the wrong units moved 0.00 mm (or 181 mm)."""
    from tests.conftest import data_path

    code, text = _cli(
        ["model", "fit", "--surface", "x.obj", "--neutral-frame", "3", "--out", tmp_path / "a.npz"], capsys
    )
    assert code == 1 and "--neutral-frame picks a frame of --markers, which is not given" in text
    head = data_path("ict-facekit", "generic_neutral_mesh.obj")
    code, text = _cli(["waters", "--mesh", head, "--units", "mm", "--no-render", "--out", tmp_path / "w"], capsys)
    assert code == 1 and "0.0338 m across read at 0.001 m per unit" in text and "check --units" in text
    take = data_path("animface", "JawMoCap.c3d")
    args = ["track", "--mocap", take, "--frames", "1585:1700", "--tets", TETS, "--no-pictures", "--no-usd"]
    code, text = _cli([*args, "--prior", "off", "--out", tmp_path / "t"], capsys)
    assert code == 0 and "has 1590 frames; tracking 5 (1585 to 1589)" in text


# ---------------------------------------------------------------------- options out of range (usage errors)
_USAGE = [
    (["demo", "--outliers", "1.5"], "fraction between 0 and 1"),
    (["demo", "--dropout", "-0.1"], "fraction between 0 and 1"),
    (["demo", "--noise-mm", "-1"], ">= 0"),
    (["demo", "--temporal-weight", "nan"], "finite"),
    (["demo", "--chunk-size", "-3"], ">= 1"),
    (["demo", "--workers", "0"], ">= 1"),
    (["demo", "--frames", "0"], ">= 1"),
    (["demo", "--fps", "0"], "> 0"),
    (["demo", "--seed", "-1"], ">= 0"),
    (["demo", "--tets", "ten"], "whole number"),
    (["demo", "--robust-mm", "inf"], "finite"),
    (["demo", "--contact-stiffness", "-5"], "> 0"),
    (["demo", "--prior", "strong"], "invalid choice"),
    (["demo", "--prior-passes", "0"], ">= 1"),
    (["track", "--mocap", "x.c3d", "--prior-passes", "-1"], ">= 1"),
    (["track", "--mocap", "x.c3d", "--frames", "5:2"], "empty"),
    (["track", "--mocap", "x.c3d", "--frames", "abc"], "A:B"),
    (["track", "--mocap", "x.c3d", "--neutral-frame", "-1"], ">= 0"),
    (["bench", "--suite", "forward", "--repeat", "0"], ">= 1"),
    (["model", "build", "--tets", "0"], "made with 1000 to 2000000 tets"),
    (["demo", "--tets", "10"], "made with 1000 to 2000000 tets"),  # was exit 1 after the parse, internal name
    (["track", "--mocap", "x.c3d", "--holdout", "1"], "N >= 2"),
    (["track", "--mocap", "x.c3d", "--contact", "lipz"], "unknown contact region(s) lipz"),
    (["resim", "--contact", "lips,tooth"], "unknown contact region(s) tooth"),
    (["model", "build", "--vtu", "x.obj"], "tet mesh file"),
    (["simulate", "--model", "m.npz", "--activation", "zygomaticus_major_l"], "expects NAME=VALUE"),
    (["simulate", "--model", "m.npz", "--obstacle", "cube:1,2,3"], "unknown kind 'cube'"),
    (["basis", "analyze", "--basis", "b.npz", "--mocap", "x.c3d", "--frames", "abc"], "frame range"),
    (["basis", "analyze", "--basis", "b.npz", "--mocap", "x.c3d", "--frames", "0:20:0"], "step S must be >= 1"),
    (["basis", "refine", "--basis", "b.npz", "--train", "t.c3d", "--regularization", "-1"], ">= 0"),
    (["basis", "refine", "--basis", "b.npz", "--train", "t.c3d", "--support", "2"], "(0, 1]"),
    (["basis", "refine", "--basis", "b.npz", "--train", "t.c3d"], "ending in .npz"),
    (["simulate", "--model", "m.npz", "--tol", "0"], "> 0"),
    (["simulate", "--model", "m.npz", "--jaw-open", "nan"], "finite"),
    (["resim", "--substeps", "0"], ">= 1"),
    (["edit", "retime", "--take", "t", "--speed", "0"], "> 0"),
    (["edit", "layer", "--take", "t", "--add", "smile", "--weight", "nan"], "finite"),
    (["waters", "--mesh", "builtin", "--intensity", "2"], "between 0 and 1"),
    (["basis", "from-face", "--activation", "0"], "(0, 1]"),
    (["speech", "--model", "m", "--gesture", "closure", "--fps", "-100"], "> 0"),
]


@pytest.mark.parametrize(("args", "expected"), _USAGE, ids=[" ".join(a) for a, _ in _USAGE])
def test_out_of_range_options_are_usage_errors(args, expected, capsys):
    code, text = _cli([*args, "--out", "never_written"], capsys)
    assert code == 2
    assert expected in text and "error: argument" in text
    assert not Path("never_written").exists()


# ---------------------------------------------------------------------- what a model lacks, what no joint can do
def test_jaw_beyond_the_joint_limit_is_refused(model_path, tmp_path, capsys):
    code, text = _cli(["simulate", "--model", model_path, "--jaw-open", "90", "--out", tmp_path / "j"], capsys)
    assert code == 1 and "outside this model's jaw range" in text
    assert not (tmp_path / "j" / "equilibrium.npz").exists()
    # closing past rest: within the model's closing range, not beyond it
    code, text = _cli(["simulate", "--model", model_path, "--jaw-open", "-5", "--out", tmp_path / "c"], capsys)
    assert code == 1 and "outside this model's jaw range [-2.3, 35.0] deg" in text
    assert not (tmp_path / "c" / "equilibrium.npz").exists()
    code, _ = _cli(["simulate", "--model", model_path, "--jaw-open", "-1.5", "--out", tmp_path / "c"], capsys)
    assert code == 0 and (tmp_path / "c" / "equilibrium.npz").exists()


def test_speech_on_a_face_without_its_muscles_is_refused(model_path, tmp_path, capsys):
    from tests.conftest import data_path

    speech = data_path("artisynth-face", "speech")
    args = ["speech", "--model", model_path, "--gesture", "closure", "--speech-dir", speech, "--out", tmp_path / "s"]
    code, text = _cli(args, capsys)
    assert code == 1 and "none of the muscles the gesture drives" in text and "OOP" in text
    assert not (tmp_path / "s").exists()


@pytest.mark.parametrize(
    ("extra", "said"),
    [  # each was accepted and did nothing
        (["--damping-alpha", "1"], "--damping-alpha set(s) the dynamic playback: add --dynamic"),
        (["--no-gravity", "--scheme", "midpoint"], "--scheme, --no-gravity set(s) the dynamic playback"),
        (["--exact-damping"], "--exact-damping set(s) the dynamic playback"),
        (["--data", "somewhere"], "--data is the artisynth-face folder of --setup artisynth"),
        (["--idle-muscles", "off"], "--idle-muscles sets up ArtiSynth's demo: add --setup artisynth"),
        (["--muscle-curves", "artisynth"], "--muscle-curves sets up ArtiSynth's demo: add --setup artisynth"),
        (["--muscle-elements", "artisynth"], "--muscle-elements sets up ArtiSynth's demo: add --setup artisynth"),
        (["--lower-oom", "exciter"], "--lower-oom exciter takes the targets of ArtiSynth's demo on its hexes"),
        (["--bulk-potential", "quadratic"], "--bulk-potential sets up ArtiSynth's demo: add --setup artisynth"),
        (["--ring-directions", "delaunay"], "--ring-directions sets up ArtiSynth's demo: add --setup artisynth"),
        (
            ["--bulk-potential", "log"],
            "--bulk-potential sets up ArtiSynth's demo: add --setup artisynth",
        ),  # the default
        (["--no-exact-damping"], "--exact-damping set(s) the dynamic playback"),
    ],
)
def test_speech_options_that_would_do_nothing_are_usage_errors(model_path, tmp_path, capsys, extra, said):
    code, text = _cli(
        ["speech", "--model", model_path, "--gesture", "closure", *extra, "--out", tmp_path / "s"], capsys
    )
    assert code == 2 and said in text, text
    assert not (tmp_path / "s").exists()


def test_speech_setup_options_reach_the_demo_setup(model_path, tmp_path, capsys, monkeypatch):
    """--ring-directions and --bulk-potential are handed to lip_opening_demo_model (stopped there)."""
    import wface.cli.speech as cli_speech

    seen = {}

    def setup(model, data_dir, **kwargs):
        seen.update(kwargs)
        raise cli_speech.UsageError("stopped after the setup")

    monkeypatch.setattr(cli_speech, "lip_opening_demo_model", setup)
    extra = ["--setup", "artisynth", "--ring-directions", "delaunay", "--bulk-potential", "quadratic"]
    argv = ["speech", "--model", model_path, "--gesture", "closure", *extra, "--out", tmp_path / "s"]
    code, text = _cli(argv, capsys)
    assert code == 2 and "stopped after the setup" in text, text
    assert seen["ring_directions"] == "delaunay" and seen["bulk_potential"] == "quadratic"
    assert not (tmp_path / "s").exists()


def test_speech_setup_artisynth_exact_is_the_demos_every_choice():
    """--setup artisynth-exact: the five setup options at the demo's choice and the exact damping with --dynamic;
    an option given wins, its default value included; --setup artisynth keeps wface's defaults."""
    from wface.cli import build_parser
    from wface.cli.speech import _check_options

    def played(*extra):
        args = build_parser().parse_args(["speech", "--model", "m.npz", "--gesture", "fricative", "--out", "o", *extra])
        _check_options(args)
        keys = ("setup", "setup_preset", "muscle_curves", "muscle_elements", "ring_directions", "bulk_potential")
        return tuple(getattr(args, k) for k in (*keys, "lower_oom", "exact_damping", "idle_muscles"))

    demo = ("artisynth", "artisynth", "delaunay", "quadratic", "exciter")
    assert played("--setup", "artisynth-exact") == ("artisynth", "artisynth-exact", *demo, False, "passive")
    assert played("--setup", "artisynth-exact", "--dynamic")[-2] is True
    assert played("--setup", "artisynth-exact", "--dynamic", "--no-exact-damping")[-2] is False
    own = played(
        "--setup", "artisynth-exact", "--bulk-potential", "log", "--lower-oom", "whole", "--idle-muscles", "off"
    )
    assert own == ("artisynth", "artisynth-exact", "artisynth", "artisynth", "delaunay", "log", "whole", False, "off")
    wface = ("wface", "import", "nearest", "log", "whole", False, "passive")
    assert played("--setup", "artisynth", "--dynamic") == ("artisynth", "artisynth", *wface)
    assert played() == ("import", "import", *wface)


def test_the_speech_dir_given_is_the_only_one_looked_in(model_path, tmp_path, capsys):
    """A --speech-dir without the gesture fell through to ../shared/data's gestures, unsaid."""
    (tmp_path / "gestures" / "hum").mkdir(parents=True)
    (tmp_path / "gestures" / "hum" / "0probes.art").write_text("")
    args = ["speech", "--model", model_path, "--gesture", "closure", "--speech-dir", tmp_path / "gestures"]
    code, text = _cli([*args, "--out", tmp_path / "s"], capsys)
    assert code == 1 and "no closure/0probes.art there (its gestures: hum)" in text, text
    assert not (tmp_path / "s").exists()


def test_missing_surfaces_and_muscles_are_named(model_path, tmp_path, capsys):
    from wface.model import load_model, save_model

    model = load_model(model_path)
    model.surface_groups = {k: v for k, v in model.surface_groups.items() if k in model.pressure_actuators}
    bare = save_model(model, tmp_path / "bare.npz")  # no lip surfaces (the pressure keeps its wall)
    code, text = _cli(["simulate", "--model", bare, "--contact", "lips", "--out", tmp_path / "c"], capsys)
    assert code == 1 and "lip" in text, text
    code, text = _cli(["simulate", "--model", bare, "--activation", "nosuch=0.5", "--out", tmp_path / "c"], capsys)
    assert code == 1 and "unknown muscle 'nosuch'" in text
    code, text = _cli(["simulate", "--model", bare, "--activation", "procerus=1.5", "--out", tmp_path / "c"], capsys)
    assert code == 1 and "[0, 1]" in text


def test_a_directory_that_holds_no_take_is_named_before_any_face_is_built(tmp_path, capsys, monkeypatch):
    import wface.cli.take_face as take_face  # where resim and edit build their face

    def no_face(*_args, **_kwargs):
        raise AssertionError("a face was built before --take was checked")

    (tmp_path / "empty").mkdir()
    monkeypatch.setattr(take_face, "build_face", no_face)
    for args in (["resim", "--take", tmp_path / "empty"], ["edit", "retime", "--take", tmp_path / "empty"]):
        code, text = _cli([*args, "--out", tmp_path / "o"], capsys)
        assert code == 1 and "not a tracking output directory" in text and str(tmp_path / "empty") in text, text
    code, text = _cli(["resim", "--take", tmp_path / "nowhere", "--out", tmp_path / "o"], capsys)
    assert code == 1 and "does not exist" in text
    (tmp_path / "afile").write_text("x")
    code, text = _cli(["resim", "--take", tmp_path / "afile", "--out", tmp_path / "o"], capsys)
    assert code == 1 and "is a file, not a take directory" in text
    assert not (tmp_path / "o").exists()


def test_a_takes_controls_file_is_taken_for_its_directory(reference, tmp_path, capsys):
    """README: feed controls.npz back with --take; the file itself used to be refused as "does not exist"."""
    from wface.takes.store import require_take_dir

    assert require_take_dir(reference / "controls.npz") == reference


def test_broken_meshes_are_named_before_any_face_is_built(tmp_path, capsys, monkeypatch):
    """A render mesh or fit target that cannot be read stops the command at once, naming the file and
    why (meshio's PLY reader exits the process on a bad header: it must not), with nothing written."""
    import wface.cli.model as model_cli
    import wface.cli.track as track_cli

    def no_face(*_args, **_kwargs):
        raise AssertionError("a face was built before the mesh was read")

    for mod in (track_cli, model_cli):
        monkeypatch.setattr(mod, "build_face", no_face)
    (tmp_path / "bad.ply").write_text("not a mesh\n")
    (tmp_path / "empty.stl").write_text("solid x\nendsolid x\n")
    (tmp_path / "points.obj").write_text("v 0 0 0\nv 1 0 0\n")
    cases = {"bad.ply": "not a readable surface mesh", "empty.stl": "no triangles", "points.obj": "no faces"}
    for name, why in cases.items():
        mesh = tmp_path / name
        code, text = _cli(["demo", "--render-mesh", mesh, "--out", tmp_path / "o"], capsys)
        assert code == 2 and f"--render-mesh: {mesh}" in text and why in text, text
        code, text = _cli(["model", "fit", "--surface", mesh, "--out", tmp_path / "f.npz"], capsys)
        assert code == 1 and str(mesh) in text and why in text, text
    assert not (tmp_path / "o").exists() and not (tmp_path / "f.npz").exists()


# ---------------------------------------------------------------------- the top-level handler
def test_out_that_is_a_file_or_unwritable(model_path, tmp_path, capsys):
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    code, text = _cli(["simulate", "--model", model_path, "--out", a_file], capsys)
    assert code == 1 and str(a_file) in text and "Traceback" not in text
    code, text = _cli([*DEMO, "--out", a_file], capsys)
    assert code == 1 and "is a file" in text
    if os.geteuid() == 0:
        pytest.skip("running as root: every directory is writable")
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        code, text = _cli(["simulate", "--model", model_path, "--out", locked / "sub"], capsys)
        assert code == 1 and "Permission denied" in text
    finally:
        locked.chmod(0o700)


def test_missing_optional_package_names_the_extra(monkeypatch, tmp_path, capsys):
    import wface.cli.model as cli_model

    def boom(args):
        raise ModuleNotFoundError("No module named 'pyvista'", name="pyvista")

    monkeypatch.setattr(cli_model, "_info", boom)
    code, text = _cli(["model", "info", "x.npz"], capsys)
    assert code == 1 and "pip install 'wface[viz]'" in text


@pytest.mark.parametrize(
    ("exc", "code", "words"),
    [(KeyboardInterrupt(), 130, "interrupted"), (BrokenPipeError(), 141, ""), (RuntimeError("bug"), 1, "internal")],
)
def test_interrupt_pipe_and_bugs(monkeypatch, capsys, exc, code, words):
    import wface.cli.model as cli_model

    def boom(args):
        raise exc

    monkeypatch.setattr(cli_model, "_info", boom)
    got, text = _cli(["model", "info", "x.npz"], capsys)
    assert got == code
    assert (words in text) if words else text == ""
    assert "Traceback" not in text


def test_debug_shows_the_traceback(capsys):
    with pytest.raises(FileNotFoundError):
        main(["model", "info", "nowhere.npz", "--debug"])
    code, text = _cli(["model", "info", "nowhere.npz"], capsys)
    assert code == 1 and text.strip() == "wface model info: error: face model file not found: nowhere.npz"


def test_closed_pipe_is_quiet():
    """`wface --help | true`: the reader is gone before wface writes; no BrokenPipeError spew."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "wface", "--help"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    proc.stdout.close()  # the reader goes away at once
    assert proc.wait(timeout=120) in (0, 141)
    assert b"Traceback" not in proc.stderr.read()


def test_chunks_of_a_one_pass_take_say_they_may_differ_from_a_serial_run(tmp_path, capsys):
    args = [*DEMO, "--no-usd", "--prior", "temporal", "--chunk-size", "2", "--out", tmp_path / "t"]
    code, text = _cli(args, capsys)
    assert code == 0 and "note: with --prior temporal each chunk" in text
    code, text = _cli([*DEMO, "--no-usd", "--chunk-size", "2", "--out", tmp_path / "a"], capsys)
    assert code == 0 and "--prior temporal each chunk" not in text  # the default refits over the take


def test_resume_plan_counts_the_frames_of_a_take_with_hidden_markers(tmp_path, capsys):
    """With --holdout the frame files' fingerprints hold the markers the fit saw (the hidden ones
    missing); the resume plan used to compare them with every marker and announce every frame redone."""
    out = tmp_path / "held"
    code, text = _cli([*DEMO, "--holdout", "5", "--no-usd", "--out", out], capsys)
    assert code == 0, text
    code, text = _cli([*DEMO, "--holdout", "5", "--no-usd", "--out", out, "--resume"], capsys)
    assert code == 0, text
    assert f"reusing {FRAMES} of {FRAMES} frames" in text


def test_another_runs_results_are_described_in_words():
    """A --take source was printed as a raw dict, and an edit's own --frames option as the take's frame count."""
    from wface.takes.provenance import describe_source

    run = {"kind": "resim", "model_sha256": "ab" * 32, "source": {"take": {"path": "tk", "fingerprint": "cc"}}}
    assert describe_source(run) == f"wface resim of tk on model {'ab' * 6}"
    edit = {"kind": "edit exaggerate", "model_sha256": "ab" * 32, "source": {"take": {"path": "tk"}, "frames": 1}}
    assert describe_source(edit) == f"wface edit exaggerate of tk (--frames 1) on model {'ab' * 6}"
    track = {"kind": "track", "model_sha256": "ab" * 32, "source": {"file": "Jaw.c3d", "frames": "0:300"}}
    assert describe_source(track) == f"wface track of Jaw.c3d frames 0:300 on model {'ab' * 6}"
