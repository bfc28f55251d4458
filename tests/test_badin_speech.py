"""Issue 9 point 3: the ArtiSynth speech gestures (excitation curves) played on the Badin face.

Parsing is checked against exact values from the files; the interpolation against its definition
(ArtiSynth ``CubicStep``: cubic Hermite with zero end slopes). The physics test plays a subsampled
closure (3 frames) through the CLI and checks that the lips close.
"""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from tests.conftest import data_path
from wface.model import load_model
from wface.speech.gestures import (
    held_gesture,
    interpolate,
    map_gesture_to_model,
    read_excitation_curve,
    read_gesture,
    read_probes,
)
from wface.speech.playback import gesture_times, lip_opening_mm

_EXACT = 1e-12  # float64 round-off of a few operations

BADIN_NAMES = [
    f"{b}_{s}" for b in ("DAO", "BUC", "DLI", "MENT", "OOM", "OOP", "LLSAN", "LAO", "RIS", "ZYG", "LLS") for s in "lr"
]


def _fake_model(names=BADIN_NAMES):
    return SimpleNamespace(muscle_names=list(names), n_muscles=len(names), muscle_index=list(names).index)


def test_interpolation_orders():
    kt, kv = np.array([0.0, 1.0, 3.0]), np.array([0.0, 2.0, -1.0])
    t = np.array([-1.0, 0.0, 0.5, 1.0, 2.0, 3.0, 4.0])
    assert np.allclose(interpolate(kt, kv, t, "Linear"), [0, 0, 1, 2, 0.5, -1, -1], atol=_EXACT)
    assert np.allclose(interpolate(kt, kv, t, "Step"), [0, 0, 0, 2, 2, -1, -1], atol=_EXACT)
    # CubicStep: v0 + (v1 - v0)(3s^2 - 2s^3): midpoints are the mean, quarter points 5/32 of the way
    cs = interpolate(kt, kv, np.array([0.5, 0.25, 2.0]), "CubicStep")
    assert np.allclose(cs, [1.0, 2.0 * 5 / 32, 0.5], atol=_EXACT)
    # zero slope at every knot (the "step" in CubicStep), continuous values
    h = 1e-6
    for k in kt:
        d = (
            interpolate(kt, kv, np.array([k + h]), "CubicStep") - interpolate(kt, kv, np.array([k - h]), "CubicStep")
        ) / (2 * h)
        assert abs(d[0]) < 1e-5
    with pytest.raises(ValueError, match="not supported"):
        interpolate(kt, kv, t, "SphericalCubic")


def test_implicit_time_file_and_scale(tmp_path):
    f = tmp_path / "c.txt"
    f.write_text("0.5 1.5 2.0\nLinear 1 0.25\n0.0\n1.0\n1.0\n0.0\n0.0\n")
    c = read_excitation_curve(f)
    assert np.allclose(c.times, [0.0, 0.25, 0.5, 0.75, 1.0])
    # absolute time = t0 + local time; values scaled by 2
    assert np.allclose(c.values([0.5, 0.625, 1.0, 1.125, 9.0]), [0.0, 1.0, 2.0, 1.0, 0.0], atol=_EXACT)


def test_closure_curves_parse_exactly():
    d = data_path("artisynth-face", "speech", "closure")
    oop = read_excitation_curve(d / "oop.txt")
    assert (oop.t0, oop.t1, oop.scale, oop.order, oop.vsize) == (0.0, 1.0, 1.0, "CubicStep", 1)
    assert np.array_equal(oop.times, [0.0, 0.202, 0.732, 1.0])
    assert np.array_equal(oop.data[:, 0], [0.0, 0.0, 1.0, 1.0])
    assert abs(oop.values(0.467)[0] - 0.5) < _EXACT  # midpoint of the 0.202 -> 0.732 rise
    oom = read_excitation_curve(d / "oom.txt")
    assert np.allclose(oom.values([0.0, 0.2, 0.5, 0.8, 1.0]), [0.0, 0.0, 0.15, 0.3, 0.3], atol=_EXACT)


