"""wface.speech.artisynth_demo: the Badin face set up as ArtiSynth's BadinFaceDemoLipOpening."""

import numpy as np
import pytest

from tests.conftest import data_path
from wface.mesh.quality import signed_volumes
from wface.speech.artisynth_demo import (
    ARTISYNTH_MAX_STRESS_PA,
    LIP_OPENING_RINGS,
    delaunay_fibre_directions,
    lip_opening_demo_model,
    oop_ring_entries,
    ring_hexes,
    without_idle_fibres,
)

# The model's tets are the import's conforming split of the hexes less the slivers it removed
# (docs/design.md, "Speech gestures": 16,819 of 16,969 mm^3); 2 % says the right tets were found.
_RING_VOLUME_RTOL = 0.02
_GAUSS = np.array([-1.0, 1.0]) / np.sqrt(3.0)
_CORNERS = np.array(
    [[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1], [-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]], float
)


def _hex_volume_m3(x: np.ndarray) -> float:
    """Volume of a trilinear hexahedron ((8, 3) corners, ANSYS order) by 2x2x2 Gauss quadrature of
    det J (exact: det J is a polynomial of degree at most 2 in each coordinate)."""
    vol = 0.0
    for xi in _GAUSS:
        for eta in _GAUSS:
            for zeta in _GAUSS:
                p = np.array([xi, eta, zeta])
                f = 1.0 + _CORNERS * p  # (8, 3): N_i = f_i0 f_i1 f_i2 / 8
                dN = _CORNERS * np.stack([f[:, 1] * f[:, 2], f[:, 0] * f[:, 2], f[:, 0] * f[:, 1]], axis=1) / 8.0
                vol += np.linalg.det(x.T @ dN)  # Gauss weights 1
    return abs(vol)


@pytest.fixture(scope="module")
def demo(badin_model):
    return lip_opening_demo_model(badin_model, data_path("artisynth-face"))


def test_hex_volume_quadrature():
    box = (_CORNERS + 1.0) * np.array([0.5, 1.0, 1.5])  # 1 x 2 x 3, sheared below
    assert _hex_volume_m3(box) == pytest.approx(6.0, rel=1e-12)
    shear = box @ np.array([[1.0, 0.0, 0.0], [0.3, 1.0, 0.0], [0.0, 0.2, 1.0]])
    assert _hex_volume_m3(shear) == pytest.approx(6.0, rel=1e-12)
    wedge = box.copy()
    wedge[[5, 6]] = wedge[[4, 7]]  # top edge collapsed: a prism of half the volume
    assert _hex_volume_m3(wedge) == pytest.approx(3.0, rel=1e-12)


def test_the_ring_tets_fill_the_ring_hexes(badin_model, demo):
    x = badin_model.rest_positions_m
    hexes = np.unique(np.concatenate(list(ring_hexes(data_path("artisynth-face")).values())), axis=0)
    hex_volume = sum(_hex_volume_m3(x[h]) for h in hexes)
    k = demo.muscle_names.index("OOP")
    tets = demo.fibre_tet[demo.fibre_muscle == k]
    assert len(np.unique(tets)) == len(tets)
    ring_volume = np.abs(signed_volumes(x, demo.tets[tets])).sum()
    assert ring_volume == pytest.approx(hex_volume, rel=_RING_VOLUME_RTOL)
    # the import's tube-embedded OOP holds about a quarter of that (measured 3,745 mm^3)
    oop = np.isin(np.asarray(badin_model.muscle_names)[badin_model.fibre_muscle], ["OOP_l", "OOP_r"])
    imported = (
        np.abs(signed_volumes(x, badin_model.tets[badin_model.fibre_tet[oop]])) * badin_model.fibre_fraction[oop]
    ).sum()
    assert imported < 0.5 * ring_volume
    assert np.allclose(demo.fibre_fraction[demo.fibre_muscle == k], 1.0)
    assert np.allclose(np.linalg.norm(demo.fibre_direction[demo.fibre_muscle == k], axis=1), 1.0)


