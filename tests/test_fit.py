"""Template fitting (wface.faces.fit, wface.faces.registration): known warps recovered, tets kept
positive, fitted models saved, loaded and validated, the command line, and real targets."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial import cKDTree

from tests.conftest import data_path
from wface.cli import main
from wface.faces import build_face
from wface.faces.fit import fit_template, ict_feature_landmarks
from wface.faces.registration import register_surface
from wface.mesh.closest import SurfaceQuery
from wface.mesh.improve import tet_sine_quality_deg
from wface.mesh.meshfile import SurfaceMesh, read_surface_mesh
from wface.mesh.quality import volume_ratio_quality
from wface.mesh.surface import boundary_faces
from wface.model import load_model, save_model

_WARP_TOL_MM = 0.5  # the bound on skin and markers for a smooth warp of the template itself
_NEAR_MARKER_M = 0.015  # skin within 15 mm of a landmark: where the correspondence is observable
_SURFACE_MAX_MM = 1.5  # worst skin vertex off the warped surface (a 5K face's skin edges are ~8 mm)


@pytest.fixture(scope="module")
def face():
    return build_face(5000)


def _smooth_warp(x: np.ndarray) -> np.ndarray:
    """Anisotropic scale, a shift and a broad bump: 3 mm over ~5 cm (m -> m)."""
    y = x * np.array([1.05, 0.97, 1.02]) + np.array([0.003, -0.002, 0.001])
    bump = np.exp(-np.sum((x - np.array([0.03, -0.04, 0.08])) ** 2, axis=1) / 0.05**2)
    return y + 0.003 * bump[:, None] * np.array([0.3, 0.2, 1.0])


def _strong_warp(x: np.ndarray) -> np.ndarray:
    """20 % wider, 15 % shorter, 10 % deeper, a 6 mm bulge on one cheek and a 6 mm dent on the brow."""
    y = x * np.array([1.2, 0.85, 1.1])
    bulge = np.exp(-np.sum((x - np.array([0.04, -0.04, 0.07])) ** 2, axis=1) / 0.025**2)
    dent = np.exp(-np.sum((x - np.array([-0.03, 0.03, 0.08])) ** 2, axis=1) / 0.025**2)
    return y + 0.006 * bulge[:, None] * np.array([0.5, 0.0, 1.0]) - 0.006 * dent[:, None] * np.array([0, 0, 1.0])


def _target(face, warp) -> tuple[SurfaceMesh, dict]:
    skin = face.skin_triangles
    mesh = SurfaceMesh(
        points=warp(face.rest_positions_m),
        face_vertex_counts=np.full(len(skin), 3, np.int32),
        face_vertex_indices=skin.ravel(),
        meters_per_unit=1.0,
        source="warp",
    )
    landmarks = {n: warp(p[None])[0] for n, p in zip(face.marker_names, face.marker_positions_m, strict=True)}
    return mesh, landmarks


def _in_target_frame(res, points_m: np.ndarray) -> np.ndarray:
    inv = np.linalg.inv(res.target_to_model)
    return points_m @ inv[:3, :3].T + inv[:3, 3]


def test_a_smooth_warp_of_the_template_is_recovered(face):
    mesh, landmarks = _target(face, _smooth_warp)
    res = fit_template(face, surface=mesh, landmarks=landmarks)
    skin = np.unique(face.skin_triangles)
    truth = _smooth_warp(face.rest_positions_m)
    got = _in_target_frame(res, res.model.rest_positions_m)
    markers = _in_target_frame(res, res.model.marker_positions_m)
    marker_err_mm = np.linalg.norm(markers - _smooth_warp(face.marker_positions_m), axis=1) * 1e3
    assert marker_err_mm.max() < _WARP_TOL_MM
    surface_mm = SurfaceQuery(truth, face.skin_triangles).closest(got[skin]).distance_m * 1e3
    assert surface_mm.mean() < _WARP_TOL_MM and surface_mm.max() < _SURFACE_MAX_MM
    # Along the surface only the landmarks and the smoothness say where a point belongs; near them the
    # correspondence is recovered too (far out at the patch's borders it can slide, unobservably).
    near = cKDTree(face.marker_positions_m).query(face.rest_positions_m[skin])[0] < _NEAR_MARKER_M
    corr_mm = np.linalg.norm(got[skin] - truth[skin], axis=1)[near] * 1e3
    assert np.sqrt(np.mean(corr_mm**2)) < _WARP_TOL_MM
    assert res.report.quality_after["inverted"] == 0
    assert res.report.as_dict()["surface_distance_mm"]["mean"] < _WARP_TOL_MM


@pytest.fixture(scope="module")
def strong_fits(face):
    """The strong warp fitted with and without the interior smoothing (the registration is deterministic)."""
    mesh, landmarks = _target(face, _strong_warp)
    return fit_template(face, surface=mesh, landmarks=landmarks), fit_template(
        face, surface=mesh, landmarks=landmarks, smooth_interior=False
    )


def test_a_strong_warp_keeps_every_tet_positive(strong_fits):
    res, _ = strong_fits
    vol = res.model.rest_volume_m3
    assert vol.min() > 0 and res.report.quality_after["inverted"] == 0
    rep = res.report.as_dict()
    assert rep["quality_before"]["min_dihedral_deg"] > 0 and rep["quality_after"]["min_dihedral_deg"] > 2.0
    # the skin really went to the strongly warped target (20 % wider is 13 mm at the ears)
    assert rep["surface_distance_mm"]["mean"] < 1.0


def _fit_quality(template, x: np.ndarray) -> np.ndarray:
    """Per tet, the smoothing's objective (deg): min(sine angle, goal q / q_goal), the template's worst the goals."""
    x0, tets = template.rest_positions_m, template.tets
    goal_deg, q_goal = tet_sine_quality_deg(x0[tets]).min(), volume_ratio_quality(x0, tets).min()
    return np.minimum(tet_sine_quality_deg(x[tets]), goal_deg / q_goal * volume_ratio_quality(x, tets))


def _fibre_directions(template, x: np.ndarray) -> np.ndarray:
    """d' = F d / |F d| for every fibre entry, F the deformation gradient of its tet at ``x``."""
    t = template.fibre_tet
    p = x[template.tets[t]]
    F = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]], axis=2) @ template.dm_inv[t]
    d = np.einsum("kij,kj->ki", F, template.fibre_direction)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_the_interior_smoothing_moves_free_interior_nodes_only(face, strong_fits):
    """After the relaxation the worst tets are raised by moving free interior nodes alone: skin, attached
    and other boundary nodes, markers, tets and node ids are those of the relaxed fit; fibres follow."""
    res, raw = strong_fits
    x, x_raw = res.model.rest_positions_m, raw.model.rest_positions_m
    assert np.array_equal(res.model.tets, face.tets) and len(x) == len(x_raw) == face.n_nodes
    boundary = np.zeros(face.n_nodes, dtype=bool)
    boundary[boundary_faces(face.tets).ravel()] = True
    assert np.all(boundary[np.unique(face.skin_triangles)]) and np.all(boundary[face.attached_nodes])
    assert np.array_equal(x[boundary], x_raw[boundary])  # the registered skin and the bone side stay
    moved = np.any(x != x_raw, axis=1)
    assert moved.sum() == res.report.interior_smoothing["moved_nodes"] > 0 and not np.any(moved & boundary)
    assert np.array_equal(res.model.marker_positions_m, raw.model.marker_positions_m)
    assert np.array_equal(res.model.attached_nodes, face.attached_nodes)
    assert np.array_equal(res.model.fibre_tet, face.fibre_tet)
    assert all(np.array_equal(res.model.surface_groups[k], v) for k, v in face.surface_groups.items())
    assert res.report.surface_distance_mm == raw.report.surface_distance_mm
    assert res.report.quality_relaxed == raw.report.quality_after and raw.report.interior_smoothing is None
    # the relaxation left tets well below the template's worst; the smoothing raises the worst of them
    # in both measures (measured: min dihedral 8.99 -> 6.08 -> 6.34 deg, volume ratio 0.160 -> 0.104 -> 0.113)
    q_relaxed, q_after = _fit_quality(face, x_raw).min(), _fit_quality(face, x).min()
    assert q_relaxed < 6.5 and q_after > q_relaxed + 0.2
    rel, after = res.report.quality_relaxed, res.report.quality_after
    assert after["min_dihedral_deg"] > rel["min_dihedral_deg"] and after["min_volume_ratio"] > rel["min_volume_ratio"]
    assert after["inverted"] == 0
    # fibre directions are turned by the final tets, not the relaxed ones
    np.testing.assert_allclose(res.model.fibre_direction, _fibre_directions(face, x), atol=1e-12)
    turned = moved[face.tets[face.fibre_tet]].any(axis=1)
    assert turned.any() and not np.allclose(res.model.fibre_direction[turned], raw.model.fibre_direction[turned])


