"""Non-rigid registration of a template skin to a target surface and/or landmarks.

The template's skin vertices x_i (m) move by displacements d_i that minimise (docs/design.md,
"Template fitting"):

    E(d) = 1/N_f sum_i w_i [(n_i . (x_i + d_i - p_i))^2 + beta |x_i + d_i - p_i|^2]   template -> target
         + 1/N_b sum_j w_j |sum_k b_jk (x_k + d_k) - q_j|^2                           target -> template
         + lam/N_l sum_l |sum_k c_lk (x_k + d_k) - y_l|^2                              landmarks
         + alpha sum_{i interior} |(L u)_i|^2 / A_i,   u = x + d - x0                  thin-plate smoothness

p_i is the closest target point of template vertex i (n_i the target normal there), q_j a target
vertex with b_j the barycentric weights of its closest template point, c_l the barycentric
embedding of landmark l in the template skin, y_l its target position, L the cotangent
Laplacian, A_i the lumped vertex area and u the whole displacement from the template x0 (the
stiffness holds the accumulated field, not each step's increment). The smoothness uses interior
rows only, so every affine displacement costs nothing and it penalises bending alone (a discrete
thin plate); a membrane term on each step's increment (not on u) damps steps that would collapse
small triangles. The point-to-plane data term with a small point-to-point share beta lets the
skin slide along the target (Chen & Medioni 1992). Correspondences are recomputed each iteration
(non-rigid ICP, Amberg et al. 2007) while alpha falls from stiff to supple. A pair is left out
when its closest point lies on the other surface's boundary (the template patch does not cover
the back of the head; the target has holes at the eyes) unless both points are on a boundary,
when the normals differ by more than 60 degrees, when the offset between the two does not run
along the normal (within 45 degrees: a point beside the other surface's edge), or when it is
farther than the iteration's cut-off. Each iteration is one sparse symmetric solve. With a
target surface the smoothness is a weight per unit area (``_spacing2_m2``): alpha means the same
on a 5K and a 100K face.

With a target surface the landmark weight falls with alpha (landmarks guide the start; the
surfaces decide the end). No step may turn a skin triangle over (by more than 120 degrees): where
one would, the corners of the folding triangles and their neighbours are held by a per-vertex
damping that grows tenfold per retry (a local trust region), and a stage that still folds the skin
is undone and ends the schedule. With landmarks alone (a marker frame, no scan) the
smoothness also holds a membrane term on the whole displacement: a thin plate would carry the
markers' affine trend out to the patch's borders (the ears, the top of the forehead), where no
data says anything; the membrane lets it fade.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix, csr_matrix, diags, identity, kron
from scipy.sparse.linalg import spsolve

from wface.mesh.closest import SurfaceQuery
from wface.mesh.surface import triangle_normals, vertex_normals
from wface.mesh.surface_fields import cotangent_laplacian

__all__ = ["RegistrationResult", "boundary_vertices", "register_surface"]

#: (alpha relative to the data terms, iterations) from stiff to supple
DEFAULT_SCHEDULE: tuple[tuple[float, int], ...] = ((30.0, 3), (10.0, 3), (3.0, 3), (1.0, 3), (0.3, 4))
_BETA = 0.1  # point-to-point share of the template -> target term
_MAX_NORMAL_DEG = 60.0
_ALONG_COS = np.cos(np.radians(45.0))
_FOLD_COS = -0.5  # a skin triangle turned by more than 120 degrees has folded over
_MEMBRANE = 0.1  # step damping (membrane on the increment) relative to the bending
_ANCHOR = 0.1  # landmarks alone: a membrane on the whole displacement, so it fades away from them
_FOLD_RETRIES = 6  # solves per iteration, holding the vertices of would-be folds ever harder
_MIN_CUT_M = 5e-3  # the correspondence cut-off never falls below this
_H_REF_M = 5.5e-3  # skin spacing the schedule's alphas refer to (the 20K built-in face at the ICT head's scale)


@dataclass
class RegistrationResult:
    """What ``register_surface`` found.

    Attributes:
        vertices_m: (n, 3) registered template vertices (vertices off the skin unchanged).
        distance_m: (n,) distance of each skin vertex to the target surface, NaN where the pair
            was left out in the last iteration (or there is no target surface).
        used: (n,) bool, the skin vertices paired with the target in the last iteration.
        landmark_residual_m: (l,) distance of each landmark to its target.
        history: per iteration {alpha, pairs, rms_mm, landmark_rms_mm}.
    """

    vertices_m: np.ndarray
    distance_m: np.ndarray
    used: np.ndarray
    landmark_residual_m: np.ndarray
    history: list[dict] = field(default_factory=list)


def boundary_vertices(triangles: np.ndarray, n: int) -> np.ndarray:
    """(n,) bool: vertices on an edge used by one triangle only."""
    tri = np.asarray(triangles, dtype=np.int64)
    edges = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
    uniq, counts = np.unique(edges, axis=0, return_counts=True)
    mask = np.zeros(n, dtype=bool)
    mask[uniq[counts == 1].ravel()] = True
    return mask


def _on_boundary(hit, triangles: np.ndarray, boundary: np.ndarray) -> np.ndarray:
    """(k,) bool: the closest point lies on a boundary vertex or on an edge between two boundary vertices."""
    corners = triangles[hit.triangle]
    zero = hit.barycentric < 1e-9
    n_zero = zero.sum(axis=1)
    on_b = boundary[corners]
    vertex_hit = (n_zero >= 2) & np.any(on_b & ~zero, axis=1)
    edge_hit = (n_zero == 1) & np.all(on_b | zero, axis=1)
    return vertex_hit | edge_hit


def _interp_normals(vertices, triangles, normals, hit) -> np.ndarray:
    n = np.einsum("kj,kjd->kd", hit.barycentric, normals[triangles[hit.triangle]])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def _step(A, b, u, alpha_rel, bend, membrane, *, anchored: bool, hold=None) -> np.ndarray:
    """(n, 3) step d of one iteration: (A + S + D + H) d = b - S u with S the smoothness on the
    whole displacement u (bending, plus the membrane anchor for landmarks alone), D the membrane
    damping of the step and H = diag(hold) per vertex; all scale with the data terms' mean diagonal."""
    diag = A.diagonal()
    scale = float(diag[diag > 0].mean()) if np.any(diag > 0) else 1.0
    S = alpha_rel * scale * (bend + _ANCHOR * membrane if anchored else bend)
    h = 1e-9 if hold is None else 1e-9 + np.repeat(hold, 3)
    K = A + S + _MEMBRANE * alpha_rel * scale * membrane + diags(scale * h)
    return spsolve(K.tocsc(), b - S @ u.ravel()).reshape(-1, 3)