def test_muscles_stress_and_boundary(badin_model, demo):
    assert "OOP" in demo.muscle_names and not {"OOP_l", "OOP_r"} & set(demo.muscle_names)
    assert demo.material.sigma_max_pa == ARTISYNTH_MAX_STRESS_PA and badin_model.material.sigma_max_pa == 3e5
    # every other muscle keeps its fibres
    for name in ("ZYG_l", "MENT_r", "OOM_l"):
        old = badin_model.fibre_tet[badin_model.fibre_muscle == badin_model.muscle_names.index(name)]
        new = demo.fibre_tet[demo.fibre_muscle == demo.muscle_names.index(name)]
        assert np.array_equal(np.sort(old), np.sort(new)), name
    # attachFaceToSkull, after the import's lists, fixes the inner surface and frees the lip, cheek and nose free
    # lists, 32 of the import's nose nodes among them (as RunLipOpening -Dlip.fixed shows); jaw nodes stay on the jaw
    from wface.faces.ansys import read_int_list
    from wface.speech.artisynth_demo import FREE_NODE_FILES, _node_ids

    data = data_path("artisynth-face")
    free = set(np.concatenate([_node_ids(data, read_int_list(data / f), f) for f in FREE_NODE_FILES]).tolist())
    old = dict(zip(badin_model.attached_nodes.tolist(), badin_model.attached_bone.tolist(), strict=True))
    new = dict(zip(demo.attached_nodes.tolist(), demo.attached_bone.tolist(), strict=True))
    freed = set(old) - set(new)
    assert len(freed) == 32 and freed <= free and all(old[n] == 0 for n in freed)
    assert not (set(new) & free - {n for n, b in new.items() if b == 1})  # only the jaw holds a free-list node
    assert len(new) == 1866 and len(old) == 885
    assert all(new[n] == 1 for n, b in old.items() if b == 1)
    assert demo.metadata["artisynth_lip_opening_demo"]["ring"] == list(LIP_OPENING_RINGS)
    partial = lip_opening_demo_model(badin_model, data_path("artisynth-face"), ring=False, boundary=False)
    assert partial.muscle_names == badin_model.muscle_names
    assert np.array_equal(partial.attached_nodes, badin_model.attached_nodes)
    assert partial.material.sigma_max_pa == ARTISYNTH_MAX_STRESS_PA
    # ArtiSynth's BlemkerMuscle / GenericMuscle: deviatoric fibre stress; the import keeps wface's uniaxial law
    assert demo.material.fibre_stress == "deviatoric" and badin_model.material.fibre_stress == "uniaxial"
    assert demo.metadata["artisynth_lip_opening_demo"]["fibre_stress"] == "deviatoric"
    kept = lip_opening_demo_model(
        badin_model, data_path("artisynth-face"), ring=False, boundary=False, fibre_stress=None
    )
    assert kept.material.fibre_stress == "uniaxial"


def test_demo_flesh_is_artisynths_law_whatever_the_model_file(badin_model):
    """An import saved before the C20 term existed carries 1175 Pa as mu01; the demo setup uses
    BadinFaceDemo's MooneyRivlinMaterial (C10 2500, C20 1175, bulk 10 C10) all the same."""
    from dataclasses import replace

    old = badin_model.with_material(replace(badin_model.material, mu01_pa=1175.0, mu20_pa=0.0))
    demo = lip_opening_demo_model(old, data_path("artisynth-face"), ring=False, boundary=False)
    law = (demo.material.mu10_pa, demo.material.mu01_pa, demo.material.mu20_pa, demo.material.kappa_pa)
    assert law == (2500.0, 0.0, 1175.0, 25000.0)
    assert demo.metadata["artisynth_lip_opening_demo"]["flesh"] == "artisynth"
    kept = lip_opening_demo_model(old, data_path("artisynth-face"), ring=False, boundary=False, flesh=False)
    assert kept.material.mu01_pa == 1175.0 and kept.material.mu20_pa == 0.0
    # the bulk potential: wface's log one unless the demo's own quadratic one is asked for
    assert demo.material.bulk_potential == "log" == demo.metadata["artisynth_lip_opening_demo"]["bulk_potential"]
    quad = lip_opening_demo_model(
        old, data_path("artisynth-face"), ring=False, boundary=False, bulk_potential="quadratic"
    )
    assert quad.material.bulk_potential == "quadratic" and quad.material.kappa_pa == 25000.0
    assert quad.metadata["artisynth_lip_opening_demo"]["bulk_potential"] == "quadratic"


