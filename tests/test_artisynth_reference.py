"""ArtiSynth's own lip-opening runs measured by wface: the brick-mesh boundary, the node-dump reader and
examples/artisynth_lip_area.py on dumps made from the Badin face's rest shape (real data; skipped
without ../shared/data)."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import data_path
from wface.faces.ansys import hex_boundary_triangles, hexes_to_tets, read_ansys_nodes
from wface.faces.artisynth import MESH_PREFIX
from wface.mesh.quality import signed_volumes
from wface.mesh.surface import boundary_faces
from wface.speech.aperture import ARTISYNTH_VIEW_DIRECTION_BADIN

_EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
REST_AREA_MM2 = 39.50  # the imported face's rest aperture (README, the lip-opening tables)
SCALE = 1.05  # a uniform scaling of the face scales the orthographic aperture by SCALE^2


def _example(name: str):
    """The example at examples/NAME.py (NAME may name a subfolder: "artisynth_reference/export_wface_tets")."""
    spec = importlib.util.spec_from_file_location(Path(name).name, _EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _bricks():
    """Two unit bricks side by side and a wedge (a brick with a collapsed edge) on top of the first."""
    x = np.array(
        [[i, j, k] for k in (0.0, 1.0) for j in (0.0, 1.0) for i in (0.0, 1.0, 2.0)]
        + [[0.0, 0.0, 2.0], [0.0, 1.0, 2.0]],
        dtype=np.float64,
    )
    node = {tuple(p): n for n, p in enumerate(x.tolist())}
    corners = ((0, 0, 0), (0, 0, 1), (0, 1, 1), (0, 1, 0), (1, 0, 0), (1, 0, 1), (1, 1, 1), (1, 1, 0))  # (dz, dy, dx)

    def brick(o):
        return [node[(o[0] + dx, o[1] + dy, o[2] + dz)] for dz, dy, dx in corners]

    b0, b1 = brick((0.0, 0.0, 0.0)), brick((1.0, 0.0, 0.0))
    top0, top1 = node[(0.0, 0.0, 2.0)], node[(0.0, 1.0, 2.0)]
    wedge = [b0[4], b0[5], b0[6], b0[7], top0, top0, top1, top1]  # ANSYS order, face 5-6 collapsed
    return x, np.array([b0, b1, wedge])


def _area(x, tris):
    p = x[tris]
    return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum()


def test_hex_boundary_is_the_closed_outer_surface_of_bricks_and_wedges():
    x, hexes = _bricks()
    tris = hex_boundary_triangles(hexes)
    edges = np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
    _, count = np.unique(edges, axis=0, return_counts=True)
    assert np.all(count == 2)  # closed, manifold: the shared faces are gone
    # the same surface as the boundary of the tets the importer makes from these bricks
    tets, _, new_points = hexes_to_tets(hexes, x)
    xt = np.concatenate([x, new_points.reshape(-1, 3)])
    assert _area(x, tris) == pytest.approx(_area(xt, boundary_faces(tets)), rel=1e-12)
    # outward: the divergence theorem gives the volume, 2 bricks + a wedge of half a brick
    p = x[tris]
    volume = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6.0
    assert volume == pytest.approx(2.5, rel=1e-12)


@pytest.fixture(scope="module")
def rest_dump(tmp_path_factory):
    """A RunLipOpening-format dump of the Badin face: rest; rest moved 1 mm along the camera's view
    direction; rest scaled by SCALE about the lips' centre; and a last frame cut short."""
    data = data_path("artisynth-face")
    _, xb = read_ansys_nodes(data / f"{MESH_PREFIX}.node")
    d = np.asarray(ARTISYNTH_VIEW_DIRECTION_BADIN) / np.linalg.norm(ARTISYNTH_VIEW_DIRECTION_BADIN)
    ex = _example("artisynth_lip_area")
    centre = xb[ex.lip_node_ids(data, xb)].mean(axis=0)
    scaled = centre + SCALE * (xb - centre)
    path = tmp_path_factory.mktemp("dump") / "nodes.txt"
    with open(path, "w") as fh:
        for t, x in ((0.0, xb), (0.01, xb + 0.001 * d), (0.02, scaled)):
            fh.write(f"T {t:.6f} 0.000000\n")
            np.savetxt(fh, x, fmt="%.9g")
        fh.write("T 0.030000 0.000000\n1.0 2.0 3.0\n")
    return data, path, len(xb)


def test_node_dump_reader_drops_a_cut_frame_and_names_a_wrong_mesh(rest_dump, tmp_path, capsys):
    data, path, n = rest_dump
    ex = _example("artisynth_lip_area")
    times, oop, X = ex.read_node_dump(path, n)
    assert times.tolist() == [0.0, 0.01, 0.02] and X.shape == (3, n, 3) and np.all(oop == 0)
    assert "incomplete" in capsys.readouterr().out
    with pytest.raises(ValueError, match="another mesh"):
        ex.read_node_dump(path, n + 1)
    empty = tmp_path / "empty.txt"
    empty.write_text("no frames here\n")
    with pytest.raises(ValueError, match="no frame"):
        ex.read_node_dump(empty, n)