def _unfolded_step(A, b, x, x0, tri, n_rest, alpha_rel, bend, membrane, *, anchored: bool) -> np.ndarray:
    """A step that turns no skin triangle over: where the plain step would fold triangles, their
    corners (and their neighbours) are held by a per-vertex damping that grows tenfold per retry, so
    the rest of the skin still moves (a local trust region)."""
    hold = np.zeros(len(x))
    for _ in range(_FOLD_RETRIES):
        d = _step(A, b, x - x0, alpha_rel, bend, membrane, anchored=anchored, hold=hold)
        bad = np.einsum("td,td->t", triangle_normals(x + d, tri), n_rest) < _FOLD_COS
        if not bad.any():
            return d
        near = np.zeros(len(x), dtype=bool)
        near[tri[bad].ravel()] = True
        near[tri[np.any(near[tri], axis=1)].ravel()] = True
        hold[near] = np.maximum(10.0 * hold[near], 10.0)
    return d


def _bary_matrix(rows_tri: np.ndarray, bary: np.ndarray, n: int) -> csr_matrix:
    """(k, n) sparse matrix of barycentric rows over the corners ``rows_tri`` (k, 3)."""
    k = len(rows_tri)
    return coo_matrix((bary.ravel(), (np.repeat(np.arange(k), 3), rows_tri.ravel())), shape=(k, n)).tocsr()