def test_fibres_turn_with_the_flesh_and_the_model_round_trips(face, tmp_path):
    mesh, landmarks = _target(face, _smooth_warp)
    res = fit_template(face, surface=mesh, landmarks=landmarks)
    fitted = res.model
    path = save_model(fitted, tmp_path / "actor.npz")
    again = load_model(path)  # validates
    assert np.array_equal(again.rest_positions_m, fitted.rest_positions_m)
    assert again.metadata["fit"]["inverted_tets"] == 0
    assert "seconds" not in str(again.metadata["fit"])  # no wall-clock time: a refit hashes the same
    assert again.muscle_names == face.muscle_names and np.array_equal(again.fibre_tet, face.fibre_tet)
    assert np.array_equal(again.attached_nodes, face.attached_nodes)
    # d' = F d / |F d| with F the tet's deformation gradient, for every fibre entry
    np.testing.assert_allclose(fitted.fibre_direction, _fibre_directions(face, fitted.rest_positions_m), atol=1e-12)
    # the bones and the joint follow the cranium's similarity, which a mild warp keeps near 1.0-1.05
    assert 0.95 < res.report.bones["cranium"]["scale"] < 1.1
    assert fitted.jaw_joint.condyle_distance_m == pytest.approx(
        face.jaw_joint.condyle_distance_m * res.report.bones["cranium"]["scale"], rel=1e-9
    )