def _saddle_ring(n: int = 24):
    """A closed polyline on a saddle (so its midpoints span 3D): (midpoints, unit segment directions)."""
    th = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    p = np.column_stack([np.cos(th), np.sin(th), 0.2 * np.sin(2 * th)])
    q = np.roll(p, -1, axis=0)
    return 0.5 * (p + q), (q - p) / np.linalg.norm(q - p, axis=1, keepdims=True)


def test_delaunay_directions_reproduce_fibres_and_ignore_sign():
    mid, d = _saddle_ring()
    # at a fibre's own midpoint (a Delaunay vertex) the weight is 1 on that fibre
    got = delaunay_fibre_directions(mid, mid, d)
    np.testing.assert_allclose(np.abs(np.einsum("kd,kd->k", got, d)), 1.0, atol=1e-9)
    # outside the hull (far above the ring's centre) the blend is of one hull face's fibres: unit, finite
    above = delaunay_fibre_directions(np.array([[0.0, 0.0, 3.0], [2.5, 0.1, 0.0]]), mid, d)
    np.testing.assert_allclose(np.linalg.norm(above, axis=1), 1.0)
    # a fibre and its reverse are the same fibre: flipping every second direction changes no axis
    flipped = d * np.where(np.arange(len(d)) % 2, -1.0, 1.0)[:, None]
    pts = np.random.default_rng(0).uniform(-0.8, 0.8, (50, 3)) * np.array([1.0, 1.0, 0.1])
    a, b = delaunay_fibre_directions(pts, mid, d), delaunay_fibre_directions(pts, mid, flipped)
    np.testing.assert_allclose(np.abs(np.einsum("kd,kd->k", a, b)), 1.0, atol=1e-9)


def test_artisynth_ring_directions_close_to_nearest_segment(badin_model):
    """ArtiSynth's Delaunay blend of the 7M fibres against the nearest segment, on the same ring tets
    (measured: median 5.6 degrees, 90th percentile 15.9, largest 47.2)."""
    data = data_path("artisynth-face")
    t0, d0 = oop_ring_entries(badin_model, data)
    t1, d1 = oop_ring_entries(badin_model, data, directions="delaunay")
    np.testing.assert_array_equal(t0, t1)
    angle = np.degrees(np.arccos(np.clip(np.abs(np.einsum("kd,kd->k", d0, d1)), 0.0, 1.0)))
    assert 1.0 < np.median(angle) < 10.0 and np.percentile(angle, 90) < 25.0
    with pytest.raises(ValueError, match="nearest' or 'delaunay"):
        oop_ring_entries(badin_model, data, directions="closest")


def test_idle_muscles_lose_their_fibres_and_driven_ones_keep_them(badin_model, demo):
    """without_idle_fibres: the approximant drives OOP alone (``GestureMapping.driven_muscles``), so every other
    muscle gets strength 0; their passive fibres then do no work (forces at a stretched state equal those of
    the model whose other muscles' fibre entries are removed), and OOP's are unchanged."""
    from dataclasses import replace

    from wface.physics import Simulator
    from wface.speech.gestures import map_gesture_to_model, read_gesture

    gesture = read_gesture(data_path("artisynth-face", "speech", "approximant"))
    driven = map_gesture_to_model(gesture, demo).driven_muscles(gesture, demo)
    assert driven == ["OOP"]
    idle = without_idle_fibres(demo, driven)
    oop = demo.muscle_names.index("OOP")
    assert idle.muscle_strength[oop] == demo.muscle_strength[oop] and np.count_nonzero(idle.muscle_strength) == 1
    assert idle.metadata["idle_muscles_without_fibres"] == [n for n in demo.muscle_names if n != "OOP"]
    keep = demo.fibre_muscle == oop
    only_oop = replace(
        demo,
        fibre_tet=demo.fibre_tet[keep],
        fibre_muscle=demo.fibre_muscle[keep],
        fibre_fraction=demo.fibre_fraction[keep],
        fibre_direction=demo.fibre_direction[keep],
    )
    x = demo.rest_positions_m * np.array([1.06, 0.97, 1.02])  # every fibre direction stretched or shortened
    a = np.zeros(demo.n_muscles)
    a[oop] = 0.2
    f_idle, f_only = Simulator(idle).forces(x, a), Simulator(only_oop).forces(x, a)
    np.testing.assert_allclose(f_idle, f_only, atol=1e-9 * np.abs(f_only).max())
    assert np.abs(Simulator(demo).forces(x, a) - f_only).max() > 1e-3 * np.abs(f_only).max()
    with pytest.raises(ValueError, match="not in the model"):
        without_idle_fibres(demo, ["OOP", "risorius"])