def _smoothness(vertices, triangles, skin_vertices) -> tuple[csr_matrix, csr_matrix]:
    """(bending, membrane), each (3n, 3n) and scaled so that the bending's mean diagonal is 1.

    bending: sum over interior skin vertices of |(L u)_i|^2 / A_i per coordinate (a thin plate,
    zero for every affine u). membrane: u^T L u (penalises stretching), applied to each step's
    increment only: a damping that keeps a step from collapsing small triangles (the corners of
    the mouth) without biasing the converged field.
    """
    n = len(vertices)
    lap, area = cotangent_laplacian(vertices, triangles)
    interior = np.zeros(n, dtype=bool)
    interior[skin_vertices] = True
    interior &= ~boundary_vertices(triangles, n)
    bend = lap.T @ (diags(interior / area) @ lap)
    d_bend = bend.diagonal()
    s_bend = float(d_bend[d_bend > 0].mean())
    s_lap = max(float(lap.diagonal().mean()), 1e-300)
    return kron(bend / s_bend, identity(3), format="csr"), kron(lap / s_lap, identity(3), format="csr")


def _spacing2_m2(vertices, triangles, skin_vertices) -> float:
    """Skin area per skin vertex (m^2): the square of the mesh spacing h.

    The surface terms are means over the ~N paired vertices (each weighs ~1/N ~ h^2) and the
    normalised bending's energy of a given smooth field scales as h^2, the membrane's as 1: the
    bending is therefore scaled by (h_ref/h)^4 and the membrane by (h_ref/h)^2 relative to the
    data, which makes the smoothness a weight per unit area, independent of the mesh.
    """
    e1 = vertices[triangles[:, 1]] - vertices[triangles[:, 0]]
    e2 = vertices[triangles[:, 2]] - vertices[triangles[:, 0]]
    return float(0.5 * np.linalg.norm(np.cross(e1, e2), axis=1).sum() / max(len(skin_vertices), 1))


