"""Actuation basis: building, synthesis, analysis, refinement, RBF carry-over, retargeting."""

from __future__ import annotations

import numpy as np
import pytest

from wface.basis import (
    ActuationBasis,
    FaceSplit,
    MarkerBasis,
    analyze,
    interpolate_to_mesh,
    load_basis,
    match_elements,
    refine_marker_basis,
    retarget,
)
from wface.basis.core import polygons_to_triangles


def _grid_basis(n_side=12, n_elements=5, seed=0) -> ActuationBasis:
    """A bumpy sheet (metres) with smooth Gaussian 'muscle' displacement fields."""
    rng = np.random.default_rng(seed)
    u = np.linspace(-0.05, 0.05, n_side)
    x, y = np.meshgrid(u, u, indexing="ij")
    v = np.stack([x.ravel(), y.ravel(), 0.01 * np.cos(30 * x.ravel()) * np.cos(30 * y.ravel())], 1)
    quads = []
    for i in range(n_side - 1):
        for j in range(n_side - 1):
            a = i * n_side + j
            quads.append([a, a + n_side, a + n_side + 1, a + 1])
    quads = np.array(quads)
    shapes = []
    for _ in range(n_elements):
        c = rng.uniform(-0.04, 0.04, size=2)
        w = np.exp(-np.sum((v[:, :2] - c) ** 2, axis=1) / (2 * 0.02**2))
        shapes.append(w[:, None] * rng.normal(scale=0.005, size=3))
    return ActuationBasis(
        v, np.array(shapes), [f"m{i}_L" for i in range(n_elements)], np.full(len(quads), 4), quads.ravel()
    )


def test_polygons_to_triangles_and_synthesis():
    tri = polygons_to_triangles(np.array([3, 4, 5]), np.arange(12))
    np.testing.assert_array_equal(tri, [[0, 1, 2], [3, 4, 5], [3, 5, 6], [7, 8, 9], [7, 9, 10], [7, 10, 11]])
    b = _grid_basis()
    x = np.array([0.2, 0.0, 1.0, 0.5, 0.1])
    pos = b.synthesize(x)
    np.testing.assert_allclose(pos, b.neutral_m + np.tensordot(x, b.shapes_m, axes=1), atol=1e-15)
    assert b.synthesize(np.stack([x, x])).shape == (2, b.n_vertices, 3)
    with pytest.raises(ValueError, match="5 elements"):
        b.synthesize(np.ones(3))


def test_save_load_round_trip_and_builders(tmp_path):
    b = _grid_basis()
    b.save(tmp_path / "b.npz")
    c = load_basis(tmp_path / "b.npz")
    assert c.names == b.names
    np.testing.assert_array_equal(c.shapes_m, b.shapes_m)
    np.testing.assert_array_equal(c.neutral_m, b.neutral_m)
    np.testing.assert_array_equal(c.triangles, b.triangles)
    d = ActuationBasis.from_displacements(b.neutral_m, b.shapes_m, b.names, triangles=b.triangles)
    np.testing.assert_array_equal(d.triangles, b.triangles)

    # OBJ set in centimetres: neutral plus one file per element
    def write_obj(path, verts):
        with open(path, "w") as fh:
            fh.writelines(f"v {float(p[0])!r} {float(p[1])!r} {float(p[2])!r}\n" for p in verts)
            fh.writelines("f " + " ".join(str(i + 1) for i in q) + "\n" for q in b.face_indices.reshape(-1, 4))

    write_obj(tmp_path / "neutral.obj", b.neutral_m * 100)
    paths = {}
    for i, n in enumerate(b.names):
        paths[n] = tmp_path / f"{n}.obj"
        write_obj(paths[n], (b.neutral_m + b.shapes_m[i]) * 100)
    o = ActuationBasis.from_obj_files(tmp_path / "neutral.obj", paths, units_to_m=0.01)
    np.testing.assert_allclose(o.shapes_m, b.shapes_m, atol=1e-15)
    with pytest.raises(FileNotFoundError, match="nope.npz"):
        load_basis(tmp_path / "nope.npz")
    np.savez(tmp_path / "junk.npz", a=np.zeros(3))
    with pytest.raises(ValueError, match="junk.npz: neither"):
        load_basis(tmp_path / "junk.npz")


