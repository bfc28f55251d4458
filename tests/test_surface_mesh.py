"""The one surface mesh (wface.mesh.meshfile): what a source head has (polygons as authored, UVs with
seams, normals, material groups with names even without an .mtl, material colours, units) survives
reading, posing and writing OBJ and USD, for the Waters tools and for render meshes alike."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import data_path

from wface.io.usd import write_surface_mesh
from wface.mesh.meshfile import SurfaceMesh, read_surface_mesh, write_obj
from wface.testing.synthetic_head import synthetic_head

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
    mesh = read_surface_mesh(_source(tmp_path))
    assert mesh.units == "cm" and mesh.n_vertices == mesh.n_points == 6 and mesh.meters_per_unit == 0.01
    assert mesh.face_vertex_counts.tolist() == [4, 4, 3]
    assert mesh.uv.shape == (8, 2) and mesh.uv_indices.tolist()[4:8] == [4, 5, 6, 7]
    assert mesh.normals.shape == (2, 3) and mesh.material_names == ["Skin", "Teeth"]
    assert mesh.face_materials.tolist() == [0, 1, 1] and mesh.material_library == "head.mtl"
    assert mesh.material_colors == {"Skin": pytest.approx((0.8, 0.6, 0.5))}
    np.testing.assert_allclose(mesh.vertices_m[4], [0.2, 0.0, 0.0])  # cm -> m
    np.testing.assert_array_equal(mesh.points[4], [20.0, 0.0, 0.0])  # the file's own values
    assert {k: v.tolist() for k, v in mesh.face_groups.items()} == {"Skin": [0], "Teeth": [1, 2]}

    (tmp_path / "out").mkdir()
    out = write_obj(tmp_path / "out" / "posed.obj", mesh)
    assert out.read_text().startswith("# wface, units: cm\nmtllib head.mtl\nv 0 0 0\nv 10 0 0")
    again = read_surface_mesh(out)
    assert again.units == "cm"
    np.testing.assert_allclose(again.vertices_m, mesh.vertices_m, atol=_CM_TOL * 1e-2)
    for key in ("face_vertex_counts", "face_vertex_indices", "uv_indices", "normal_indices", "face_materials"):
        np.testing.assert_array_equal(getattr(again, key), getattr(mesh, key), err_msg=key)
    np.testing.assert_allclose(again.uv, mesh.uv, atol=1e-9)
    assert again.material_names == mesh.material_names


def test_posed_mesh_keeps_layout_and_gets_its_own_normals(tmp_path):
    mesh = read_surface_mesh(_source(tmp_path))
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

    mesh = read_surface_mesh(_source(tmp_path))
    path = write_surface_mesh(tmp_path / "head.usda", mesh, name="WatersFace")
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

    mesh = read_surface_mesh(data_path("ict-facekit", "generic_neutral_mesh.obj"))
    assert (mesh.units, mesh.n_vertices, mesh.uv.shape[0], len(mesh.material_names)) == ("cm", 26719, 28911, 12)
    summary = pose_mesh(mesh, tmp_path, expression="happy", render=False)
    posed = read_surface_mesh(summary["files"]["obj"])
    assert (posed.units, posed.n_vertices, posed.uv.shape[0]) == ("cm", 26719, 28911)
    np.testing.assert_array_equal(posed.face_materials, mesh.face_materials)
    np.testing.assert_array_equal(posed.face_vertex_counts, mesh.face_vertex_counts)  # quads stay quads
    moved_mm = np.linalg.norm(posed.vertices_m - mesh.vertices_m, axis=1) * 1e3
    assert moved_mm.max() == pytest.approx(summary["max_displacement_mm"], rel=1e-6)
    stage = Usd.Stage.Open(summary["files"]["usd"])
    assert UsdGeom.GetStageMetersPerUnit(stage) == pytest.approx(0.01)
    pts = np.asarray(UsdGeom.Mesh(stage.GetPrimAtPath("/WatersFace/Mesh")).GetPointsAttr().Get())
    np.testing.assert_allclose(pts * 0.01, posed.vertices_m, atol=1e-6)  # float32 centimetres


_OBJ = """\
# two quads and a triangle, a UV seam, two materials, no .mtl file
mtllib missing.mtl
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 2 0 0
v 2 1 0
v 3 0.5 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
vt 0.5 0.5
vt 0.9 0.1
usemtl Skin
f 1/1 2/2 3/3 4/4
f 2/5 5/2 6/3 3/6
usemtl Eyes
f 5/1 7/2 6/3
"""


@pytest.mark.parametrize("library", ["mtllib missing.mtl\n", ""])
def test_an_obj_keeps_its_polygons_uv_seams_and_material_groups(tmp_path, library):
    """Groups keep their names with a missing .mtl and with no mtllib line at all."""
    path = tmp_path / "quad.obj"
    path.write_text(_OBJ.replace("mtllib missing.mtl\n", library))
    m = read_surface_mesh(path, units="cm")
    assert m.n_points == 7 and m.face_vertex_counts.tolist() == [4, 4, 3]
    assert m.face_vertex_indices.tolist() == [0, 1, 2, 3, 1, 4, 5, 2, 4, 6, 5]
    assert m.uv_indices.tolist() == [0, 1, 2, 3, 4, 1, 2, 5, 0, 1, 2]  # vertex 1 has two UVs: a seam
    assert {k: v.tolist() for k, v in m.face_groups.items()} == {"Skin": [0, 1], "Eyes": [2]}
    assert m.material_names == ["Skin", "Eyes"] and m.face_materials.tolist() == [0, 0, 1]
    assert m.material_colors == {} and m.normals is None
    assert m.material_library == ("missing.mtl" if library else None)
    assert m.meters_per_unit == 0.01
    assert m.triangles().tolist() == [[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2], [4, 6, 5]]
    assert m.triangle_faces().tolist() == [0, 0, 1, 1, 2]
    assert m.faces_of(["Eyes", "Skin"]).tolist() == [0, 1, 2]
    with pytest.raises(KeyError, match="it has Skin, Eyes"):
        m.faces_of(["Teeth"])


def test_other_formats_and_bad_files(tmp_path):
    import meshio

    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]) * 0.1
    meshio.write(tmp_path / "t.ply", meshio.Mesh(pts, [("triangle", np.array([[0, 1, 2], [0, 1, 3]]))]))
    m = read_surface_mesh(tmp_path / "t.ply")
    assert m.n_faces == 2 and m.meters_per_unit == 1.0 and m.uv is None and m.face_materials is None
    with pytest.raises(FileNotFoundError, match="mesh file not found"):
        read_surface_mesh(tmp_path / "none.obj")
    (tmp_path / "bad.obj").write_text("v 0 0 0\nf 1 2 3\n")
    with pytest.raises(ValueError, match="outside"):
        read_surface_mesh(tmp_path / "bad.obj")
    with pytest.raises(ValueError, match="unknown units"):
        read_surface_mesh(tmp_path / "t.ply", units="furlong")
    with pytest.raises(ValueError, match="one index per face corner"):
        SurfaceMesh(pts, [3], [0, 1, 2], uv=np.zeros((2, 2)), uv_indices=[0, 1, 2])


def test_obj_round_trip_and_triangulation(tmp_path):
    head = synthetic_head(8, 12)
    write_obj(tmp_path / "h.obj", head)
    again = read_surface_mesh(tmp_path / "h.obj", units="m")
    np.testing.assert_allclose(again.vertices_m, head.vertices_m, atol=1e-9)
    np.testing.assert_array_equal(again.face_vertex_indices, head.face_vertex_indices)
    tri = head.triangles()
    assert len(tri) == int((head.face_vertex_counts - 2).sum()) == len(head.triangle_faces())
    quad = SurfaceMesh(np.eye(4, 3), [4], [0, 1, 2, 3])
    np.testing.assert_array_equal(quad.triangles(), [[0, 1, 2], [0, 2, 3]])


def test_write_obj_converts_units_and_names_odd_ones(tmp_path):
    mesh = read_surface_mesh(_source(tmp_path))
    out = write_obj(tmp_path / "mm.obj", mesh, units="mm")
    assert out.read_text().startswith("# wface, units: mm\n")
    again = read_surface_mesh(out, units="mm")
    np.testing.assert_allclose(again.points_m, mesh.points_m, atol=1e-12)
    np.testing.assert_array_equal(again.points[4], [200.0, 0.0, 0.0])
    odd = SurfaceMesh(mesh.points, mesh.face_vertex_counts, mesh.face_vertex_indices, meters_per_unit=0.3048)
    assert odd.units is None
    assert write_obj(tmp_path / "ft.obj", odd).read_text().startswith("# wface, meters per unit: 0.3048\n")
