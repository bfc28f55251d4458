"""Face-skull contact (``Contact(regions="skull")``): the face against the jaw and maxilla meshes only, as
ArtiSynth's lip-skull contact (docs/design.md, "Contact"), on a small box face and on the Badin import."""

from __future__ import annotations

import numpy as np
import pytest

from wface.model import BoneMesh
from wface.physics import Simulator
from wface.physics.contact import SKULL_MESHES, Contact
from wface.solvers.pattern import BlockPattern
from wface.testing.box import box_tet_mesh
from wface.testing.models import box_model

_LIFT_M = 0.003  # the jaw end of the box is lifted this much: the box bends up into the maxilla block
_FD_STEP_M = 1e-8


def _block(lo, hi, bone: str) -> BoneMesh:
    """A closed box surface (triangles of a one-cell tet box's boundary) from corner lo to hi."""
    from wface.mesh.surface import boundary_faces

    x, tets = box_tet_mesh((1, 1, 1), tuple(np.subtract(hi, lo)))
    return BoneMesh(x + np.asarray(lo, dtype=float), boundary_faces(tets).astype(np.int32), bone)


def _bent_box():
    """A 40 x 20 x 20 mm box, x- face on the cranium, x+ face on the jaw; a maxilla block 0.5 mm above
    its top over x in [15, 35] mm, a jaw block 0.2 mm below its bottom from x = 10 mm past the jaw end,
    and decoys that the skull region must leave out (upper-teeth and cranium blocks where the maxilla is)."""
    model = box_model((8, 4, 4), (0.04, 0.02, 0.02), cranium_faces=("x-",), jaw_faces=("x+",), muscles=0)
    model.bone_meshes = {
        "maxilla": _block((0.015, -0.01, 0.0205), (0.035, 0.03, 0.03), "cranium"),
        "jaw": _block((0.01, -0.01, -0.01), (0.045, 0.03, -0.0002), "jaw"),
        "upper_teeth": _block((0.015, -0.01, 0.0205), (0.035, 0.03, 0.03), "cranium"),
        "cranium": _block((0.015, -0.01, 0.0205), (0.035, 0.03, 0.03), "cranium"),
    }
    target = model.rest_positions_m[model.attached_nodes].copy()
    target[model.attached_bone == 1, 2] += _LIFT_M
    return model, target


@pytest.fixture(scope="module")
def bent():
    model, target = _bent_box()
    sim = Simulator(model)
    free = sim.solve(None, target, tol=1e-9)
    return model, target, sim, free


def test_skull_region_holds_the_jaw_and_maxilla_only(bent):
    model, *_ = bent
    contact = Contact(model, regions="skull")
    assert sorted(name for name, _ in contact.rigid) == sorted(SKULL_MESHES)
    assert set(SKULL_MESHES) < set(model.bone_meshes)
    with pytest.raises(ValueError, match="no jaw or maxilla mesh"):
        Contact(box_model((2, 2, 2), muscles=0), regions="skull")


def test_nodes_pushed_into_the_skull_come_out(bent):
    model, target, sim, free = bent
    contact = Contact(model, regions="skull")
    contact.set_pose(target)
    # without contact the bent box passes through both blocks (the jaw block follows the jaw: 3 mm up)
    pen = contact.penetration(free.x)["sources"]
    assert pen["maxilla"]["max_penetration_m"] > 0.5e-3 and pen["jaw"]["max_penetration_m"] > 0.5e-3
    eq = sim.solve(None, target, contact=contact, tol=1e-8, max_iterations=60)
    assert eq.converged and eq.inverted_elements == 0
    after = contact.penetration(eq.x)["sources"]
    for name in SKULL_MESHES:  # the default penalty keeps it within a few % of the free overlap
        assert 0 < after[name]["max_penetration_m"] < 0.1 * pen[name]["max_penetration_m"]
    # the nodes that were deepest in the maxilla are pushed back below it, not through it
    pairs = contact.evaluate(free.x)
    in_maxilla = pairs.source == pairs.names.index("maxilla")
    deep = pairs.node[in_maxilla][np.argmax(pairs.penetration_m[in_maxilla])]
    assert eq.x[deep, 2] < free.x[deep, 2] - 0.5 * pen["maxilla"]["max_penetration_m"]


