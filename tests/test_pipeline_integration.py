"""Regressions found by chaining track -> edit -> resim -> USD (examples/performance_pipeline.py)."""

from __future__ import annotations

import numpy as np
import pytest

_SOLVE_TOL_M = 1e-5  # two Newton solves at relative residual 1e-6 agree to ~1e-6 m on the 2K face


@pytest.fixture(scope="module")
def model():
    from wface.faces.builtin import build_face

    return build_face(2000)


@pytest.fixture(scope="module")
def exaggerated(model):
    """A two-frame edited take: rest, then a smile exaggerated x2 (zygomatici past full activation)."""
    from wface.takes import Take, exaggerate, expression_pose, rest_pose

    big = exaggerate(expression_pose(model, "smile"), 2.0, joint=model.jaw_joint)
    assert big.force_length_scale is not None and big.drive.max() > 1.0
    return Take.from_poses(
        [rest_pose(model.n_muscles), big], 30.0, list(model.muscle_names), model.jaw_joint, source="smile x2"
    )


def test_edited_take_keeps_its_exaggeration_in_dynamics(model, exaggerated):
    """Bug: wface.takes.dynamic.Take had no force-length scale, so an exaggerated edit (drives > 1) was
    re-simulated with its activations clipped at 1: the dynamic pass lost the exaggeration."""
    from wface.physics import Damping, Simulator
    from wface.takes import Take, resimulate, simulate_poses

    take = exaggerated
    assert take.activations.max() <= 1.0 and take.force_length_scale.max() > 1.0
    np.testing.assert_allclose(take.activations * take.force_length_scale, exaggerated.drives, atol=1e-12)
    quasistatic = simulate_poses(model, exaggerated).x_m[1]
    # start from the exaggerated frame, heavily damped: stays at its quasistatic equilibrium
    held = Take(
        take.activations[[1, 1]], 30.0, bones=take.bones[[1, 1]], force_length_scale=take.force_length_scale[[1, 1]]
    )
    sim = Simulator(model)
    dyn = resimulate(model, held, substeps=1, damping=Damping(0.0, 1e-2), sim=sim)
    assert sim.force_length_scale == 1.0  # the caller's simulator is given back as it was
    np.testing.assert_allclose(dyn.positions_m[0], quasistatic, atol=_SOLVE_TOL_M)
    np.testing.assert_allclose(dyn.positions_m[1], quasistatic, atol=_SOLVE_TOL_M)
    clipped = Take(np.tile(exaggerated.activations[1], (2, 1)), 30.0, bones=take.bones[[1, 1]])  # no scale
    clipped = resimulate(model, clipped, substeps=1)
    assert np.linalg.norm(clipped.positions_m[0] - quasistatic, axis=1).max() > 1e-3  # what the bug gave


def test_resim_load_take_reads_an_edits_force_length_scale(model, exaggerated, tmp_path):
    """`wface edit exaggerate` writes force_length_scale into controls.npz; `wface resim --take`
    must replay the drives, not the clipped activations."""
    from wface.takes import load_take, write_controls

    write_controls(tmp_path, model, exaggerated)
    take = load_take(tmp_path, model)
    np.testing.assert_allclose(take.activations * take.force_length_scale, exaggerated.drives, atol=1e-12)
    assert take.activations.max() <= 1.0


def test_tracked_take_keeps_its_frame_rate_without_usd(model, tmp_path):
    """Bug: controls.npz of `wface track` had no fps, so with --no-pictures (no animation.usdc) a
    60 fps capture was edited and re-simulated at 30 fps (half speed, wrong inertia)."""
    from wface.takes import load_take
    from wface.takes.store import FrameRecord, take_from_records, write_controls
    from wface.tracking.rig import FaceRig

    c = FaceRig(model).rest_controls()
    n = model.n_nodes
    recs = [FrameRecord(f, c, np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((0, 3)), np.zeros(0), {}) for f in (0, 1)]
    write_controls(tmp_path, model, take_from_records(model, recs, fps=60.0))
    assert load_take(tmp_path, model, reference=False).fps == 60.0
    assert load_take(tmp_path, model).fps == 60.0