def test_artisynth_lip_area_measures_the_rest_aperture_and_its_changes(rest_dump, tmp_path):
    data, path, _ = rest_dump
    args = [f"rest={path}", str(path), "--data", str(data), "--out", str(tmp_path)]
    report = _example("artisynth_lip_area").main(args)
    assert report["runs"]["nodes"]["area_mm2"] == report["runs"]["rest"]["area_mm2"]  # a bare path: its name
    run = report["runs"]["rest"]
    area = np.array(run["area_mm2"])
    assert area[0] == pytest.approx(REST_AREA_MM2, abs=0.01)  # the hex boundary is the tets' boundary
    assert area[1] == pytest.approx(area[0], abs=1e-6)  # a shift along the view direction changes nothing
    assert area[2] == pytest.approx(SCALE**2 * area[0], abs=0.05)
    assert max(run["error_mm2"]) < 0.05
    assert run["rest_node_difference_m"] < 1e-8  # the dump prints 9 significant digits
    orig = report["original"]
    assert orig["below_20_from_s"] == pytest.approx(0.42) and orig["shut_from_s"] is None  # 19.85 mm^2 at 0.42 s
    assert orig["mean_after_0.6s_mm2"] == pytest.approx(15.5, abs=0.1)
    saved = json.loads((tmp_path / "artisynth_lip_area.json").read_text())
    assert saved["runs"]["rest"]["area_mm2"] == run["area_mm2"]
    assert (tmp_path / "artisynth_lip_area.png").stat().st_size > 10_000


def test_hex_states_are_measured_as_artisynth_runs_with_lip_node_distances(rest_dump, tmp_path):
    """--hexes: wface's hex play (states.npz, wface's frame, the node file's order) is measured on the same
    boundary as the dumps: the same frames give the same areas; --lip-nodes: the 1 mm shift is 1 mm."""
    from wface.faces.artisynth import badin_to_wface

    data, path, n = rest_dump
    ex = _example("artisynth_lip_area")
    times, _, X = ex.read_node_dump(path, n)
    states = tmp_path / "states.npz"
    np.savez(states, x_hex_m=np.stack([badin_to_wface(x) for x in X]), time_s=times)
    with pytest.raises(ValueError, match="hex nodes"):
        ex.read_hex_states(states, n + 1)
    args = [f"dump={path}", "--hexes", f"hexes={states}", "--lip-nodes", "0", "0.01", "0.05"]
    report = ex.main(args + ["--data", str(data), "--out", str(tmp_path)])
    dump, hexes = report["runs"]["dump"], report["runs"]["hexes"]
    np.testing.assert_allclose(hexes["area_mm2"], dump["area_mm2"], atol=1e-6)
    assert hexes["source"] == "wface on the hexes" and hexes["oop"] is None
    d = report["lip_node_distance_mm"]["dump / hexes"]
    assert set(d) == {"0", "0.01"} and d["0"] < 1e-6 and d["0.01"] < 1e-6  # no frame at 0.05 s
    shifted = tmp_path / "shifted.npz"
    np.savez(shifted, x_hex_m=np.stack([badin_to_wface(X[0]), badin_to_wface(X[0])]), time_s=[0.0, 0.01])
    report = ex.main(
        [f"dump={path}", "--hexes", f"rest={shifted}", "--lip-nodes", "0.01"]
        + ["--data", str(data), "--out", str(tmp_path / "b")]
    )
    assert report["lip_node_distance_mm"]["dump / rest"]["0.01"] == pytest.approx(1.0, abs=1e-6)


def test_speech_states_on_the_tets_are_measured_on_the_file_nodes(rest_dump, tmp_path):
    """--tets: a wface speech run on the import (states.npz: every node, the node file's first, wface's frame) is
    measured on the node file's nodes, as the dumps are; a states.npz with fewer nodes is refused."""
    from wface.faces.artisynth import badin_to_wface

    data, path, n = rest_dump
    ex = _example("artisynth_lip_area")
    times, _, X = ex.read_node_dump(path, n)
    extra = np.full((len(times), 7, 3), 9.0)  # the nodes the import adds after the file's
    x = np.concatenate([np.stack([badin_to_wface(f) for f in X]), extra], axis=1)
    states = tmp_path / "states.npz"
    np.savez(states, node_positions_m=x, times_s=times)
    with pytest.raises(ValueError, match="fewer than the node file's"):
        ex.read_speech_states(states, n + 8)
    report = ex.main([f"dump={path}", "--tets", f"tets={states}", "--lip-nodes", "0.01"] + [
        "--data", str(data), "--out", str(tmp_path)])  # fmt: skip
    np.testing.assert_allclose(report["runs"]["tets"]["area_mm2"], report["runs"]["dump"]["area_mm2"], atol=1e-6)
    assert report["runs"]["tets"]["source"] == "wface on its tets"
    assert report["lip_node_distance_mm"]["dump / tets"]["0.01"] < 1e-6