def _marker_basis(b: ActuationBasis, k=20, seed=1) -> MarkerBasis:
    rng = np.random.default_rng(seed)
    ids = rng.choice(b.n_vertices, k, replace=False)
    return MarkerBasis(b.vertex_shapes(ids), [f"k{i}" for i in range(k)], list(b.names), b.neutral_m[ids])


def test_analysis_recovers_contractions_with_gaps_and_split():
    b = _grid_basis(n_elements=6)
    mb = _marker_basis(b, k=25)
    rng = np.random.default_rng(4)
    x_true = rng.uniform(0, 1, size=(40, 6))
    x_true[x_true < 0.3] = 0.0  # many inactive elements
    d = mb.predict(x_true)
    an = analyze(mb, d)
    np.testing.assert_allclose(an.contractions, x_true, atol=1e-8)
    assert an.marker_rms_m.max() < 1e-10
    d_gap = d.copy()
    d_gap[5, :3] = np.nan
    an_gap = analyze(mb, d_gap, warm_start=False)
    np.testing.assert_allclose(an_gap.contractions, x_true, atol=1e-8)
    assert np.isnan(an_gap.error_m[5, :3]).all()
    d_gap[7] = np.nan  # a frame with no markers at all: no contractions, NaN error, no crash
    an_gap = analyze(mb, d_gap)
    assert np.isnan(an_gap.marker_rms_m[7]) and np.all(an_gap.contractions[7] == 0)
    np.testing.assert_allclose(an_gap.contractions[8:], x_true[8:], atol=1e-8)
    # Above the box: clipped at 1, or followed with exaggeration (x >= 0)
    big = mb.predict(np.full((1, 6), 1.5))
    assert analyze(mb, big).contractions.max() <= 1.0
    np.testing.assert_allclose(analyze(mb, big, upper=None).contractions, 1.5, atol=1e-8)
    # A split with disjoint groups solves each independently (same answer when the groups decouple)
    split = FaceSplit([(np.arange(12), np.arange(3)), (np.arange(12, 25), np.arange(3, 6))])
    an_split = analyze(mb, d, split=split)
    assert an_split.contractions.shape == (40, 6)
    with pytest.raises(ValueError, match="overlap"):
        FaceSplit([(np.arange(3), [0]), (np.arange(2, 5), [1])])


def test_analysis_plot_says_what_its_colours_and_frames_are(tmp_path, monkeypatch):
    """analysis.png: the colour bar reads 'contraction (0-1, dimensionless)', the title names the frames."""
    pytest.importorskip("matplotlib")
    from matplotlib.figure import Figure

    from wface.basis import plots

    mb = _marker_basis(_grid_basis(n_elements=4), k=20)
    an = analyze(mb, mb.predict(np.random.default_rng(2).uniform(0, 1, size=(12, 4))))
    saved = []
    monkeypatch.setattr(Figure, "savefig", lambda fig, path, **kw: saved.append(fig))
    plots.plot_analysis(an, tmp_path / "a.png", title=plots.frames_title("JawMoCap.c3d", (0, 600, 5)))
    (fig,) = saved
    assert fig.axes[0].get_title() == "JawMoCap.c3d, frames 0:600:5"
    assert fig.axes[-1].get_ylabel() == "contraction (0-1, dimensionless)"  # the colour bar's axes
    assert plots.frames_title("a.c3d", None) == "a.c3d, all frames"
    assert plots.frames_title("a.c3d", (None, 90, 1)) == "a.c3d, frames :90:1"