def register_surface(
    vertices_m: np.ndarray,
    triangles: np.ndarray,
    *,
    target_vertices_m: np.ndarray | None = None,
    target_triangles: np.ndarray | None = None,
    target_samples: np.ndarray | None = None,
    landmark_triangles: np.ndarray | None = None,
    landmark_barycentric: np.ndarray | None = None,
    landmark_targets_m: np.ndarray | None = None,
    landmark_weight: float = 10.0,
    schedule: tuple[tuple[float, int], ...] = DEFAULT_SCHEDULE,
    max_distance_m: float = 0.02,
    progress=None,
) -> RegistrationResult:
    """Move the template skin onto a target surface and/or landmarks (module docstring).

    Args:
        vertices_m: (n, 3) template vertices (the skin's triangles index them; others are kept).
        triangles: (t, 3) template skin triangles.
        target_vertices_m, target_triangles: the target surface, already in the template's frame.
        target_samples: target vertex ids that pull on the template (default: all used by
            ``target_triangles``).
        landmark_triangles, landmark_barycentric: (l,) template triangle and (l, 3) weights of
            each landmark.
        landmark_targets_m: (l, 3) target position of each landmark (NaN rows are ignored).
        landmark_weight: lam, relative to the surface terms.
        schedule: (alpha, iterations) pairs, alpha relative to the data terms' mean diagonal.
        max_distance_m: cut-off of a correspondence in the first iteration; it shrinks to 3 x
            the median distance (at least 5 mm) as the fit converges.
        progress: optional callable(str) for one line per stage.

    Returns:
        A ``RegistrationResult``.
    """
    x0 = np.asarray(vertices_m, dtype=np.float64)
    tri = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    n = len(x0)
    skin = np.unique(tri)
    has_surface = target_vertices_m is not None
    lm_ok = None
    if landmark_targets_m is not None:
        lm_y = np.asarray(landmark_targets_m, dtype=np.float64).reshape(-1, 3)
        lm_ok = np.isfinite(lm_y).all(axis=1)
        lm_tri = tri[np.asarray(landmark_triangles)[lm_ok]]
        lm_b = np.asarray(landmark_barycentric, dtype=np.float64)[lm_ok]
        lm_y = lm_y[lm_ok]
        if not lm_ok.any():
            lm_ok = None
    if not has_surface and lm_ok is None:
        raise ValueError("register_surface needs a target surface, landmarks, or both")
    if has_surface:
        ty = np.asarray(target_vertices_m, dtype=np.float64)
        tt = np.asarray(target_triangles, dtype=np.int64).reshape(-1, 3)
        t_query = SurfaceQuery(ty, tt)
        t_normals = vertex_normals(ty, tt)
        t_boundary = boundary_vertices(tt, len(ty))
        samples = np.unique(tt) if target_samples is None else np.asarray(target_samples, dtype=np.int64)
    boundary = boundary_vertices(tri, n)
    bend, membrane = _smoothness(x0, tri, skin)
    if has_surface:  # per unit area, so that alpha means the same at 5K and at 100K tets
        r = _H_REF_M**2 / _spacing2_m2(x0, tri, skin)
        bend, membrane = bend * r**2, membrane * r
    x = x0.copy()
    n_rest = triangle_normals(x0, tri)
    cut = max_distance_m
    history = []
    alpha_first = schedule[0][0]
    used = np.zeros(n, dtype=bool)
    dist = np.full(n, np.nan)
    for alpha_rel, iters in schedule:
        x_stage = x.copy()
        # with a surface the landmarks only guide: their weight falls with the stiffness
        lam = landmark_weight * (alpha_rel / alpha_first if has_surface else 1.0)
        for _ in range(iters):
            A = csr_matrix((3 * n, 3 * n))
            b = np.zeros(3 * n)
            pairs = 0
            if has_surface:
                A_s, b_s, used, dist, pairs = _surface_terms(
                    x, tri, skin, boundary, t_query, ty, tt, t_normals, t_boundary, samples, cut
                )
                A, b = A + A_s, b + b_s
            if lm_ok is not None:
                B = kron(_bary_matrix(lm_tri, lm_b, n), identity(3), format="csr")
                r = lm_y.ravel() - B @ x.ravel()
                w = lam / len(lm_y)
                A = A + w * (B.T @ B)
                b = b + w * (B.T @ r)
            x = x + _unfolded_step(A, b, x, x0, tri, n_rest, alpha_rel, bend, membrane, anchored=not has_surface)
            rms = float(np.sqrt(np.nanmean(dist[used] ** 2)) * 1e3) if used.any() else None
            lm_rms = None
            if lm_ok is not None:
                lm_p = np.einsum("kj,kjd->kd", lm_b, x[lm_tri])
                lm_rms = float(np.sqrt(np.mean(np.sum((lm_p - lm_y) ** 2, axis=1))) * 1e3)
            history.append({"alpha": alpha_rel, "pairs": int(pairs), "rms_mm": rms, "landmark_rms_mm": lm_rms})
            if has_surface and used.any():
                cut = max(_MIN_CUT_M, min(cut, 3.0 * float(np.median(dist[used]))))
        folded = int(np.count_nonzero(np.einsum("td,td->t", triangle_normals(x, tri), n_rest) < _FOLD_COS))
        if folded:  # a stage that folds the skin is too supple for this target: keep the stiffer result
            x = x_stage
            history.append({"alpha": alpha_rel, "folded_triangles": folded, "kept": "previous stage"})
            if progress is not None:
                progress(f"registration alpha {alpha_rel:g}: {folded} skin triangle(s) fold; the previous stage stands")
            break
        if progress is not None:
            progress(f"registration alpha {alpha_rel:g}: {history[-1]}")
    if has_surface:
        hit = t_query.closest(x[skin])
        dist = np.full(n, np.nan)
        dist[skin] = hit.distance_m
        dist[~used] = np.nan
    lm_res = np.zeros(0)
    if lm_ok is not None:
        lm_res = np.full(len(lm_ok), np.nan)
        lm_res[lm_ok] = np.linalg.norm(np.einsum("kj,kjd->kd", lm_b, x[lm_tri]) - lm_y, axis=1)
    return RegistrationResult(x, dist, used, lm_res, history)