def test_export_wface_tets_writes_the_import_back_in_the_badin_frame(tmp_path):
    """examples/artisynth_reference/export_wface_tets.py: the file RunLipOpening -Dlip.mesh reads."""
    from types import SimpleNamespace

    from wface.faces.artisynth import badin_to_wface

    export = _example("artisynth_reference/export_wface_tets")
    x_badin, hexes = _bricks()
    tets, _, steiner, _ = hexes_to_tets(hexes, x_badin, return_sources=True)
    x_badin = np.vstack([x_badin, steiner]) * 0.01
    n_file = len(_bricks()[0])
    model = SimpleNamespace(
        rest_positions_m=badin_to_wface(x_badin), tets=tets, metadata={"added_nodes": {"first_id": n_file}}
    )
    path = tmp_path / "tets.txt"
    assert export.write_tets(model, path) == (len(x_badin), n_file, len(tets))

    lines = path.read_text().splitlines()
    assert lines[0] == f"NODES {len(x_badin)} {n_file}"
    back = np.loadtxt(lines[1 : 1 + len(x_badin)])
    np.testing.assert_allclose(back, x_badin, atol=1e-14)  # Badin frame again, not wface's
    assert lines[1 + len(x_badin)] == f"TETS {len(tets)}"
    t = np.loadtxt(lines[2 + len(x_badin) :], dtype=np.int64)
    np.testing.assert_array_equal(t, tets)
    volume = signed_volumes(back, t)
    assert (volume > 0).all()  # the frame change is a rotation: orientation kept
    assert volume.sum() == pytest.approx(2.5e-6)  # two 1 cm bricks and half a one

    with pytest.raises(SystemExit, match="not a wface Badin import"):
        export.write_tets(SimpleNamespace(rest_positions_m=x_badin, tets=tets, metadata={}), tmp_path / "no.txt")


def test_export_wface_tets_refine_splits_each_tet_in_eight_conforming(tmp_path):
    """--refine: 8 children per tet that fill it exactly, midpoints shared between neighbours."""
    export = _example("artisynth_reference/export_wface_tets")
    x, hexes = _bricks()
    tets, _, steiner = hexes_to_tets(hexes, x)
    x = np.vstack([x, np.reshape(steiner, (-1, 3))])
    x8, tets8, ends = export.refine_tets(x, tets)

    n_edges = len(
        np.unique(np.sort(tets[:, [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]]], axis=2).reshape(-1, 2), axis=0)
    )
    assert len(x8) == len(x) + n_edges and len(ends) == n_edges  # one node per edge, not per tet edge
    np.testing.assert_allclose(x8[len(x) :], 0.5 * (x[ends[:, 0]] + x[ends[:, 1]]))
    assert len(tets8) == 8 * len(tets)
    v, v8 = signed_volumes(x, tets), signed_volumes(x8, tets8)
    assert (v8 > 0).all()
    np.testing.assert_allclose(v8.reshape(-1, 8).sum(axis=1), v, rtol=1e-12)  # the children fill each parent
    # conforming: every inner face is shared by exactly two children, and the boundary is the parents'
    # boundary cut in four (same area)
    faces = np.sort(tets8[:, [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]].reshape(-1, 3), axis=1)
    _, count = np.unique(faces, axis=0, return_counts=True)
    assert set(count.tolist()) <= {1, 2}
    assert _area(x8, boundary_faces(tets8)) == pytest.approx(_area(x, boundary_faces(tets)), rel=1e-12)
    assert len(boundary_faces(tets8)) == 4 * len(boundary_faces(tets))
    # written: the node file's nodes as "x y z", then each midpoint as "x y z a b" (its end nodes)
    from types import SimpleNamespace

    from wface.faces.artisynth import badin_to_wface

    model = SimpleNamespace(rest_positions_m=badin_to_wface(x), tets=tets, metadata={"added_nodes": {"first_id": 14}})
    file = tmp_path / "tets8.txt"
    assert export.write_tets(model, file, refine=True) == (len(x8), 14, len(tets8))
    lines = file.read_text().splitlines()
    rows = [line.split() for line in lines[1 : 1 + len(x8)]]
    assert [len(r) for r in rows] == [3] * len(x) + [5] * n_edges
    np.testing.assert_array_equal(np.array([r[3:] for r in rows[len(x) :]], dtype=np.int64), ends)
    np.testing.assert_array_equal(np.loadtxt(lines[2 + len(x8) :], dtype=np.int64), tets8)
