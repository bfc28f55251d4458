"""examples/fidelity_animface.py, cheek_puff.py, lip_sneer.py and upper_face.py run headless with tiny options on the
real AnimFace capture (skipped without ../shared/data); lip_slide.py's penalty is checked against finite differences."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import data_path
from wface.model import load_model

_EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _example(name: str):
    spec = importlib.util.spec_from_file_location(name, _EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_fidelity_table_on_two_jaw_frames(tmp_path, monkeypatch):
    monkeypatch.setenv("WFACE_DATA", str(data_path("animface").parent))
    out = tmp_path / "fid"
    args = ["--out", str(out), "--takes", "Jaw", "--tets", "2000", "--frames", "4", "--step", "2"]
    assert _example("fidelity_animface").main(args) == 0
    res = json.loads((out / "fidelity.json").read_text())
    assert set(res) == {"Jaw/builtin", "Jaw/fitted"}
    for r in res.values():
        assert r["frames"] == 2 and len(r["holdout_markers"]) == 41 // 5
        assert 0 < r["marker_rms_mm_mean"] < 10 and 0 < r["holdout_rms_mm_mean"] < 20
    # the fitted face passes through the neutral frame: its first frame (file frame 0) fits closer
    fitted = json.loads((out / "Jaw_fitted" / "report.json").read_text())["marker_rms_mm"][0]
    builtin = json.loads((out / "Jaw_builtin" / "report.json").read_text())["marker_rms_mm"][0]
    assert fitted < builtin
    assert "| Jaw | fitted | 2 |" in (out / "fidelity.md").read_text()
    # errors in the actor's millimetres: the capture comes onto the built-in face scaled by ~0.9, onto
    # the face fitted to it by 1
    assert 0.85 < res["Jaw/builtin"]["capture_to_model_scale"] < 0.95
    assert abs(res["Jaw/fitted"]["capture_to_model_scale"] - 1.0) < 0.01
    for r in res.values():
        s = r["capture_to_model_scale"]
        assert r["marker_rms_capture_mm_mean"] == pytest.approx(r["marker_rms_mm_mean"] / s, rel=1e-12)
        assert r["holdout_rms_capture_mm_mean"] == pytest.approx(r["holdout_rms_mm_mean"] / s, rel=1e-12)


def test_cheek_puff_analysis(tmp_path, monkeypatch):
    monkeypatch.setenv("WFACE_DATA", str(data_path("animface").parent))
    out = tmp_path / "cheeks"
    assert _example("cheek_puff").main(["--out", str(out), "--tets", "2000", "--frames", "300"]) == 0
    res = json.loads((out / "cheek_puff.json").read_text())
    assert len(res["cheek_markers"]) == 6 and (out / "cheek_puff.png").stat().st_size > 0
    # in the first 5 s the cheeks puff out by several mm, beyond what every outward muscle at 1 does
    puffed = [
        n
        for n in res["cheek_markers"]
        if res["capture_outward_max_mm"][n] > res["model_outward_all_pushers_on_mm"][n] + 2
    ]
    assert len(puffed) >= 3


def test_lip_sneer_analysis(tmp_path, monkeypatch):
    monkeypatch.setenv("WFACE_DATA", str(data_path("animface").parent))
    out = tmp_path / "sneer"
    assert _example("lip_sneer").main(["--out", str(out), "--tets", "2000", "--frames", "300"]) == 0
    res = json.loads((out / "lip_sneer.json").read_text())
    assert res["markers"][:2] == ["Mouth_Up", "Mouth_UpL1"] and (out / "lip_sneer.png").stat().st_size > 0
    fit = res["peak_fit"]
    # the left sneer carries the upper lip's middle 6 mm towards the actor's left while lifting it, and
    # the lip beside it back into the face: no bounded combination of the muscles makes that, even
    # for these four markers alone (the whole-face tracker leaves ~5 mm on them)
    lateral, up, forward = fit["capture_mm"]["Mouth_Up"]
    assert lateral > 5.0 and up > 4.0
    assert fit["capture_mm"]["Mouth_UpL1"][2] < -4.0
    assert fit["linear_rms_mm"] > 2.0 and fit["solved_rms_mm"] > 3.0
    assert fit["solved_residual_mm"]["Mouth_UpL1"][2] > 3.0  # the model's lip stays in front


def test_the_imported_badin_face_fits_a_known_warp_of_its_own_skin(badin_model):
    """examples/fit_badin.py: the Badin template onto its own skin scaled 8 / 5 / 3 % with a 3 mm bump,
    told only that surface and its 10 markers' warped places."""
    rep = _example("fit_badin").fit_to_warp(badin_model)
    assert rep["surface_distance_mm"]["mean"] < 0.5 and rep["landmark_rms_mm"] < 0.5  # the 0.5 mm
    assert rep["skin_to_warped_surface_mm"]["mean"] < 0.5 and rep["skin_to_warped_surface_mm"]["max"] < 1.5
    assert rep["inverted_tets"] == 0 and rep["quality_after"]["min_dihedral_deg"] > 5.0  # 6.7 before
    assert 1.03 < rep["scale"] < 1.08  # the warp's mean scale, from the landmarks