def test_probes_active_flags_targets_and_file_precedence():
    d = data_path("artisynth-face", "speech")
    probes, outputs = read_probes(d / "closure" / "0probes.art")
    by = {p.name: p for p in probes}
    assert [p.name for p in probes] == ["OOP", "OOM", "MENT", "OOMi", "RIS", "LLSAN", "LLS"]
    assert {p.name for p in probes if p.active} == {"OOM", "MENT", "RIS"}
    assert (by["OOMi"].target, by["OOMi"].target_kind) == ("OOMl", "exciters")
    assert (by["LLS"].target, by["LLS"].attached_file) == ("LLS", "lls.txt")
    assert outputs[0]["props"] == "lipOpeningArea"
    g = read_gesture(d / "closure")
    assert sorted(g.curves) == ["MENT", "OOM", "RIS"] and g.duration_s == (0.0, 1.0)
    assert len(read_gesture(d / "closure", include_inactive=True).curves) == 7
    # approximant: the attached file (peak 0.3) replaces the inline data (peak 1.0), as in ArtiSynth
    ap = read_gesture(d / "approximant")
    assert sorted(ap.curves) == ["OOP"]
    assert ap.curves["OOP"].values(1.0)[0] == 0.3
    assert {p.name: p for p in ap.probes}["OOP"].inline_data[:, 1].max() == 1.0
    assert ap.reference_lip_area.shape == (101, 2) and ap.reference_lip_area[0, 1] > 40.0
    fr = read_gesture(d / "fricative")
    assert sorted(fr.curves) == ["LLS", "LLSAN", "MENT", "OOMi", "RIS"]


def test_mapping_drives_both_sides():
    d = data_path("artisynth-face", "speech")
    model = _fake_model()
    fr = read_gesture(d / "fricative")
    mp = map_gesture_to_model(fr, model)
    assert mp.muscles["LLS"] == ["LLS_l", "LLS_r"] and mp.muscles["OOMi"] == ["OOM_l", "OOM_r"]
    assert mp.unmapped == [] and any("OOMl" in n for n in mp.notes)
    A = mp.activations(fr, model, np.array([0.0, 0.5, 1.0]))
    assert A.shape == (3, model.n_muscles)
    assert np.allclose(A[:, model.muscle_index("LLS_l")], [0.0, 0.25, 0.5], atol=_EXACT)
    assert np.array_equal(A[:, model.muscle_index("LLS_l")], A[:, model.muscle_index("LLS_r")])
    assert np.all(A[:, model.muscle_index("OOP_l")] == 0)  # OOP is inactive in the fricative
    skip = map_gesture_to_model(fr, model, lower_oom="skip")
    assert skip.unmapped == ["OOMi"] and "OOMi" not in skip.muscles
    partial = map_gesture_to_model(fr, _fake_model(["LLS_l", "LLS_r", "MENT_l", "MENT_r"]))
    assert sorted(partial.unmapped) == ["LLSAN", "OOMi", "RIS"]


def test_bad_gesture_data_is_named_and_out_of_range_excitations_are_said(tmp_path):
    """A curve above 1 used to be clipped without a word, a bad number was "could not convert string to float"
    without the file, and a probe the model cannot play was noted only in report.json."""
    import shutil

    from wface.cli.speech import _check_model

    g = tmp_path / "closure"
    shutil.copytree(data_path("artisynth-face", "speech", "closure"), g)
    (g / "oom.txt").write_text((g / "oom.txt").read_text().replace("0.8  0.3", "0.8  1.5"))
    with pytest.warns(UserWarning, match="probe OOM's excitation runs from 0 to 1.5; it is played clipped"):
        read_gesture(g)
    (g / "ment.txt").write_text((g / "ment.txt").read_text() + "0.9 abc\n")
    with (
        pytest.warns(UserWarning, match="clipped"),
        pytest.raises(ValueError, match=r"ment.txt: data row \d+ holds a value that is not a number"),
    ):
        read_gesture(g)
    model = _fake_model(["OOM_l", "OOM_r", "MENT_l", "MENT_r"])
    model.marker_names = ["Mouth_Up", "Mouth_Down"]
    closure = read_gesture(data_path("artisynth-face", "speech", "closure"))
    mapping = map_gesture_to_model(closure, model)
    assert mapping.unmapped == ["RIS"]
    with pytest.warns(UserWarning, match="probe RIS is not played: probe RIS drives RIS, which the model does not"):
        _check_model(SimpleNamespace(model="m.npz"), model, closure, mapping)