def test_the_demos_own_muscle_curves(badin_model, demo):
    """muscle_curves="artisynth": OOP BlemkerMuscle's curves, every other muscle GenericMuscle's, recorded in the
    metadata; the default keeps wface's on every muscle; without the ring there is no OOP to give them to."""
    own = lip_opening_demo_model(badin_model, data_path("artisynth-face"), muscle_curves="artisynth")
    curves = dict(own.material.muscle_curves)
    assert curves.pop("OOP") == "blemker" and set(curves.values()) == {"generic"}
    assert sorted(curves) == sorted(n for n in own.muscle_names if n != "OOP")
    assert own.metadata["artisynth_lip_opening_demo"]["muscle_curves"] == "artisynth"
    assert demo.material.muscle_curves == () and demo.metadata["artisynth_lip_opening_demo"]["muscle_curves"] == "law"
    with pytest.raises(ValueError, match="set ring=True"):
        lip_opening_demo_model(badin_model, data_path("artisynth-face"), ring=False, muscle_curves="artisynth")


def test_fibre_points_attached_as_artisynth_attaches_markers(badin_model):
    """attached_fibres: a fibre point inside the mesh stays where the data puts it; one in no element goes to the
    nearest point of the mesh's surface (FemModel3d.addNumberedMarker projects it), which is nearer than any other
    point of that surface; on the Badin face 60 of the 232 points, BUC's up to 4 mm."""
    from wface.faces.artisynth import badin_muscle_fibres
    from wface.mesh.closest import SurfaceQuery
    from wface.mesh.embed import containing_tets
    from wface.mesh.surface import boundary_faces
    from wface.speech.artisynth_demo import attached_fibres

    x = badin_model.rest_positions_m
    raw = badin_muscle_fibres(data_path("artisynth-face"))
    moved = attached_fibres(badin_model, raw)
    assert list(moved) == list(raw)
    for a, b in zip(moved.values(), raw.values(), strict=True):
        assert [p.shape for p in a] == [p.shape for p in b]
    p0 = np.concatenate([np.concatenate(v) for v in raw.values()])
    p1 = np.concatenate([np.concatenate(v) for v in moved.values()])
    tet, _ = containing_tets(p0, x, badin_model.tets, k=len(badin_model.tets))  # every tet: the exact answer
    inside = tet >= 0
    np.testing.assert_array_equal(p1[inside], p0[inside])
    assert len(np.unique(p0[~inside].round(12), axis=0)) == 60
    surface = SurfaceQuery(x, boundary_faces(badin_model.tets))
    hit = surface.closest(p0[~inside])
    np.testing.assert_allclose(p1[~inside], hit.point_m, atol=1e-12)
    np.testing.assert_allclose(surface.closest(p1[~inside]).distance_m, 0.0, atol=1e-9)
    step = np.linalg.norm(p1 - p0, axis=1)
    buc = np.concatenate([np.concatenate(moved[n]) - np.concatenate(raw[n]) for n in ("BUC_l", "BUC_r")])
    assert 4.0e-3 < np.linalg.norm(buc, axis=1).max() < 4.1e-3 and step.max() == np.linalg.norm(buc, axis=1).max()