def test_analysis_matches_scipy_per_frame_on_noisy_data():
    from scipy.optimize import lsq_linear

    b = _grid_basis(n_elements=8, seed=3)
    mb = _marker_basis(b, k=15, seed=2)
    rng = np.random.default_rng(0)
    d = mb.predict(rng.uniform(0, 1, size=(20, 8))) + rng.normal(scale=3e-4, size=(20, 15, 3))
    an = analyze(mb, d)
    a = mb.shapes_m.reshape(-1, 8)
    for f in range(20):
        ref = lsq_linear(a, d[f].ravel(), bounds=(0, 1), method="bvls", tol=1e-14)
        cost = np.sum((a @ an.contractions[f] - d[f].ravel()) ** 2)
        assert cost <= np.sum((a @ ref.x - d[f].ravel()) ** 2) * (1 + 1e-9) + 1e-20


def test_refinement_reduces_training_and_held_out_error():
    b_true = _grid_basis(n_elements=5, seed=7)
    mb_true = _marker_basis(b_true, k=30, seed=3)
    rng = np.random.default_rng(11)
    wrong = mb_true.shapes_m + rng.normal(scale=1.5e-3, size=mb_true.shapes_m.shape)
    mb0 = mb_true.with_shapes(wrong)
    takes = [mb_true.predict(rng.uniform(0, 1, size=(60, 5)) * (rng.random((60, 5)) < 0.6)) for _ in range(3)]
    res = refine_marker_basis(mb0, takes[:2], max_iterations=15, rel_tol=1e-4)
    e = res.errors_m
    assert e[-1] < 0.2 * e[0]
    assert min(e) == pytest.approx(res.errors_m[-1]) or min(e) < e[0]
    before = analyze(mb0, takes[2]).total_rms_m
    after = analyze(res.basis, takes[2]).total_rms_m
    assert after < 0.3 * before


def test_interpolate_to_mesh_is_exact_at_markers_and_local():
    b = _grid_basis(n_side=30, n_elements=2)
    ids = np.array([300, 310, 320, 500, 510, 520, 700, 710, 720])
    change = np.zeros((len(ids), 3, 2))
    change[:, 2, 0] = 0.001  # +1 mm in z for element 0 at all markers
    out = interpolate_to_mesh(b, b.neutral_m[ids], change, fade_start_m=0.02, fade_end_m=0.03)
    np.testing.assert_allclose(out.shapes_m[0, ids, 2] - b.shapes_m[0, ids, 2], 0.001, atol=1e-12)
    np.testing.assert_array_equal(out.shapes_m[1], b.shapes_m[1])
    far = np.linalg.norm(b.neutral_m[:, None, :2] - b.neutral_m[ids][None, :, :2], axis=2).min(1) > 0.03
    np.testing.assert_array_equal(out.shapes_m[0, far], b.shapes_m[0, far])


def test_retarget_matches_names_and_reports_unmatched():
    src = _grid_basis(n_elements=4)
    tgt = ActuationBasis(src.neutral_m * 1.2, src.shapes_m[[2, 0, 1]] * 2, ["m2_l", "M0Left", "other"], src.face_counts,
                         src.face_indices)  # fmt: skip
    m = match_elements(src.names, tgt.names)
    assert sorted(m.pairs) == [(0, 1), (2, 0)]
    assert m.unmatched_source == ["m1_L", "m3_L"] and m.unmatched_target == ["other"]
    x = np.array([[0.5, 0.1, 0.25, 0.9]])
    r = retarget(x, src.names, tgt, synthesize=True, name_map={"m1_L": "other"})
    np.testing.assert_allclose(r.contractions, [[0.25, 0.5, 0.1]])
    np.testing.assert_allclose(r.positions_m[0], tgt.synthesize(r.contractions[0]))
    with pytest.raises(ValueError, match="no element names in common"):
        retarget(x[:, :1], ["zzz"], tgt)