def test_a_neutral_marker_frame_alone_fits_the_face(face):
    rng = np.random.default_rng(3)
    names = list(face.marker_names)
    markers = _smooth_warp(face.marker_positions_m)
    rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # a capture in another frame
    capture = markers @ rot.T * 1.0 + np.array([0.2, 0.1, -0.05])
    capture[rng.choice(len(names), 2, replace=False)] = np.nan  # two markers missing at the neutral frame
    res = fit_template(face, markers_m=capture, marker_names=names)
    ok = np.isfinite(capture).all(axis=1)
    assert res.model.marker_names == [n for n, k in zip(names, ok, strict=True) if k]
    assert res.report.as_dict()["landmark_rms_mm"] < 1.0
    assert res.report.surface_distance_mm is None and res.report.quality_after["inverted"] == 0
    # the fitted face keeps the template's axes (+y up): the capture's rotation went into the frame
    assert np.ptp(res.model.rest_positions_m[:, 1]) == pytest.approx(np.ptp(face.rest_positions_m[:, 1]), rel=0.1)


def test_fit_refuses_a_missing_target(face):
    with pytest.raises(ValueError, match="needs a target"):
        fit_template(face)


def test_landmark_names_that_are_not_the_templates_markers_are_named(face):
    """Landmarks the template does not have used to be dropped without a word (the fit then started
    from principal axes, 0 landmarks)."""
    mesh, landmarks = _target(face, _smooth_warp)
    with pytest.raises(ValueError, match="none of the landmark names .Nose_Tip, Jaw. is one of the template's markers"):
        fit_template(face, surface=mesh, landmarks={"Nose_Tip": 0, "Jaw": 1})
    with pytest.warns(UserWarning, match="landmarks that are not the template's markers, not used: Nose_Tip"):
        fit_template(face, surface=mesh, landmarks={**landmarks, "Nose_Tip": 0})


def test_model_fit_command_on_a_mesh_file(tmp_path, capsys):
    tpl = build_face(2000)
    save_model(tpl, tmp_path / "tpl.npz")
    x = _smooth_warp(tpl.rest_positions_m) * 100.0  # centimetres, as artists model heads
    lines = [f"v {a:.6f} {b:.6f} {c:.6f}" for a, b, c in x]
    lines += [f"f {i + 1} {j + 1} {k + 1}" for i, j, k in tpl.skin_triangles]
    (tmp_path / "head.obj").write_text("\n".join(lines) + "\n")
    lm = {
        n: (_smooth_warp(p[None])[0] * 100).tolist()
        for n, p in zip(tpl.marker_names, tpl.marker_positions_m, strict=True)
    }
    (tmp_path / "lm.json").write_text(json.dumps(lm))
    rc = main(
        ["model", "fit", "--template", str(tmp_path / "tpl.npz"), "--surface", str(tmp_path / "head.obj"),
         "--landmarks", str(tmp_path / "lm.json"), "--out", str(tmp_path / "actor.npz"), "--json"]
    )  # fmt: skip
    cap = capsys.readouterr()
    assert rc == 0 and "0.01 m per unit" in cap.err and "inverted tets 0" in cap.err
    report = json.loads(cap.out)  # --json: stdout holds the report alone
    assert report["surface_distance_mm"]["mean"] < 1.0
    fitted = load_model(tmp_path / "actor.npz")
    assert np.allclose(np.asarray(fitted.metadata["fit"]["target_to_model"])[3], [0, 0, 0, 1])
    # the same head read as millimetres is a face 10x too small: refused, naming --units (it used to fit it)
    rc = main(
        ["model", "fit", "--template", str(tmp_path / "tpl.npz"), "--surface", str(tmp_path / "head.obj"),
         "--units", "mm", "--landmarks", str(tmp_path / "lm.json"), "--out", str(tmp_path / "small.npz")]
    )  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 1 and "times the template's size" in err and "check --units" in err, err
    assert not (tmp_path / "small.npz").exists()