def test_held_gesture_holds_each_level_for_one_frame():
    """The approximant's OOP held at 0.05, 0.1, 0.3: played at 1 fps, frame k drives OOP_l/OOP_r at
    level k and nothing else (the held-excitation apertures of docs/design.md, "Speech gestures")."""
    g = read_gesture(data_path("artisynth-face", "speech") / "approximant")
    model = _fake_model()
    levels = [0.05, 0.1, 0.3]
    h = held_gesture(g, levels)
    assert list(h.curves) == ["OOP"] and h.duration_s == (0.0, 2.0) and h.reference_lip_area is None
    t = gesture_times(*h.duration_s, 1.0)
    A = map_gesture_to_model(h, model).activations(h, model, t)
    for side in "lr":
        assert np.array_equal(A[:, model.muscle_index(f"OOP_{side}")], levels)
    assert np.count_nonzero(A) == 2 * len(levels)
    assert g.curves["OOP"].values(0.5)[0] != 0.05  # the input gesture is unchanged
    with pytest.raises(ValueError, match=r"in \[0, 1\]"):
        held_gesture(g, [0.2, 1.5])
    with pytest.raises(ValueError, match="no probe 'ZYG'"):
        held_gesture(g, [0.2], probe="ZYG")


def test_frame_times_and_lip_opening():
    t = gesture_times(0.0, 1.0, 25.0)
    assert len(t) == 26 and t[0] == 0.0 and abs(t[-1] - 1.0) < _EXACT
    assert np.allclose(gesture_times(0.0, 0.9, 4.0), [0.0, 0.25, 0.5, 0.75, 0.9], atol=_EXACT)  # end kept
    sub = gesture_times(0.0, 1.0, 100.0, max_frames=3)
    assert len(sub) == 3 and sub[0] == 0.0 and sub[-1] == 1.0
    m = np.zeros((2, 3, 3))
    m[:, 2, 1] = [0.01, 0.004]
    assert np.allclose(lip_opening_mm(m, ["Mouth_Down", "x", "Mouth_Up"]), [10.0, 4.0])


@pytest.mark.slow
def test_closure_closes_the_lips_cli(tmp_path, badin_model_path):
    from wface.cli import main

    face = badin_model_path  # the import itself (--model DIR) is tested in test_artisynth.py
    out = tmp_path / "closure"
    args = ["speech", "--model", str(face), "--gesture", "closure", "--max-frames", "3", "--out", str(out)]
    assert main([*args, "--no-rig"]) == 0  # the rig: one ~20 s solve per muscle here (test_usd_rig.py tests it)
    rep = json.loads((out / "report.json").read_text())
    assert rep["frames"] == 3 and rep["all_converged"] and rep["inverted_elements_max"] == 0
    assert rep["probe_to_muscles"]["OOM"] == ["OOM_l", "OOM_r"]
    assert rep["material"]["mu20_pa"] == 1175.0 and rep["material"]["fibre_stress"] == "uniaxial"  # the import's
    header = (out / "lip_opening.csv").read_text().splitlines()[0].split(",")
    table = np.loadtxt(out / "lip_opening.csv", delimiter=",", skiprows=1)
    t, lo = table[:, 0], table[:, header.index("lip_opening_mm")]
    area = table[:, header.index("lip_opening_area_mm2")]
    assert np.allclose(t, [0.0, 0.5, 1.0])  # 101 frames at 100 fps, subsampled to 3
    # the aperture: 39.5 mm^2 at rest (ArtiSynth's camera), shut once the lips pass through each other
    assert area[0] == pytest.approx(39.5, abs=0.5) and area[1] == 0.0 and area[2] == 0.0
    # ArtiSynth counts every green pixel of its window; here nothing but the mouth shows any of it
    seen = table[:, header.index("window_seen_mm2")]
    assert np.allclose(seen, area, rtol=0, atol=1e-9) and np.allclose(rep["window_seen_mm2"], seen, atol=1e-4)
    # measured: 17.19 -> 7.70 (t = 0.5) -> 5.72 mm; the lips close steadily as OOM, MENT and RIS rise
    assert lo[1] < lo[0] - 5.0 and lo[2] < lo[1] - 1.0 and lo[2] < lo[0] - 8.0
    assert (out / "lip_opening.png").stat().st_size > 1000 and (out / "animation.usdc").stat().st_size > 1000
    # every frame's state, for measures of one's own: the CSV's curves come back from it
    st = np.load(out / "states.npz")
    model = load_model(face)
    assert st["node_positions_m"].shape == (3, model.n_nodes, 3) and np.allclose(st["times_s"], t)
    assert list(st["muscle_names"]) == model.muscle_names and st["activations"].shape == (3, model.n_muscles)
    assert np.allclose(lip_opening_mm(st["markers_m"], list(st["marker_names"])), lo, atol=1e-5)
    assert np.allclose(st["lip_opening_area_mm2"], area, atol=1e-5) and st["converged"].all()
    assert "kinetic_energy_j" not in st.files  # quasistatic
    # without contact the closing lips pass through each other (measured: 6 mm at t = 1 s)
    assert rep["contact"] is None and rep["lip_gap_mm"][0] > 0 and rep["lip_gap_mm_min"] < -3.0