def test_the_demos_own_muscle_elements(badin_model, demo):
    """demo_muscle_entries: whole hexes within 6 mm of a bundle's fibres, as ArtiSynth's addElementsNearFibres
    picks them (its own lists, dumped by RunLipOpening -Dlip.muscles, hold these counts but for RIS 216, DLI 120,
    LAO 74, BUC 60: README); muscle_elements="artisynth" puts every muscle but OOP on them, fraction 1, and leaves
    OOP's rings as they were."""
    from wface.speech.artisynth_demo import _tets_in_hexes, demo_muscle_entries, face_hexes

    data = data_path("artisynth-face")
    entries = demo_muscle_entries(badin_model, data)
    owner = _tets_in_hexes(badin_model, face_hexes(data), badin_model.rest_positions_m)
    hexes = {
        b: sum(len(np.unique(owner[entries[f"{b}_{s}"][0]])) for s in "lr")
        for b in ("OOM", "MENT", "RIS", "LLS", "LLSAN", "DAO", "DLI", "LAO", "ZYG", "BUC")
    }
    assert hexes == {
        "OOM": 704, "MENT": 92, "RIS": 215, "LLS": 102, "LLSAN": 152, "DAO": 60, "DLI": 121, "LAO": 76, "ZYG": 50,
        "BUC": 61,
    }  # fmt: skip
    assert "OOP" not in entries and "OOP_l" not in entries
    for tets, d in entries.values():
        np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
        assert np.all(owner[tets] >= 0)
    own = lip_opening_demo_model(badin_model, data, muscle_elements="artisynth")
    assert own.metadata["artisynth_lip_opening_demo"]["muscle_elements"] == "artisynth"
    oom = own.fibre_muscle == own.muscle_index("OOM_l")
    assert np.array_equal(own.fibre_tet[oom], np.sort(entries["OOM_l"][0])) and np.all(own.fibre_fraction[oom] == 1)
    oop_own, oop_demo = (m.fibre_muscle == m.muscle_index("OOP") for m in (own, demo))
    assert np.array_equal(own.fibre_tet[oop_own], demo.fibre_tet[oop_demo])
    assert np.array_equal(own.fibre_direction[oop_own], demo.fibre_direction[oop_demo])
    assert np.all(np.diff(own.fibre_tet) >= 0)
    with pytest.raises(ValueError, match="muscle_elements must be"):
        lip_opening_demo_model(badin_model, data, muscle_elements="hexes")


def test_the_oomi_exciters_own_targets(badin_model, demo):
    """ooml_exciter_tets: the OOMl exciter's targets (exciters/OOMl.art, positions in the OOM bundle's element list)
    are 232 of OOM's 704 hexes. ArtiSynth's own exciter, dumped by RunLipOpening -Dlip.muscles, targets elements 13,
    14, 15, ... 21, 29 first: the OOM list's positions 7-15 and 23. Every target lies in the lower lip: the split by
    the lips' surfaces (with_lower_oom's default) holds them all and tets of 69 hexes more, at the mouth's corners.
    The split model's OOMl muscles sit on exactly those tets (OOM on the demo's own elements)."""
    from wface.speech.artisynth_demo import _hex_elements, _tets_in_hexes, face_hexes, ooml_exciter_tets
    from wface.speech.gestures import with_lower_oom

    data = data_path("artisynth-face")
    mask = ooml_exciter_tets(demo, data)
    assert mask.shape == (len(demo.tets),)
    owner = _tets_in_hexes(demo, face_hexes(data), demo.rest_positions_m)
    numbers, _ = _hex_elements(data)
    target = np.unique(owner[mask])
    assert len(target) == 232
    assert numbers[target][:10].tolist() == [13, 14, 15, 16, 17, 18, 19, 20, 21, 29]
    assert np.array_equal(mask, np.isin(owner, target) & (owner >= 0))  # whole hexes
    own = lip_opening_demo_model(badin_model, data, muscle_elements="artisynth")  # OOM on the demo's 704 hexes
    exact, nearer = with_lower_oom(own, mask), with_lower_oom(own)
    lower = [exact.muscle_index(n) for n in ("OOMl_l", "OOMl_r")]
    on = np.isin(exact.fibre_muscle, lower)
    oom = np.isin(own.fibre_muscle, [own.muscle_index(n) for n in ("OOM_l", "OOM_r")])
    assert np.array_equal(on, oom & mask[own.fibre_tet])
    near_hexes = np.unique(owner[nearer.fibre_tet[np.isin(nearer.fibre_muscle, lower)]])
    assert set(target) <= set(near_hexes) and len(near_hexes) - len(target) == 69  # tets of 69 hexes more
    with pytest.raises(ValueError, match="one per tet"):
        with_lower_oom(demo, mask[:-1])