def test_model_fit_needs_a_target(capsys):
    assert main(["model", "fit", "--out", "x.npz"]) == 1
    assert "--surface" in capsys.readouterr().err


def test_fit_to_the_real_jaw_capture_neutral_frame(face):
    from wface.io.mocap import read_mocap

    take = read_mocap(data_path("animface", "JawMoCap.c3d"))
    res = fit_template(face, markers_m=take.positions_m[0], marker_names=take.marker_names)
    rep = res.report.as_dict()
    assert rep["inverted_tets"] == 0 and rep["landmark_rms_mm"] < 1.0
    assert len(res.model.marker_names) == take.n_markers  # the actor's own markers now


def test_fit_to_the_ict_head_raises_the_worst_tets(face):
    """The built-in face onto the ICT-FaceKit head: the relaxation leaves tets well below the template's
    worst, the interior smoothing brings them back near it; the fit's accuracy is the relaxation's."""
    head = read_surface_mesh(data_path("ict-facekit", "generic_neutral_mesh.obj"))
    res = fit_template(face, surface=head, landmarks=ict_feature_landmarks())
    rep = res.report.as_dict()
    relaxed, after = rep["quality_relaxed"], rep["quality_after"]
    # measured at 5,280 tets: min dihedral 8.99 -> 6.21 -> 8.62 deg, volume ratio 0.160 -> 0.084 -> 0.124
    assert relaxed["min_dihedral_deg"] < 7.0 and after["min_dihedral_deg"] > 8.0
    assert relaxed["min_volume_ratio"] < 0.1 and after["min_volume_ratio"] > 0.11
    assert rep["inverted_tets"] == 0
    # measured: 0.14 mm mean / 1.13 mm max off the head, landmarks 0.48 mm RMS
    assert rep["surface_distance_mm"]["mean"] < 0.2 and rep["surface_distance_mm"]["max"] < 1.5
    assert rep["landmark_rms_mm"] < 0.6


_SAME_FIELD_REL = 0.15  # coarse vs fine discretisation of one continuous thin plate (measured ~7 %)


def _grid(side_m: float, h_m: float) -> tuple[np.ndarray, np.ndarray]:
    """A flat square patch of side ``side_m`` in the z = 0 plane, triangulated at spacing ``h_m``."""
    n = int(round(side_m / h_m)) + 1
    g = np.linspace(-side_m / 2, side_m / 2, n)
    X, Y = np.meshgrid(g, g, indexing="ij")
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return np.c_[X.ravel(), Y.ravel(), np.zeros(n * n)], np.r_[np.c_[a, b, c], np.c_[a, c, d]]


def _slide_centre(h_m: float) -> np.ndarray:
    """Register a 12 cm patch onto its own plane with one landmark pulling its centre 10 mm along x;
    returns the x displacement (mm) at (30, 0) mm and (0, 30) mm."""
    x, tri = _grid(0.12, h_m)
    target_v, target_t = _grid(0.2, 0.01)
    centre = int(np.argmin(np.linalg.norm(x, axis=1)))
    t = int(np.flatnonzero((tri == centre).any(axis=1))[0])
    res = register_surface(
        x,
        tri,
        target_vertices_m=target_v,
        target_triangles=target_t,
        landmark_triangles=np.array([t]),
        landmark_barycentric=(tri[t] == centre).astype(float)[None],
        landmark_targets_m=np.array([[0.01, 0.0, 0.0]]),
    )
    probes = [int(np.argmin(np.linalg.norm(x - p, axis=1))) for p in ([0.03, 0, 0], [0, 0.03, 0])]
    assert res.landmark_residual_m[0] < 1e-4
    return (res.vertices_m - x)[probes, 0] * 1e3


def test_the_smoothness_does_not_depend_on_the_mesh_spacing():
    coarse, fine = _slide_centre(0.01), _slide_centre(0.0025)  # 169 and 2,401 vertices
    assert coarse.min() > 1.0  # the pull spreads: the field is not a spike at the landmark
    np.testing.assert_allclose(fine, coarse, rtol=_SAME_FIELD_REL)
