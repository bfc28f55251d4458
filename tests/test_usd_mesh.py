"""write_mesh_animation: topology once, time-sampled points and extent, metadata, errors."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pxr")

from wface.io.usd import UsdWriteError, assert_stage_valid, write_mesh_animation  # noqa: E402


def _sheet(frames: int = 3):
    rng = np.random.default_rng(0)
    pts = rng.random((frames, 5, 3))
    tri = np.array([[0, 1, 2], [2, 3, 4]])
    return pts, tri


@pytest.mark.parametrize("suffix", [".usda", ".usdc"])
def test_animated_mesh_round_trip(tmp_path, suffix):
    from pxr import Usd, UsdGeom

    pts, tri = _sheet()
    out = write_mesh_animation(
        tmp_path / f"m{suffix}", points_m=pts, face_vertex_counts=None, face_vertex_indices=tri, fps=30.0
    )
    assert_stage_valid(out)  # every registered UsdValidation validator + the extent check
    stage = Usd.Stage.Open(str(out))
    assert stage.GetRootLayer().GetFileFormat().formatId == ("usda" if suffix == ".usda" else "usdc")
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert UsdGeom.GetStageUpAxis(stage) == "Y"
    assert stage.GetTimeCodesPerSecond() == 30.0
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0.0, 2.0)
    assert stage.GetDefaultPrim().GetName() == "Face"
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Mesh"))
    assert list(mesh.GetFaceVertexCountsAttr().Get()) == [3, 3]
    assert list(mesh.GetFaceVertexIndicesAttr().Get()) == tri.ravel().tolist()
    assert mesh.GetPointsAttr().GetTimeSamples() == [0.0, 1.0, 2.0]
    for f in range(3):
        got = np.asarray(mesh.GetPointsAttr().Get(f))
        np.testing.assert_allclose(got, pts[f], rtol=1e-6)  # float32 storage
        ext = np.asarray(mesh.GetExtentAttr().Get(f))
        np.testing.assert_allclose(ext, [pts[f].min(0), pts[f].max(0)], rtol=1e-6)


def test_static_mesh_polygons_and_overwrite(tmp_path):
    from pxr import Usd, UsdGeom

    quad = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.0]])
    path = tmp_path / "q.usda"
    write_mesh_animation(path, points_m=quad * 2, face_vertex_counts=[4], face_vertex_indices=[0, 1, 2, 3])
    write_mesh_animation(
        path,
        points_m=quad,
        face_vertex_counts=[4],
        face_vertex_indices=[0, 1, 2, 3],
        name="Quad",
        colors=(1.0, 0.0, 0.0),
    )  # rewriting the same file replaces it
    assert_stage_valid(path)
    stage = Usd.Stage.Open(str(path))
    assert not stage.GetPrimAtPath("/Face")
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Quad/Mesh"))
    assert mesh.GetPointsAttr().GetTimeSamples() == []
    np.testing.assert_allclose(np.asarray(mesh.GetPointsAttr().Get()), quad)
    assert list(mesh.GetDisplayColorPrimvar().Get()[0]) == [1.0, 0.0, 0.0]


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(points_m=np.zeros((4, 2)), face_vertex_counts=None, face_vertex_indices=[[0, 1, 2]]), "shape"),
        (dict(points_m=np.full((4, 3), np.nan), face_vertex_counts=None, face_vertex_indices=[[0, 1, 2]]), "NaN"),
        (dict(points_m=np.zeros((4, 3)), face_vertex_counts=None, face_vertex_indices=[[0, 1, 9]]), "outside"),
        (dict(points_m=np.zeros((4, 3)), face_vertex_counts=[3, 3], face_vertex_indices=[0, 1, 2]), "sum to"),
        (dict(points_m=np.zeros((4, 3)), face_vertex_counts=None, face_vertex_indices=[0, 1, 2]), "triangles"),
    ],
)
def test_errors_name_the_problem(tmp_path, kwargs, match):
    with pytest.raises(UsdWriteError, match=match):
        write_mesh_animation(tmp_path / "bad.usda", **kwargs)


def test_bad_suffix(tmp_path):
    with pytest.raises(UsdWriteError, match="suffix|end in"):
        write_mesh_animation(
            tmp_path / "bad.obj", points_m=np.zeros((3, 3)), face_vertex_counts=None, face_vertex_indices=[[0, 1, 2]]
        )


def test_unreadable_old_file_is_replaced(tmp_path):
    path = tmp_path / "old.usda"
    path.write_text("this is not USD\n")
    write_mesh_animation(path, points_m=np.eye(3), face_vertex_counts=None, face_vertex_indices=[[0, 1, 2]])
    assert_stage_valid(path)