def _along_normal(offset: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(k,) bool: the offset to the closest point runs along the normal there (within 45 degrees),
    or is under a millimetre: a point beside a surface's edge, not above or below it, has no partner."""
    length = np.linalg.norm(offset, axis=1)
    return (np.abs(np.einsum("kd,kd->k", offset, normals)) >= _ALONG_COS * length) | (length < 1e-3)


def _surface_terms(x, tri, skin, boundary, t_query, ty, tt, t_normals, t_boundary, samples, cut):
    """Normal equations (A, b) of the two closest-point terms at the current template ``x``."""
    n = len(x)
    normals = vertex_normals(x, tri)
    cos_max = np.cos(np.radians(_MAX_NORMAL_DEG))
    # template -> target
    hit = t_query.closest(x[skin])
    nt = _interp_normals(ty, tt, t_normals, hit)
    edge = _on_boundary(hit, tt, t_boundary)
    ok = (hit.distance_m < cut) & (~edge | boundary[skin])  # a border may meet a border
    ok &= np.einsum("kd,kd->k", nt, normals[skin]) > cos_max
    ok &= _along_normal(hit.point_m - x[skin], nt) | (edge & boundary[skin])
    i = skin[ok]
    p, nn = hit.point_m[ok], nt[ok]
    w = 1.0 / max(len(i), 1)
    # per vertex block w (n n^T + beta I); rhs w (n n^T + beta I)(p - x)
    blocks = w * (nn[:, :, None] * nn[:, None, :] + _BETA * np.eye(3))
    rhs = np.einsum("kab,kb->ka", blocks, p - x[i])
    rows = (3 * i[:, None, None] + np.arange(3)[None, :, None]).repeat(3, axis=2)
    cols = (3 * i[:, None, None] + np.arange(3)[None, None, :]).repeat(3, axis=1)
    A = coo_matrix((blocks.ravel(), (rows.ravel(), cols.ravel())), shape=(3 * n, 3 * n)).tocsr()
    b = np.zeros(3 * n)
    np.add.at(b, (3 * i[:, None] + np.arange(3)).ravel(), rhs.ravel())
    used = np.zeros(n, dtype=bool)
    used[i] = True
    dist = np.full(n, np.nan)
    dist[skin] = hit.distance_m
    # target -> template
    q_query = SurfaceQuery(x, tri)
    q = ty[samples]
    back = q_query.closest(q)
    nq = _interp_normals(x, tri, normals, back)
    edge_b = _on_boundary(back, tri, boundary)
    ok_b = (back.distance_m < cut) & (~edge_b | t_boundary[samples])
    ok_b &= np.einsum("kd,kd->k", nq, t_normals[samples]) > cos_max
    ok_b &= _along_normal(q - back.point_m, nq) | (edge_b & t_boundary[samples])
    if ok_b.any():
        B = kron(_bary_matrix(tri[back.triangle[ok_b]], back.barycentric[ok_b], n), identity(3), format="csr")
        r = q[ok_b].ravel() - B @ x.ravel()
        wb = 1.0 / ok_b.sum()
        A = A + wb * (B.T @ B)
        b = b + wb * (B.T @ r)
    return A, b, used, dist, int(ok.sum() + ok_b.sum())