def test_refinement_support_keeps_elements_local():
    """With a support fraction, an element's shape changes only where it already acts."""
    b = _grid_basis(n_elements=4, seed=5)
    mb = _marker_basis(b, k=30, seed=6)
    rng = np.random.default_rng(2)
    x = rng.uniform(0, 1, size=(80, 4))
    d = mb.predict(x) + rng.normal(scale=2e-3, size=(80, 30, 3))  # noise everywhere, also far away
    res = refine_marker_basis(mb, [d], max_iterations=3, support_fraction=0.2)
    mag = np.linalg.norm(mb.shapes_m, axis=1)
    outside = mag < 0.2 * mag.max(axis=0, keepdims=True)
    assert outside.any()
    np.testing.assert_array_equal(np.linalg.norm(res.basis.shapes_m - mb.shapes_m, axis=1)[outside], 0.0)
    assert res.errors_m[-1] < res.errors_m[0]


def test_select_regularization_by_leave_one_take_out():
    from wface.basis.refine import select_regularization

    b = _grid_basis(n_elements=4, seed=8)
    mb_true = _marker_basis(b, k=20, seed=9)
    rng = np.random.default_rng(3)
    mb0 = mb_true.with_shapes(mb_true.shapes_m + rng.normal(scale=1e-3, size=mb_true.shapes_m.shape))
    takes = [mb_true.predict(rng.uniform(0, 1, size=(40, 4))) for _ in range(3)]
    lam, scores = select_regularization(mb0, takes, candidates=(0.01, 100.0), frame_step=1, max_iterations=4)
    assert lam == 0.01 and scores[0.01] < scores[100.0]  # noise-free data: the weak prior wins
    lam, n_it, scores = select_regularization(mb0, takes, candidates=(0.01,), frame_step=1, max_iterations=4,
                                              choose_iterations=True)  # fmt: skip
    assert n_it >= 1  # refining beats the perturbed start on held-out takes


def _slit_sheet(n_x=25, n_half=10, gap_m=0.0005, corner_m=0.03):
    """A curved 10 x 10 cm sheet cut by a slit ('mouth') along y = 0 for |x| < corner_m.

    The rows either side of the slit are ``gap_m`` apart (the lips touch); they are joined
    by quads only beyond the corners. Returns (basis, upper row ids, lower row ids).
    """
    x = np.linspace(-0.05, 0.05, n_x)
    y = np.concatenate([np.linspace(-0.05, -gap_m / 2, n_half), np.linspace(gap_m / 2, 0.05, n_half)])
    xx, yy = np.meshgrid(x, y, indexing="ij")
    v = np.stack([xx.ravel(), yy.ravel(), 0.01 * (xx.ravel() / 0.05) ** 2], 1)  # curved like a face
    ny = len(y)
    quads = []
    for i in range(n_x - 1):
        for j in range(ny - 1):
            if j == n_half - 1 and abs(0.5 * (x[i] + x[i + 1])) < corner_m:
                continue  # the slit
            a = i * ny + j
            quads.append([a, a + ny, a + ny + 1, a + 1])
    quads = np.array(quads)
    b = ActuationBasis(v, np.zeros((1, len(v), 3)), ["m0"], np.full(len(quads), 4), quads.ravel())
    cols = np.arange(n_x)
    return b, cols * ny + n_half, cols * ny + n_half - 1


def test_surface_interpolation_keeps_touching_lips_apart():
    """A change on the lower lip moves the lower lip, not the touching upper lip (old metric: it does)."""
    b, upper_row, lower_row = _slit_sheet()
    inner = np.abs(b.neutral_m[lower_row, 0]) < 0.015  # the middle of the mouth, far from the corners
    lower_m, upper_m = lower_row[inner] - 2, upper_row[inner] + 2  # markers two rows (11 mm) off the slit
    ids = np.concatenate([lower_m, upper_m])
    change = np.zeros((len(ids), 3, 1))
    change[: len(lower_m), 2, 0] = 0.001  # lower lip +1 mm out of the plane, upper lip markers still
    mid = np.abs(b.neutral_m[:, 0]) < 0.01
    moved = {}
    for metric in ("surface", "euclidean"):
        out = interpolate_to_mesh(b, b.neutral_m[ids], change, metric=metric)
        dz = out.shapes_m[0, :, 2]
        np.testing.assert_allclose(dz[ids], change[:, 2, 0], atol=1e-12)  # exact at the markers
        moved[metric] = (np.abs(dz[upper_row[mid[upper_row]]]).max(), np.abs(dz[lower_row[mid[lower_row]]]).min())
    up_s, low_s = moved["surface"]
    up_e, low_e = moved["euclidean"]
    assert low_s > 0.9e-3 and up_s < 0.1e-3  # the upper lip edge stays put (within 10 %)
    assert up_e > 0.3e-3  # straight distances: the upper lip is dragged by a third of the change or more
    assert up_s < 0.2 * up_e