def test_speech_refuses_to_write_over_another_runs_results(tmp_path, badin_model_path, capsys):
    """A tracking output is not replaced by a speech run (it used to be, report.json included)."""
    from wface.cli import main

    out = tmp_path / "tracked"
    out.mkdir()
    (out / "report.json").write_text('{"frames": 20}')
    (out / "provenance.json").write_text('{"kind": "track", "fingerprint": "cca979150a86ef45"}')
    args = ["speech", "--model", str(badin_model_path), "--gesture", "closure", "--max-frames", "2", "--no-usd"]
    assert main([*args, "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "holds another take's results" in err and "--overwrite" in err, err
    assert (out / "report.json").read_text() == '{"frames": 20}'


def test_closure_with_lip_contact_cli(tmp_path, badin_model_path, capsys):
    from wface.cli import main

    out = tmp_path / "closure_contact"
    args = ["speech", "--model", str(badin_model_path), "--gesture", "closure", "--max-frames", "3", "--no-usd"]
    assert main(args + ["--contact", "lips", "--max-iterations", "25", "--out", str(out)]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["contact"] == "lips" and rep["inverted_elements_max"] == 0
    # The lips meet without passing through each other, up to the penalty (half the 0.1 mm C2 ramp plus
    # k-dependent micrometres) and the rounding of the smooth lip surfaces, inside which the faceted
    # lips overlap by up to 0.17 mm (measured gap on the faceted lips: +0.061, -0.166, -0.130 mm against
    # -6 mm without contact; with the old law, 1175 Pa as mu01, -0.129 and -0.122: ArtiSynth's C10 + C20
    # flesh is 32 % softer at small strain, and so is the penalty k = 100 x 6 (mu10 + mu01) h; frames
    # 0.5 s apart converge in 24 and 8 Newton iterations).
    assert len(rep["lip_gap_mm"]) == 3 and min(rep["lip_gap_mm"]) > -0.2
    assert rep["max_penetration_mm_max"] < 0.2
    assert "lip gap min" in capsys.readouterr().out
    assert main(args + ["--contact", "lips,gums", "--out", str(out)]) == 2  # a usage error
    # The smooth lips offset through their nodes meet nearer the faceted lips: measured on the second frame
    # -0.094 mm against the plain blend's -0.166 (the third: -0.146 against -0.130, its deepest point near a
    # lip's rim, where the contact tapers off)
    through = tmp_path / "closure_through_nodes"
    opts = ["--contact", "lips", "--lip-surface", "smooth_through_nodes", "--max-iterations", "25"]
    assert main(args + opts + ["--out", str(through)]) == 0
    rep_t = json.loads((through / "report.json").read_text())
    assert rep_t["lip_surface"] == "smooth_through_nodes" and rep_t["inverted_elements_max"] == 0
    assert rep_t["lip_gap_mm"][1] > rep["lip_gap_mm"][1] + 0.05


@pytest.mark.slow
def test_example_runs_headless(tmp_path, badin_model_path):
    """examples/badin_speech.py doubles as a test: one gesture, 3 frames, quasistatic and dynamic (with
    0.25 s steps: the example's integration, not its accuracy)."""
    import importlib.util
    from pathlib import Path

    face = data_path("artisynth-face")
    path = Path(__file__).resolve().parents[1] / "examples" / "badin_speech.py"
    spec = importlib.util.spec_from_file_location("badin_speech_example", path)
    ex = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ex)
    s = ex.run(
        tmp_path,
        gestures=("approximant",),
        variants=("quasistatic", "dynamic"),
        max_frames=3,
        max_step_ms=250.0,
        data=face,
        model_path=badin_model_path,
    )
    q, d = s["approximant"]["quasistatic"], s["approximant"]["dynamic"]
    assert q["probe_to_muscles"] == {"OOP": ["OOP_l", "OOP_r"]}
    assert q["all_converged"] and d["all_converged"] and d["mode"] == "dynamic"
    # the rest shape's aperture in ArtiSynth's camera: 39.5 mm^2 (the original records 40.1 at t = 0)
    assert q["lip_opening_area_mm2"][0] == pytest.approx(39.5, abs=0.5)
    assert d["lip_opening_area_mm2"][0] == q["lip_opening_area_mm2"][0]  # the same start
    assert q["reference_comparison"]["original"]["settled_mm2"] == pytest.approx(53.2, abs=0.1)
    assert (tmp_path / "lip_opening_area_all.png").exists() and (
        tmp_path / "approximant" / "dynamic" / "animation.usdc"
    ).exists()

    def must_not_play(*args, **kwargs):
        raise AssertionError("resume played a variant that was already written")

    # the held-OOP study on the demo setup (ArtiSynth's flesh law): more excitation, a smaller aperture
    held = ex.held_oop(tmp_path / "held", [0.01, 0.02], steps=ex.HELD_STEPS[:1], data=face, model_path=badin_model_path)
    h = held[ex.HELD_STEPS[0][0]]
    assert h["converged"] and 0 < h["area_mm2"][1] < h["area_mm2"][0] < q["lip_opening_area_mm2"][0]
    assert (tmp_path / "held" / "held_oop.png").exists()

    ex.play = must_not_play  # resume reads both variants back from their report.json
    again = ex.run(tmp_path, gestures=("approximant",), variants=("quasistatic", "dynamic"), resume=True, data=face)
    assert again["approximant"]["dynamic"]["lip_opening_area_mm2"] == d["lip_opening_area_mm2"]


def test_dynamic_playback_area_outputs_cli(tmp_path, badin_model_path):
    """``--dynamic`` with ArtiSynth's damping and the area in report.json, CSV, plot and USD (2 frames,
    100 ms steps: the outputs, not the accuracy)."""
    from pxr import Usd

    from wface.cli import main

    out = tmp_path / "dyn"
    args = ["speech", "--model", str(badin_model_path), "--gesture", "approximant", "--max-frames", "2"]
    assert main(args + ["--dynamic", "--max-step-ms", "100", "--out", str(out)]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["mode"] == "dynamic" and rep["all_converged"]
    assert rep["dynamics"]["alpha_per_s"] == 19.0 and rep["dynamics"]["beta_s"] == 0.055
    assert rep["dynamics"]["gravity_m_s2"] == [0.0, -9.8, 0.0] and rep["dynamics"]["density_kg_m3"] == 1040.0
    area = rep["lip_opening_area_mm2"]
    assert len(area) == 2 and area[0] == pytest.approx(39.5, abs=0.5)
    assert rep["lip_opening_area_view"]["name"] == "artisynth" and rep["lip_opening_area_error_mm2_max"] < 0.1
    header = (out / "lip_opening.csv").read_text().splitlines()[0].split(",")
    assert header[:2] == ["time_s", "lip_opening_area_mm2"]
    stage = Usd.Stage.Open(str(out / "animation.usdc"))
    attr = stage.GetDefaultPrim().GetAttribute("wface:lipOpeningArea_mm2")
    assert [attr.Get(Usd.TimeCode(f)) for f in (0, 1)] == pytest.approx(area, abs=1e-4)  # float32 samples
    meta = stage.GetRootLayer().customLayerData["wface"]
    # write_take stores lists as JSON strings in customLayerData
    assert json.loads(meta["lip_opening_area_mm2"]) == pytest.approx(area) and meta["mode"] == "dynamic"
    for name in ("lip_opening.png", "aperture_first.png", "aperture_last.png"):
        assert (out / name).stat().st_size > 1000


def test_the_lower_lips_oom_is_the_oomi_probes_own(badin_model):
    """with_lower_oom: the OOM fibre entries nearer the lower lip's surface become OOMl_l/OOMl_r (what ArtiSynth's
    OOMl exciter drives); played with every OOM part at one activation the split model is the one it was (same
    forces), the fricative's OOMi probe drives the lower part alone, and the closure's OOM bundle every part."""
    from wface.physics import Simulator
    from wface.speech.gestures import with_lower_oom

    split = with_lower_oom(badin_model)
    assert split.muscle_names[-2:] == ["OOMl_l", "OOMl_r"] and split.n_muscles == badin_model.n_muscles + 2
    y = split.rest_positions_m[split.tets[split.fibre_tet]].mean(axis=1)[:, 1]  # up
    for side in ("l", "r"):
        upper, lower = (split.fibre_muscle == split.muscle_index(f"{n}_{side}") for n in ("OOM", "OOMl"))
        assert upper.sum() > 1000 and lower.sum() > 1000
        mouth = np.mean([split.marker_positions_m[split.marker_names.index(m)][1] for m in ("Mouth_Up", "Mouth_Down")])
        assert np.median(y[lower]) < mouth < np.median(y[upper])  # the lower lip's part lies below the mouth line
    x = badin_model.rest_positions_m * np.array([1.03, 0.98, 1.01])
    a = np.linspace(0.1, 0.6, badin_model.n_muscles)
    oom = [badin_model.muscle_index(n) for n in ("OOM_l", "OOM_r")]
    a_split = np.concatenate([a, a[oom]])
    f0, f1 = Simulator(badin_model).forces(x, a), Simulator(split).forces(x, a_split)
    np.testing.assert_allclose(f1, f0, rtol=0, atol=1e-12 * np.abs(f0).max())
    d = data_path("artisynth-face", "speech")
    fr = map_gesture_to_model(read_gesture(d / "fricative"), split, lower_oom="lower")
    assert fr.muscles["OOMi"] == ["OOMl_l", "OOMl_r"]
    # "exciter": the same mapping, on a split made from the exciter's own targets (the split is the caller's)
    assert map_gesture_to_model(read_gesture(d / "fricative"), split, lower_oom="exciter").muscles == fr.muscles
    assert map_gesture_to_model(read_gesture(d / "closure"), split).muscles["OOM"] == [
        "OOM_l",
        "OOM_r",
        "OOMl_l",
        "OOMl_r",
    ]
    for unsplit in ("lower", "exciter"):
        with pytest.raises(ValueError, match="with_lower_oom"):
            map_gesture_to_model(read_gesture(d / "fricative"), badin_model, lower_oom=unsplit)


def test_fricative_with_the_lower_lips_oom_cli(tmp_path, badin_model_path):
    """--lower-oom lower: the OOMi probe drives OOMl_l/OOMl_r, the split's new muscles (report and CSV say so)."""
    from wface.cli import main

    out = tmp_path / "fricative_lower"
    args = ["speech", "--model", str(badin_model_path), "--gesture", "fricative", "--max-frames", "2", "--no-usd"]
    assert main([*args, "--lower-oom", "lower", "--out", str(out)]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert any("OOMl_l/OOMl_r" in n for n in rep["notes"]), rep["notes"]
    header = (out / "lip_opening.csv").read_text().splitlines()[0].split(",")
    assert "a_OOMl_l" in header and "a_OOM_l" not in header