def test_resim_stage_lines_up_with_the_tracked_and_edited_stages(model, exaggerated, tmp_path):
    """Bug: `wface resim` wrote its skin as a bare /Face/Mesh without node ids, bones or activations,
    unlike the /Face/Skin take stages of `wface track` / `wface edit`: read_take refused it and the
    three stages of one performance did not line up in a DCC."""
    from wface.io.usd import assert_stage_valid, read_take
    from wface.takes.usd import write_take_usd

    take = exaggerated
    x = np.stack([model.rest_positions_m, model.rest_positions_m + 1e-3])
    path = write_take_usd(tmp_path / "dyn.usda", model, x, take=take, metadata={"dynamic": True})
    assert_stage_valid(path)
    back = read_take(path)
    assert back["n_frames"] == 2 and back["fps"] == 30.0
    np.testing.assert_allclose(back["skin_points_m"][1], x[1][back["skin_node_ids"]], atol=1e-6)  # float32
    np.testing.assert_allclose(back["activations"], exaggerated.activations, atol=1e-6)  # as `wface edit` writes
    assert back["cranium_affines"].shape == (2, 3, 4) and back["metadata"]["dynamic"] is True


def test_neutral_frame_of_the_models_own_markers_aligns_to_the_identity(model):
    """Bug: prepare_capture pulled each named marker to the skin *node* nearest the model's marker,
    so even the model's own neutral markers were aligned with a similarity 0.2-2.8 % off scale and
    moved up to 2.6 mm (on 2K-5K tets): the neutral frame anchored a biased embedding and every
    tracked frame was scaled with it. Landmarks are now the model's marker positions themselves."""
    from wface.tracking.capture import prepare_capture

    ref = model.marker_positions_m
    cap = prepare_capture(model, np.stack([ref, ref + 1e-3]), model.marker_names, reference_positions_m=ref)
    _EXACT = 1e-9  # metres; the similarity fit of exact data is exact up to float64 round-off
    assert abs(cap.scale - 1.0) < 1e-9 and cap.alignment_rms_mm < _EXACT * 1e3
    np.testing.assert_allclose(cap.targets_m[0], ref, atol=_EXACT)
    np.testing.assert_allclose(cap.markers.positions(model.rest_positions_m), ref, atol=_EXACT)


def test_markers_standing_off_the_skin_sit_at_their_neutral_place_at_rest(model):
    """Bug: a marker embedded with its offset along the normal alone missed its neutral-frame place by
    the part of the offset off the normal (closest point on an edge or a vertex of a ridge): on the
    AnimFace takes the built-in face's NoseTop sat 3.5 mm from the capture's at rest, an error no
    control removes. Markers 3-15 mm off the skin in random directions now sit exactly in place."""
    from wface.tracking.capture import prepare_capture

    rng = np.random.default_rng(7)
    d = rng.normal(size=model.marker_positions_m.shape)
    d *= rng.uniform(0.003, 0.015, len(d))[:, None] / np.linalg.norm(d, axis=1, keepdims=True)
    ref = model.marker_positions_m + d
    names = [f"m{i}" for i in range(len(ref))]  # no names in common: a shape fit alone
    cap = prepare_capture(model, ref[None], names, reference_positions_m=ref)
    emb = cap.markers.embedding
    assert np.linalg.norm(emb.tangent_residual_m, axis=1).max() > 1e-3  # millimetres off the normal
    np.testing.assert_allclose(cap.markers.positions(model.rest_positions_m), cap.targets_m[0], rtol=0, atol=1e-12)


def test_align_to_surface_takes_landmark_points(model):
    from wface.mesh.align import Similarity, align_to_surface

    skin = model.skin_triangles
    ref = model.marker_positions_m
    rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    moved = Similarity(1.3, rot, np.array([0.1, 0.2, 0.3])).apply(ref)
    res = align_to_surface(moved, model.rest_positions_m, skin, landmark_points_m=ref, landmark_weight=1.0)
    np.testing.assert_allclose(res.aligned_m, ref, atol=1e-9)
    with pytest.raises(ValueError, match="not both"):
        align_to_surface(moved, model.rest_positions_m, skin, landmark_vertices=[0] * len(ref), landmark_points_m=ref)