def test_surface_distances_go_around_the_slit():
    from wface.mesh.surface_fields import surface_distances

    b, upper_row, lower_row = _slit_sheet()
    mid = len(upper_row) // 2
    tri = b.triangles
    t = np.flatnonzero((tri == lower_row[mid]).any(axis=1))[0]
    d = surface_distances(b.neutral_m, tri, [t], (tri[t] == lower_row[mid]).astype(float)[None])
    straight = np.linalg.norm(b.neutral_m[upper_row[mid]] - b.neutral_m[lower_row[mid]])
    assert straight < 1e-3 and d[upper_row[mid]] > 0.055  # around a corner 3 cm away and back
    assert d[lower_row[mid]] < 1e-14
    edge = np.linalg.norm(b.neutral_m[lower_row[mid + 1]] - b.neutral_m[lower_row[mid]])
    np.testing.assert_allclose(d[lower_row[mid + 1]], edge, rtol=1e-12)  # one edge along the row


def test_biharmonic_interpolate_reproduces_affine_fields_inside_a_flat_mesh():
    from wface.mesh.surface_fields import biharmonic_interpolate

    b = _grid_basis(n_side=15)
    flat = b.neutral_m * [1, 1, 0]
    tri = b.triangles
    rng = np.random.default_rng(0)
    pt = rng.choice(len(tri), 12, replace=False)
    bary = rng.dirichlet(np.ones(3), size=12)
    p = np.einsum("kj,kjd->kd", bary, flat[tri[pt]])
    f = lambda q: np.stack([np.ones(len(q)) * 0.3, 2.0 * q[:, 0] - q[:, 1]], 1)  # noqa: E731
    u = biharmonic_interpolate(flat, tri, pt, bary, f(p))
    np.testing.assert_allclose(u[:, 0], 0.3, atol=1e-12)  # constants exactly, everywhere
    inside = np.abs(flat[:, :2]).max(axis=1) < 0.03
    np.testing.assert_allclose(u[inside, 1], f(flat[inside])[:, 1], atol=0.1 * np.ptp(f(p)[:, 1]))  # bent, see module


def test_interpolate_to_mesh_rejects_unknown_metric():
    b = _grid_basis(n_elements=1)
    with pytest.raises(ValueError, match="metric"):
        interpolate_to_mesh(b, b.neutral_m[:3], np.zeros((3, 3, 1)), metric="geodesic")


def test_surface_interpolation_of_coincident_markers_needs_smoothing():
    b = _grid_basis(n_side=20, n_elements=1)
    ids = np.array([50, 50, 120, 200])  # two markers on one vertex, disagreeing
    change = np.zeros((4, 3, 1))
    change[0, 2, 0], change[1, 2, 0] = 0.001, 0.002
    with pytest.raises(ValueError, match="smoothing > 0"):
        interpolate_to_mesh(b, b.neutral_m[ids], change)
    dz = interpolate_to_mesh(b, b.neutral_m[ids], change, smoothing=1e-6).shapes_m[0, ids, 2] - b.shapes_m[0, ids, 2]
    np.testing.assert_allclose(dz, [0.0015, 0.0015, 0.0, 0.0], atol=2e-5)  # the least-squares compromise
    smooth = interpolate_to_mesh(b, b.neutral_m[ids], change, smoothing=1.0).shapes_m[0, ids, 2] - b.shapes_m[0, ids, 2]
    assert smooth[0] < dz[0]  # more smoothing, less reach
