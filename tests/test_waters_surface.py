"""Waters keeps the source mesh: UVs, normals, material groups, polygons and units through OBJ and USD."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import data_path

from wface.waters.surface import read_surface, write_obj, write_usd

_CM_TOL = 1e-6  # OBJ text keeps 9 significant digits of centimetre values


def _source(tmp_path):
    """Two quads and a triangle in cm: UVs indexed apart from the vertices (a seam), normals, two
    materials of which the .mtl defines one."""
    (tmp_path / "head.mtl").write_text("newmtl Skin\nKd 0.8 0.6 0.5\n")
    text = """mtllib head.mtl
v 0 0 0
v 10 0 0
v 10 10 0
v 0 10 0
v 20 0 0
v 20 10 0
vt 0 0
vt 0.5 0
vt 0.5 1
vt 0 1
vt 0.6 0
vt 1 0
vt 1 1
vt 0.6 1
vn 0 0 1
vn 0 0.6 0.8
usemtl Skin
f 1/1/1 2/2/1 3/3/1 4/4/1
usemtl Teeth
f 2/5/2 5/6/2 6/7/2 3/8/2
f 1/1/1 3/3/1 4/4/1
"""
    path = tmp_path / "head.obj"
    path.write_text(text)
    return path


def test_obj_keeps_everything(tmp_path):
    mesh = read_surface(_source(tmp_path))
    assert mesh.units == "cm" and mesh.n_vertices == 6
    assert mesh.face_vertex_counts.tolist() == [4, 4, 3]
    assert mesh.uv.shape == (8, 2) and mesh.uv_indices.tolist()[4:8] == [4, 5, 6, 7]
    assert mesh.normals.shape == (2, 3) and mesh.material_names == ["Skin", "Teeth"]
    assert mesh.face_materials.tolist() == [0, 1, 1] and mesh.material_library == "head.mtl"
    assert mesh.material_colors == {"Skin": pytest.approx((0.8, 0.6, 0.5))}
    np.testing.assert_allclose(mesh.vertices_m[4], [0.2, 0.0, 0.0])  # cm -> m in memory

    (tmp_path / "out").mkdir()
    out = write_obj(tmp_path / "out" / "posed.obj", mesh)
    assert out.read_text().startswith("# wface waters output, units: cm\nmtllib head.mtl\nv 0 0 0\nv 10 0 0")
    again = read_surface(out)
    assert again.units == "cm"
    np.testing.assert_allclose(again.vertices_m, mesh.vertices_m, atol=_CM_TOL * 1e-2)
    for key in ("face_vertex_counts", "face_vertex_indices", "uv_indices", "normal_indices", "face_materials"):
        np.testing.assert_array_equal(getattr(again, key), getattr(mesh, key), err_msg=key)
    np.testing.assert_allclose(again.uv, mesh.uv, atol=1e-9)
    assert again.material_names == mesh.material_names


def test_posed_mesh_keeps_layout_and_gets_its_own_normals(tmp_path):
    mesh = read_surface(_source(tmp_path))
    v = mesh.vertices_m.copy()
    v[5, 2] += 0.05  # bend the second quad out of plane
    posed = mesh.with_vertices(v)
    np.testing.assert_array_equal(posed.uv_indices, mesh.uv_indices)
    assert posed.face_materials.tolist() == [0, 1, 1] and posed.units == "cm"
    assert posed.normals.shape == (6, 3)  # one per vertex, of the new shape
    np.testing.assert_allclose(posed.normals[0], [0, 0, 1], atol=1e-12)  # the first quad stays flat
    assert abs(posed.normals[5, 2]) < 0.99  # the bent corner turned


def test_usd_keeps_units_uvs_and_materials(tmp_path):
    pytest.importorskip("pxr")
    from pxr import Usd, UsdGeom, UsdShade

    from wface.io.usd import assert_stage_valid

    mesh = read_surface(_source(tmp_path))
    path = write_usd(tmp_path / "head.usda", mesh)
    assert_stage_valid(path)
    stage = Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageMetersPerUnit(stage) == pytest.approx(0.01)
    usd_mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/WatersFace/Mesh"))
    np.testing.assert_allclose(np.asarray(usd_mesh.GetPointsAttr().Get())[4], [20, 0, 0])  # stage units: cm
    st = UsdGeom.PrimvarsAPI(usd_mesh).GetPrimvar("st")
    assert st.GetInterpolation() == UsdGeom.Tokens.faceVarying
    np.testing.assert_array_equal(np.asarray(st.GetIndices()), mesh.uv_indices)
    np.testing.assert_allclose(np.asarray(st.Get()), mesh.uv, atol=1e-7)
    subsets = {s.GetPrim().GetName(): s for s in UsdGeom.Subset.GetAllGeomSubsets(usd_mesh)}
    assert sorted(subsets) == ["Skin", "Teeth"]
    assert list(subsets["Teeth"].GetIndicesAttr().Get()) == [1, 2]
    bound, _ = UsdShade.MaterialBindingAPI(subsets["Skin"].GetPrim()).ComputeBoundMaterial()
    shader = UsdShade.Shader(stage.GetPrimAtPath(f"{bound.GetPath()}/PreviewSurface"))
    assert tuple(shader.GetInput("diffuseColor").Get()) == pytest.approx((0.8, 0.6, 0.5))


def test_ict_head_keeps_its_uvs_materials_and_centimetres(tmp_path):
    pytest.importorskip("pxr")
    from pxr import Usd, UsdGeom

    from wface.waters.pipeline import pose_mesh

    mesh = read_surface(data_path("ict-facekit", "generic_neutral_mesh.obj"))
    assert (mesh.units, mesh.n_vertices, mesh.uv.shape[0], len(mesh.material_names)) == ("cm", 26719, 28911, 12)
    summary = pose_mesh(mesh, tmp_path, expression="happy", render=False)
    posed = read_surface(summary["files"]["obj"])
    assert (posed.units, posed.n_vertices, posed.uv.shape[0]) == ("cm", 26719, 28911)
    np.testing.assert_array_equal(posed.face_materials, mesh.face_materials)
    np.testing.assert_array_equal(posed.face_vertex_counts, mesh.face_vertex_counts)  # quads stay quads
    moved_mm = np.linalg.norm(posed.vertices_m - mesh.vertices_m, axis=1) * 1e3
    assert moved_mm.max() == pytest.approx(summary["max_displacement_mm"], rel=1e-6)
    stage = Usd.Stage.Open(summary["files"]["usd"])
    assert UsdGeom.GetStageMetersPerUnit(stage) == pytest.approx(0.01)
    pts = np.asarray(UsdGeom.Mesh(stage.GetPrimAtPath("/WatersFace/Mesh")).GetPointsAttr().Get())
    np.testing.assert_allclose(pts * 0.01, posed.vertices_m, atol=1e-6)  # float32 centimetres