def test_the_imported_badin_face_fits_the_jaw_capture_neutral_frame(badin_model):
    """examples/fit_badin.py: the Badin template onto the JawMoCap neutral frame, its 8 AnimFace-named
    markers alone. The capture's markers do not sit where Badin's do (upper to lower lip 1.7 times the
    scaled template's distance), so the skin stretches near them and the relaxation leaves a sliver
    there; the interior smoothing raises it back to the template's worst tet."""
    rep = _example("fit_badin").fit_to_markers(badin_model, data_path("animface", "JawMoCap.c3d"))
    assert rep["landmark_rms_mm"] < 0.2 and rep["inverted_tets"] == 0  # measured 0.12 mm
    # measured: min dihedral 6.71 (template) -> 2.06 (relaxed) -> 6.72 deg
    assert rep["quality_relaxed"]["min_dihedral_deg"] < 3.0
    assert rep["quality_after"]["min_dihedral_deg"] > 6.5
    assert rep["quality_after"]["min_volume_ratio"] >= rep["quality_before"]["min_volume_ratio"]


def test_jaw_closing_past_rest_on_cheeks(tmp_path, monkeypatch, capsys):
    """examples/jaw_closing.py: in CheeksMoCap's first puff the actor's jaw closes past the neutral frame;
    with rest as the closed limit the tracked jaw sits on it, with the freeway space it closes."""
    monkeypatch.setenv("WFACE_DATA", str(data_path("animface").parent))
    out = tmp_path / "jaw"
    args = ["--out", str(out), "--tets", "2000", "--frames", "150:162"]
    assert _example("jaw_closing").main(args) == 0
    # the run with rest as the closed limit says so, naming the cure (the closing run sits on its own limit)
    err = capsys.readouterr().err
    assert "wface: warning: the tracked jaw sat on its closed limit (0.0 deg) in 100 % of the frames" in err
    assert "no closing range past its rest" in err and "`wface model build`" in err
    report = json.loads((out / "closed_at_rest" / "report.json").read_text())
    assert report["jaw_on_closed_limit_fraction"] > 0.5
    res = json.loads((out / "jaw_closing.json").read_text())
    assert (out / "jaw_closing.png").stat().st_size > 0 and res["closing_limit_deg"] > 2.0
    closed, closing = res["closed_at_rest"], res["closing"]
    assert closed["frames_on_the_closed_limit"] > 0.5 and closed["jaw_opening_min_deg"] > -1e-3
    assert closing["jaw_opening_min_deg"] < -0.5
    assert closing["used_mean_mm"] < closed["used_mean_mm"]