def test_skull_contact_energy_forces_and_hessian_agree_with_finite_differences(bent):
    model, target, _, free = bent
    contact = Contact(model, regions="skull")
    contact.set_pose(target)
    rng = np.random.default_rng(3)
    x = free.x + 1e-6 * rng.standard_normal(free.x.shape)  # off any closest-feature switch
    pairs = contact.evaluate(x)
    assert len(pairs.node) > 5 and {pairs.names[s] for s in np.unique(pairs.source)} == set(SKULL_MESHES)
    f = pairs.forces()
    involved = np.unique(pairs.node)
    H = pairs.assemble(BlockPattern(model.tets, model.n_nodes))
    for _ in range(4):
        v = np.zeros_like(x)
        v[involved] = rng.standard_normal((involved.size, 3))
        # energy -> forces: central differences of E along v equal -f . v (float64)
        dE = (contact.energy(x + _FD_STEP_M * v) - contact.energy(x - _FD_STEP_M * v)) / (2 * _FD_STEP_M)
        assert dE == pytest.approx(-np.sum(f * v), rel=1e-6)
        # forces -> Hessian: the pairs here are on the blocks' faces, where k n n^T is exact
        df = (contact.forces(x + _FD_STEP_M * v) - contact.forces(x - _FD_STEP_M * v)) / (2 * _FD_STEP_M)
        Hv = (H @ v.ravel()).reshape(-1, 3)
        assert np.linalg.norm(-df - Hv) <= 1e-6 * np.linalg.norm(Hv)


def test_badin_skull_contact_is_the_jaw_and_maxilla_and_free_at_rest(badin_model):
    c = Contact(badin_model, regions="lips,skull")
    assert [name for name, _ in c.rigid] == ["jaw", "maxilla"]
    assert c.penetration(badin_model.rest_positions_m)["max_penetration_m"] == 0.0
    # the flesh lies up to 0.6 mm inside the maxilla (0.05 mm the jaw) in the source data: those nodes are
    # left out of that mesh's contact at rest (inside_at_rest="ignore"), as for the teeth
    raw = Contact(badin_model, regions="skull", inside_at_rest="push").penetration(badin_model.rest_positions_m)
    assert 0.3e-3 < raw["sources"]["maxilla"]["max_penetration_m"] < 1e-3
    assert raw["sources"]["jaw"]["max_penetration_m"] < 0.1e-3
    assert c.ignored_at_rest["maxilla"] == raw["sources"]["maxilla"]["active_nodes"]


def test_the_comparison_figure_reads_the_outputs_and_the_original(tmp_path):
    """examples/badin_skull_contact.py: the original's area at each OOP level and the played curves' columns."""
    import importlib.util
    from pathlib import Path

    from tests.conftest import data_path

    face = data_path("artisynth-face")
    path = Path(__file__).resolve().parents[1] / "examples" / "badin_skull_contact.py"
    spec = importlib.util.spec_from_file_location("badin_skull_contact_example", path)
    ex = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ex)
    # the original's curve (OOP a cubic step 0 -> 0.3 over 0.2-0.8 s): 15.4 mm^2 at t = 0.8 s, where OOP reaches 0.3
    assert ex.original_at_levels(face, [0.3]) == [pytest.approx(15.41, abs=0.01)]
    t = np.linspace(0.0, 1.0, 26)
    flat = {"times_s": t.tolist(), "lip_opening_area_mm2": [40.0] * 26, "reference_comparison": {"rms_mm2": 1.0}}
    held = {"lip and skull contact": {"levels": [0.01, 0.3], "area_mm2": [30.0, 1.0]}}
    numbers = ex.figure(held, {"skull": flat}, face, tmp_path / "f.png")
    assert (tmp_path / "f.png").exists() and numbers["held"]["lip and skull contact"] == [30.0, 1.0]
    row = numbers["played"]["skull"]
    assert row["before_excitation_mm2"] == 40.0 and row["below_20_from_s"] is None
    assert row["max_difference_after_0.32s_mm2"] > 20  # a curve that never closes is far from the original's
