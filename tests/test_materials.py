"""Material groups' colours and opacity when the file defines none (wface.mesh.materials), in USD and in
the Waters pictures: an eye occlusion overlay drawn opaque in skin colour made the ICT head's eyes read
as closed."""

from __future__ import annotations

import numpy as np

from wface.io.usd import write_surface_mesh
from wface.mesh.materials import SKIN_RGB, face_appearance, material_appearance
from wface.mesh.meshfile import SurfaceMesh
from wface.waters.render import render_mesh


def _two_quads(**kw) -> SurfaceMesh:
    """Two unit quads side by side (4 cm), the left in group M_Face, the right in M_EyeOcclusion."""
    pts = np.array([[0, 0, 0], [2, 0, 0], [2, 2, 0], [0, 2, 0], [4, 0, 0], [4, 2, 0]], dtype=float)
    groups = {"M_Face": np.array([0]), "M_EyeOcclusion": np.array([1])}
    return SurfaceMesh(pts, [4, 4], [0, 1, 2, 3, 1, 4, 5, 2], meters_per_unit=0.01, face_groups=groups, **kw)


def test_names_give_eyes_teeth_and_hidden_overlays():
    looks = {n: material_appearance(n) for n in ("M_Face", "M_ScleraLeft", "M_Teeth", "M_EyeOcclusion", "Foo")}
    assert looks["M_Face"].rgb == SKIN_RGB and looks["M_Face"].opacity == 1.0
    assert min(looks["M_ScleraLeft"].rgb) > 0.85 and looks["M_ScleraLeft"].rgb != SKIN_RGB
    assert looks["M_Teeth"].rgb != SKIN_RGB
    assert looks["M_EyeOcclusion"].opacity == 0.0
    assert looks["Foo"].opacity == 1.0 and looks["Foo"].rgb != SKIN_RGB  # unknown: grey, drawn
    defined = material_appearance("M_EyeOcclusion", (0.1, 0.2, 0.3))  # an .mtl colour wins, not the opacity
    assert defined.rgb == (0.1, 0.2, 0.3) and defined.opacity == 0.0


def test_face_appearance_follows_the_groups():
    rgb, opacity = face_appearance(_two_quads())
    np.testing.assert_allclose(rgb[0], SKIN_RGB)
    np.testing.assert_array_equal(opacity, [1.0, 0.0])
    rgb, _ = face_appearance(_two_quads(material_colors={"M_Face": (0.0, 0.0, 1.0)}))
    np.testing.assert_allclose(rgb[0], (0.0, 0.0, 1.0))


def test_usd_materials_carry_the_colour_and_hide_the_overlay(tmp_path):
    from pxr import Usd, UsdShade

    path = write_surface_mesh(tmp_path / "m.usda", _two_quads(), name="Head")
    stage = Usd.Stage.Open(str(path))
    shaders = {p.GetParent().GetName(): UsdShade.Shader(p) for p in stage.Traverse() if p.GetName() == "PreviewSurface"}
    assert set(shaders) == {"M_Face", "M_EyeOcclusion"}
    np.testing.assert_allclose(shaders["M_Face"].GetInput("diffuseColor").Get(), SKIN_RGB, atol=1e-6)
    assert not shaders["M_Face"].GetInput("opacity")  # opaque: not authored
    assert shaders["M_EyeOcclusion"].GetInput("opacity").Get() == 0.0


def test_the_waters_picture_draws_group_colours_and_leaves_hidden_triangles_out(tmp_path):
    import imageio.v3 as iio

    mesh = _two_quads()
    rgb, opacity = face_appearance(mesh)
    tri, tri_face = mesh.triangles(), mesh.triangle_faces()
    red = np.tile([1.0, 0.0, 0.0], (len(tri), 1))
    view = {"size": 200, "triangle_rgb": red, "bounds_m": [0.0, 0.04, 0.0, 0.02, -0.01, 0.01]}  # the same frame
    both = iio.imread(render_mesh(tmp_path / "a.png", mesh.vertices_m, tri, **view))
    shown = iio.imread(render_mesh(tmp_path / "b.png", mesh.vertices_m, tri, visible=opacity[tri_face] > 0, **view))

    def reddish(img):
        return int(((img[..., 0] > 120) & (img[..., 1] < 80) & (img[..., 2] < 80)).sum())

    assert reddish(both) > 1000
    assert 0.3 * reddish(both) < reddish(shown) < 0.7 * reddish(both)  # one of the two quads left out