def test_upper_face_analysis(tmp_path, monkeypatch):
    monkeypatch.setenv("WFACE_DATA", str(data_path("animface").parent))
    out = tmp_path / "upper"
    assert _example("upper_face").main(["--out", str(out), "--tets", "2000", "--takes", "Eyebrows", "Cheeks"]) == 0
    res, cheeks = json.loads((out / "upper_face.json").read_text())["analysis"]
    assert (out / "upper_face.png").stat().st_size > 0
    # the bone-fixed eye corners and nasion hold the head: their residual stays near the capture's noise;
    # in CheeksMoCap's lift the eye corners move with the cheeks, and the analysis says so
    assert res["stable_residual_mm_median"] < 0.6 and res["head_motion_removed_reliably"]
    assert cheeks["stable_residual_mm_median"] > 1.5 and not cheeks["head_motion_removed_reliably"]
    cap, reach = res["capture_max_mm"], res["model_reach"]
    # in the brow raise the forehead's skin moves 3-4 mm out of the face and its middle 6 mm down,
    # where every muscle that moves it that way, fully on, moves it less than 1 mm
    for name in ("ForeHead_L", "ForeHead_M"):
        assert cap[name]["out"] > reach[name]["out"]["all_movers_on_mm"] + 2.5
    assert cap["ForeHead_M"]["down"] > 5.0 > 1.0 > reach["ForeHead_M"]["down"]["all_movers_on_mm"]
    # the raised brow goes higher than the frontalis takes it, and both brows are drawn to the midline
    # three times as far as the corrugator draws them (the pinned frontalis and corrugator are the capture's)
    assert cap["Reyebrow_M"]["up"] > reach["Reyebrow_M"]["up"]["all_movers_on_mm"] + 1.0
    for name in ("Leyebrow_M", "Reyebrow_M"):
        assert cap[name]["medial"] > 2.0 * reach[name]["medial"]["all_movers_on_mm"] + 1.0
        assert reach[name]["medial"]["strongest"][0].startswith("corrugator")
    assert "medial" not in cap["ForeHead_M"] and "medial" not in reach["Eyebrow_Center"]  # the midline's markers


def test_upper_face_glide_faces():
    upper = _example("upper_face")
    base = upper.build_face(2000)
    x = base.rest_positions_m
    faces = {top: upper.glide_face(2000, from_mm=40.0, top=top) for top in ("held", "skin", "free")}
    kept = {top: set(m.attached_nodes.tolist()) for top, m in faces.items()}
    before = set(base.attached_nodes.tolist())
    assert kept["free"] < kept["skin"] < kept["held"] < before
    freed = np.array(sorted(before - kept["held"]))
    theta = np.arctan2(x[freed, 0], x[freed, 2])
    assert (x[freed, 1] >= 0.040).all() and (np.abs(theta) <= upper.TEMPORAL_LINE_RAD).all()
    assert (x[freed, 1] < upper.TOP_EDGE_M).all()  # "held": the top edge stays whole
    edge = np.array(sorted(kept["held"] - kept["free"]))
    assert (x[edge, 1] > upper.TOP_EDGE_M).all()
    skin = set(np.unique(base.skin_triangles).tolist())
    assert all(i in skin for i in kept["skin"] - kept["free"])  # "skin": only the edge's skin nodes held
    # the freed nodes' bones and the rest of the face are unchanged
    m = faces["held"]
    assert np.array_equal(m.attached_bone, base.attached_bone[np.isin(base.attached_nodes, m.attached_nodes)])
    assert m.metadata["glide"] == {"from_mm": 40.0, "top_edge": "held", "freed_nodes": len(freed)}


def test_upper_face_variants_run(tmp_path, monkeypatch):
    """--variants tracks every glide-plane face and the stronger frontalis, and tabulates them."""
    monkeypatch.setenv("WFACE_DATA", str(data_path("animface").parent))
    out = tmp_path / "variants"
    args = ["--out", str(out), "--tets", "2000", "--takes", "Jaw", "--frames", "2", "--variants"]
    assert _example("upper_face").main([*args, "--frontalis-strength", "2"]) == 0
    rows = json.loads((out / "upper_face.json").read_text())["variants"]
    assert len(rows) == 9 and rows[0]["face"] == "built-in face"
    assert len((out / "variants.md").read_text().splitlines()) == 2 + 9
    for r in rows:
        assert 0 < r["used_below_the_brows_mm"] < 10 and 0 < r["held_out_mm"] < 20
    base, strong = load_model(out / "builtin.npz"), load_model(out / "builtin_frontalis2.npz")
    frontalis = np.array([n.startswith("frontalis") for n in base.muscle_names])
    assert np.array_equal(strong.muscle_strength, np.where(frontalis, 2.0, 1.0) * base.muscle_strength)


