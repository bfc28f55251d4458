"""Command-line runs that lost work or did nothing they said (each reproduced by a user of the CLI) are
refused before any work, with exit code 2 for options and 1 for a directory that holds other results."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from wface.cli import main
from wface.faces import build_face
from wface.model import save_model
from wface.takes.provenance import command_provenance, same_take


def _cli(args, capsys) -> tuple[int, str]:
    code = main([str(a) for a in args])
    cap = capsys.readouterr()
    return code, cap.out + cap.err


@pytest.fixture(scope="module")
def model_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("model") / "face.npz"
    save_model(build_face(1000), path)
    return path


@pytest.mark.parametrize(
    ("extra", "said"),
    [
        (["--activation", "zygomaticus_major_l=1"], "--activation shape(s) the synthetic take"),
        (["--jaw-open", "5"], "--jaw-open shape(s) the synthetic take"),
    ],
)
def test_resim_refuses_synthetic_options_with_a_take(tmp_path, capsys, extra, said):
    take = tmp_path / "take"
    take.mkdir()
    code, text = _cli(["resim", "--take", take, "--tets", "1000", "--out", tmp_path / "o", *extra], capsys)
    assert code == 2 and said in text and "would do nothing with --take" in text, text


def test_resim_refuses_a_range_for_the_synthetic_frame_count(tmp_path, capsys):
    code, text = _cli(["resim", "--tets", "1000", "--frames", "0:5", "--out", tmp_path / "o"], capsys)
    assert code == 2 and "synthetic take's frame count" in text, text


def test_bench_checks_out_before_running(tmp_path, capsys):
    code, text = _cli(["bench", "--suite", "build", "--tets", "1000", "--out", tmp_path], capsys)
    assert code == 2 and "is a directory" in text
    code, text = _cli(["bench", "--suite", "build", "--tets", "1000", "--out", tmp_path / "no" / "b.json"], capsys)
    assert code == 2 and "does not exist" in text and not (tmp_path / "no").exists()


def test_track_refuses_resume_with_overwrite(tmp_path, capsys):
    args = ["demo", "--tets", "1000", "--frames", "2", "--no-pictures", "--out", tmp_path / "d"]
    code, text = _cli([*args, "--resume", "--overwrite"], capsys)
    assert code == 2 and "--resume and --overwrite contradict" in text, text


def test_a_plain_demo_rerun_keeps_the_finished_frames(tmp_path, capsys):
    """The same run again (the README's command twice, a rerun after Ctrl-C) continues from its frames;
    the same take with other options is refused while frames are done (it deleted them), naming why."""
    out = tmp_path / "d"
    args = ["demo", "--tets", "1000", "--frames", "2", "--no-pictures", "--prior", "temporal", "--out", out]
    assert _cli(args, capsys)[0] == 0
    before = {p.name: p.stat().st_mtime_ns for p in (out / "frames").iterdir()}
    code, text = _cli(args, capsys)
    assert code == 0 and "continuing the same run" in text and "reusing 2 of 2 frames" in text, text
    assert {p.name: p.stat().st_mtime_ns for p in (out / "frames").iterdir()} == before  # reused, not redone
    code, text = _cli([*args, "--robust-mm", "5"], capsys)
    assert code == 1 and "finished frames" in text and "other options" in text and "--resume" in text, text
    assert {p.name: p.stat().st_mtime_ns for p in (out / "frames").iterdir()} == before


def test_simulate_claims_its_directory(tmp_path, capsys, model_path):
    demo = tmp_path / "demo"
    demo.mkdir()
    (demo / "report.json").write_text('{"frames": 30}')
    (demo / "provenance.json").write_text(json.dumps({"kind": "demo", "fingerprint": "0" * 16}))
    args = ["simulate", "--model", model_path, "--activation", "zygomaticus_major_r=0.3"]
    code, text = _cli([*args, "--out", demo], capsys)
    assert code == 1 and "holds another take's results" in text and not (demo / "summary.json").exists(), text
    code, text = _cli([*args, "--out", tmp_path / "smile"], capsys)
    assert code == 0 and "provenance.json" in text and "frames/" not in text
    again = ["simulate", "--model", model_path, "--activation", "zygomaticus_major_r=0.5", "--out", tmp_path / "smile"]
    code, text = _cli(again, capsys)  # another activation: another result, not silently replaced
    assert code == 1 and "--overwrite" in text
    assert json.loads((tmp_path / "smile" / "summary.json").read_text())["activations"]["zygomaticus_major_r"] == 0.3


def test_another_speech_gesture_is_another_take():
    face = build_face(1000)
    ns = {"model": "badin.npz", "max_frames": 2, "tol": 1e-4}
    closure = command_provenance("speech", face, argparse.Namespace(gesture="closure", **ns))
    approximant = command_provenance("speech", face, argparse.Namespace(gesture="approximant", **ns))
    tighter = command_provenance("speech", face, argparse.Namespace(gesture="closure", **{**ns, "tol": 1e-6}))
    assert not same_take(closure, approximant) and same_take(closure, tighter)


def test_provenance_leaves_the_parsers_bookkeeping_out():
    """The option defaults a parser keeps to tell which options were given are not options of the run."""
    face = build_face(1000)
    args = argparse.Namespace(
        gesture="closure", tol=1e-4, dynamic_option_defaults={"scheme": "euler"}, contact_option_defaults={"a": 1}
    )
    options = command_provenance("speech", face, args)["options"]
    assert options == {"tol": 1e-4}


def test_model_build_counts_the_pressure_actuator_apart(tmp_path, capsys):
    code, text = _cli(["model", "build", "--tets", "1000", "--out", tmp_path / "f.npz"], capsys)
    assert code == 0 and "35 muscles and 1 pressure actuator" in text


def test_bench_without_json_prints_a_readable_summary(capsys):
    code, text = _cli(["bench", "--suite", "forward", "--tets", "1000", "--repeat", "1", "--device", "cpu"], capsys)
    assert code == 0 and text.startswith("wface bench --suite forward on cpu"), text
    assert "result 1:" in text and "tets" in text and "{" not in text  # no raw JSON


def test_model_commands_do_not_replace_an_existing_file_unasked(tmp_path, capsys, model_path):
    out = tmp_path / "kept.npz"
    out.write_bytes(model_path.read_bytes())
    code, text = _cli(["model", "build", "--tets", "1000", "--out", out], capsys)
    assert code == 2 and "exists" in text and "--overwrite" in text
    assert out.read_bytes() == model_path.read_bytes()
    assert _cli(["model", "build", "--tets", "1000", "--out", out, "--overwrite"], capsys)[0] == 0


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (["simulate", "--activation", "orbicularis_oris_upper=1", "--lip-surface", "faceted"], "which is off"),
        (["simulate", "--activation", "orbicularis_oris_upper=1", "--contact-stiffness", "1e6"], "which is off"),
        (["edit", "blend", "--from", "smile", "--to", "surprise", "--mix", "happy:0.5"], "not both"),
        (["model", "build", "--tets", "1000", "--free-to-mm", "50"], "within [5, 40] mm"),
    ],
)
def test_options_that_contradict_or_do_nothing_exit_2(tmp_path, capsys, model_path, args, said):
    if args[0] == "simulate":
        args = [args[0], "--model", model_path, *args[1:]]
    out = tmp_path / ("o.npz" if args[0] == "model" else "o")
    code, text = _cli([*args, "--out", out], capsys)
    assert code == 2 and said in text, text
    assert not out.exists()


def test_resim_takes_the_face_the_take_was_made_on(tmp_path, capsys):
    """`wface resim --take` without --tets rebuilt the default 5K face and refused the 1K take ("pass the
    same --model (or --tets)"); report.json records the face and resim builds it."""
    take = tmp_path / "demo"
    args = ["demo", "--tets", "1000", "--frames", "2", "--no-pictures", "--prior", "temporal", "--out", take]
    assert _cli(args, capsys)[0] == 0
    assert json.loads((take / "report.json").read_text())["face_model"] == {"builtin_tets": 1000}
    code, text = _cli(["resim", "--take", take, "--substeps", "1", "--out", tmp_path / "dyn"], capsys)
    assert code == 0 and "the built-in face at --tets 1000" in text, text


def test_no_rig_writes_the_point_cache_alone(tmp_path, capsys):
    """The rig's skin z-fights with the point cache until a DCC user hides one; --no-rig leaves it out."""
    from pxr import Usd

    out = tmp_path / "demo"
    args = ["demo", "--tets", "1000", "--frames", "2", "--no-pictures", "--prior", "temporal", "--out", out]
    assert _cli([*args, "--no-rig"], capsys)[0] == 0
    stage = Usd.Stage.Open(str(out / "animation.usdc"))
    assert stage.GetPrimAtPath("/Face/Skin") and not stage.GetPrimAtPath("/Face/Rig")
    args[-1] = tmp_path / "with_rig"
    assert _cli(args, capsys)[0] == 0
    assert Usd.Stage.Open(str(tmp_path / "with_rig" / "animation.usdc")).GetPrimAtPath("/Face/Rig")


def test_bench_does_not_replace_a_file_unasked(tmp_path, capsys):
    """`bench --out v2.npz` replaced a face model with JSON text after the run."""
    kept = tmp_path / "v2.json"
    kept.write_text("earlier")
    args = ["bench", "--suite", "build", "--tets", "1000", "--repeat", "1", "--out"]
    code, text = _cli([*args, kept], capsys)
    assert code == 2 and f"--out {kept} exists" in text and "--overwrite" in text, text
    code, text = _cli([*args, tmp_path / "v2.npz"], capsys)
    assert code == 2 and "ending in .json" in text and not (tmp_path / "v2.npz").exists(), text
    assert kept.read_text() == "earlier"


def test_model_build_does_not_replace_the_vtu_unasked(tmp_path, capsys, model_path):
    """--out was protected, --vtu was not: `model build --out new.npz --vtu keep.vtu` replaced keep.vtu."""
    keep = tmp_path / "keep.vtu"
    keep.write_text("a mesh")
    code, text = _cli(["model", "build", "--tets", "1000", "--out", tmp_path / "new.npz", "--vtu", keep], capsys)
    assert code == 2 and f"--vtu {keep} exists" in text and "--overwrite" in text, text
    assert keep.read_text() == "a mesh" and not (tmp_path / "new.npz").exists()


@pytest.mark.parametrize(
    ("args", "code", "said"),
    [  # a user's pass with bad input: each was silently taken, or answered with the wrong reason
        (["track", "--mocap", "none.c3d", "--tets", "3000"], 2, "--tets does nothing here"),  # with --model
        (["demo", "--dropout", "0.95"], 2, "leaves too few markers to track"),
        (["simulate", "--activation", "frontalis_medial_l=0.5", "--activation", "frontalis_medial_l=0.9"], 1,
         "frontalis_medial_l is given twice (0.5 and 0.9)"),
        (["resim", "--activation", "none", "--activation", "mentalis_l=1"], 1, "'none' stands alone"),
        (["edit", "blend", "--from", "smile", "--to", "surprise", "--neutral", "foo"], 2, "--neutral does nothing"),
    ],
)  # fmt: skip
def test_options_taken_wrong_are_said(tmp_path, capsys, model_path, args, code, said):
    if args[0] in ("track", "simulate"):
        args = [args[0], "--model", model_path, *args[1:]]
    got, text = _cli([*args, "--out", tmp_path / "o"], capsys)
    assert got == code and said in text, text


def test_a_negative_number_list_is_a_value():
    """`--head-shake -10,3` was read as an unknown option (it worked only as --head-shake=-10,3)."""
    from wface.cli import build_parser

    args = build_parser().parse_args(["resim", "--out", "o", "--head-shake", "-10,3", "--damping", "0,-2e-4"])
    assert args.head_shake == "-10,3" and args.damping == "0,-2e-4"


def test_import_of_a_file_says_it_is_a_file(tmp_path, capsys):
    f = tmp_path / "face.txt"
    f.write_text("x")
    code, text = _cli(["model", "import", "artisynth", f, "--out", tmp_path / "o.npz"], capsys)
    assert code != 0 and "is a file: give the ArtiSynth face's directory" in text


def test_coincident_landmarks_are_said_in_words():
    from wface.mesh.align import umeyama

    with pytest.raises(ValueError, match="all lie at one place"):
        umeyama(np.zeros((4, 3)), np.eye(4, 3))


def test_a_refused_contact_leaves_out_as_it_was(tmp_path, model_path, capsys):
    """A contact refused when it is built (a ball round the whole face) is said before --out is claimed: resim
    left a directory holding provenance.json alone."""
    out = tmp_path / "o"
    ball = ["--obstacle", "sphere:0,0,0,0.5"]
    code, text = _cli(["resim", "--model", model_path, "--frames", "3", *ball, "--out", out], capsys)
    assert code != 0 and "surface nodes at rest" in text and not out.exists(), text