def test_lip_analysis_on_the_jaw_take(tmp_path, monkeypatch):
    """lip_sneer.py --take Jaw: JawMoCap pouts the upper lip 5.1 mm forward where the muscles push it 3.6 mm
    (5,280 tets; the coarse 2,000-tet face reaches 4.7)."""
    monkeypatch.setenv("WFACE_DATA", str(data_path("animface").parent))
    out = tmp_path / "jaw_lip"
    assert _example("lip_sneer").main(["--out", str(out), "--tets", "5000", "--take", "Jaw"]) == 0  # 2,000: 4.7
    res = json.loads((out / "lip_sneer.json").read_text())
    assert res["take"] == "Jaw"
    reach = res["model_reach"]["Mouth_Up"]["+forward"]["all_movers_on_mm"]
    assert res["capture_max_mm"]["Mouth_Up"]["forward"] > reach + 1.0 > 2.0


def test_lip_slide_penalty_is_a_consistent_energy():
    """examples/lip_slide.py's sliding-plane penalty, patched into the Simulator and its stiffness: its forces are
    minus the energy's gradient (central differences, float64), its K v the forces' derivative, the assembled and
    matrix-free stiffness agree, a displacement within the planes costs nothing, and leaving the block restores
    the Simulator."""
    from wface.faces.builtin import build_face
    from wface.physics.penalty import default_contact_stiffness
    from wface.physics.simulator import Simulator

    slide = _example("lip_slide")
    face = build_face(1500)
    sim = Simulator(face, precision="float64")
    rng = np.random.default_rng(3)
    x = face.rest_positions_m + 2e-4 * rng.standard_normal(face.rest_positions_m.shape)
    x[face.attached_nodes] = face.rest_positions_m[face.attached_nodes]
    a = np.zeros(face.n_muscles)
    v = rng.standard_normal(x.shape)
    v[face.attached_nodes] = 0.0
    e_plain, f_plain = sim.energy_and_forces(x, a)
    diag_plain = sim.tangent(x, a, project=False).diagonal()
    with slide.sliding_upper_lip(1.0, 0.5, 25.0):
        nodes, n = slide.held_nodes(face, 0.5, np.radians(25.0))
        assert nodes.size > 3 and np.allclose(np.linalg.norm(n, axis=1), 1.0)
        e, f = sim.energy_and_forces(x, a)
        h = 1e-7
        slope = (sim.energy(x + h * v, a) - sim.energy(x - h * v, a)) / (2 * h)
        assert slope == pytest.approx(-np.sum(f * v), rel=1e-6)
        spring = f - f_plain  # the penalty's own forces: on the held nodes only, along their normals
        assert e > e_plain and np.abs(np.delete(spring, nodes, axis=0)).max() == 0.0
        assert np.allclose(np.cross(spring[nodes], n), 0.0, atol=1e-12)
        tangent = sim.tangent(x, a, project=False)
        kv = tangent.matvec(v)
        df = (sim.forces(x + h * v, a) - sim.forces(x - h * v, a)) / (2 * h)
        np.testing.assert_allclose(kv, -df, atol=1e-6 * np.abs(kv).max())
        free = sim.pattern("free")
        assembled = free.scatter(tangent.assemble(free) @ free.gather(v))
        u = face.free_nodes  # K_UU v_U: the rows of the unknowns (v is zero on the attached nodes)
        np.testing.assert_allclose(assembled[u], kv[u], atol=1e-9 * np.abs(kv).max())
        k = default_contact_stiffness(face)  # stiffness factor 1
        np.testing.assert_allclose(tangent.diagonal()[nodes] - diag_plain[nodes], k * n**2, rtol=1e-9)
        along = face.rest_positions_m.copy()  # 1 mm along each held node's plane: no penalty energy
        t = np.cross(n, [1.0, 0.0, 0.0])
        along[nodes] += 1e-3 * t / np.linalg.norm(t, axis=1, keepdims=True)
        e_along = sim.energy(along, a)
    assert e_along == pytest.approx(sim.energy(along, a), rel=1e-12)  # the flesh's own energy there, unpatched
    assert sim.energy(x, a) == pytest.approx(e_plain, rel=1e-12)  # leaving the block restored the Simulator
