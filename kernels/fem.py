"""Nonlinear FEM of the face flesh and muscles (Warp device code, float64 and float32).

Linear tetrahedra, F = Ds Dm^-1. Forces of element t on its nodes: H = -V0 P Dm^-T, columns to
nodes 1..3, node 0 gets minus their sum (Teran et al. 2003, 2005; docs/design.md, "Elements and forces").

Flesh (isotropic, on the signed singular values s of F = U diag(s) V^T, det U = det V = +1, the
smallest singular value carrying the sign of det F; Irving et al. 2004):

    psi(s) = mu10 (J^-2/3 I1 - 3) + mu01 (J^-4/3 I2 - 3) + mu20 (J^-2/3 I1 - 3)^2 + kappa/2 (ln J)^2
             + kq/2 (J - 1)^2,
    J = s1 s2 s3, I1 = sum s_i^2, I2 = sum_{i<j} s_i^2 s_j^2 (kq: ArtiSynth's quadratic bulk potential,
    ``Material.bulk_potential``; one of kappa and kq is 0).

Inversion: singular values are clamped below at c (``clamp``), s^ = max(s, c). So that forces stay
the exact gradient of an energy (energy line search, finite-difference tests) the energy is
continued below the clamp by its first-order Taylor expansion in the clamped values
(Stomakhin et al. 2012):  psi_ext(s) = psi(s^) + sum_i g_i(s^) (s_i - s^_i), which is C1.
Its gradient is G_j = g_j(s^) + [s_j >= c] sum_i H_ij(s^) (s_i - s^_i), and P = U diag(G) V^T.
psi is written as a sum of monomials c_k prod s_i^a_ki plus the volumetric term, so its first,
second and third derivatives are closed form.

Stiffness (Teran et al. 2005; Smith, de Goes & Kim 2019): dP/dF has nine eigen-modes in the
diagonal frame: the 3x3 block A = d2 psi_ext / ds ds on the diagonal entries, and for each pair
(i, j) a symmetric mode with eigenvalue (G_i - G_j)/(s_i - s_j) (limit A_ii - A_ij when
s_i ~ s_j) and a rotational mode with (G_i + G_j)/(s_i + s_j). The projected tangent clamps
negative eigenvalues (and A's) at zero; the exact tangent keeps them.

Muscle fibre of one (tet, muscle) entry, fibre direction d, q = F d, lam = |q|:
    T(lam, a) = k (a f_L(lam) + f_P(lam)), k = fraction * strength * sigma_max,
    P_f = (T/lam) q d^T, energy W = k (a G_L(lam) + G_P(lam)), G = integral of f from 1 to lam.
    d2W/dq2 = (T/lam) I + (T' - T/lam) q q^T / lam^2 has eigenvalues T/lam (across the fibre) and
    T' (along it); the projected tangent clamps both at zero (T >= 0 always for a >= 0).
Force-length f_L and passive f_P are the piecewise curves of docs/design.md, "Muscle fibres".

Deviatoric fibres (kernel flag ``fibre_law``, the index of ``Material.fibre_stress`` in
``FIBRE_STRESSES``: 0 uniaxial, 1 "deviatoric", 2 "blemker", deviatoric with Blemker's curves): the
curves of lam~ = phi(J) lam, phi = J^-1/3 (continued by its tangent line below J_c = clamp^3; see
``fibre.py`` for d lam~/dF and d2 lam~), P_f = T(lam~) d lam~/dF. Tangent: T' g g^T + T d2 lam~
(g = d lam~/dF). Its isotropic part T lam d2 phi(J) is a function of J alone, so it joins the
flesh's singular-value modes (G_i += c phi' J/s_i, A_ij += c (phi'' J^2/(s_i s_j) + phi' [i != j] s_k),
c = sum over the tet's entries of T lam) and is projected with them; the rest, T' g g^T +
T phi' (a b^T + b a^T) on span{a = vec(n d^T), b = vec(cof F)} and (T phi/lam) (I - n n^T) (x) d d^T,
is projected by an exact 2x2 eigen-decomposition on that span and a clamp of the last coefficient.
Each projected piece is PSD, so their sum is; the exact tangent is the sum unclamped.

All kernels come from ``fem_kernels(dtype)`` (dtype = wp.float64 or wp.float32), built once per
dtype. The flesh energy in singular values lives in ``flesh.py``, the fibre curves in ``fibre.py``.
"""

import functools

import warp as wp

from wface.kernels.fibre import fibre_functions
from wface.kernels.flesh import flesh_functions

wp.set_module_options({"enable_backward": False})

__all__ = ["fem_kernels"]


@functools.cache
def fem_kernels(dtype):  # noqa: C901 - one closure per scalar type keeps both variants identical
    """Return a namespace of the FEM kernels for scalar ``dtype`` (``wp.float64`` or ``wp.float32``)."""
    S = dtype
    vec3 = wp.types.vector(3, S)
    vec9 = wp.types.vector(9, S)
    mat33 = wp.types.matrix((3, 3), S)
    mat99 = wp.types.matrix((9, 9), S)
    vec45 = wp.types.vector(45, S)  # a symmetric 9x9 matrix, upper triangle row by row
    tie_eps = 1.0e-6 if S == wp.float64 else 3.0e-3
    fibre = fibre_functions(S)
    fibre_tension = fibre.fibre_tension
    force_length = fibre.force_length
    deviatoric_fibre = fibre.deviatoric_fibre
    deviatoric_fibre_tangent = fibre.deviatoric_fibre_tangent
    isotropic_volume_terms = fibre.isotropic_volume_terms
    volume_factor = fibre.volume_factor
    flesh = flesh_functions(S)
    flesh_energy = flesh.flesh_energy
    flesh_stress = flesh.flesh_stress
    flesh_response = flesh.flesh_response

    # ------------------------------------------------------------------ element helpers
    @wp.func
    def deformation_gradient(x: wp.array(dtype=vec3), tets: wp.array2d(dtype=wp.int32), dm_inv: mat33, t: int):
        x0 = x[tets[t, 0]]
        Ds = wp.matrix_from_cols(x[tets[t, 1]] - x0, x[tets[t, 2]] - x0, x[tets[t, 3]] - x0)
        return Ds * dm_inv

    @wp.func
    def scatter_stress(
        P: mat33, dm_inv: mat33, scale: S, tets: wp.array2d(dtype=wp.int32), t: int, out: wp.array(dtype=vec3)
    ):
        """out[node] += scale * P r_a (r_a = rows of Dm^-1), node 0 gets minus the sum."""
        H = scale * (P * wp.transpose(dm_inv))
        c1 = vec3(H[0, 0], H[1, 0], H[2, 0])
        c2 = vec3(H[0, 1], H[1, 1], H[2, 1])
        c3 = vec3(H[0, 2], H[1, 2], H[2, 2])
        wp.atomic_add(out, tets[t, 1], c1)
        wp.atomic_add(out, tets[t, 2], c2)
        wp.atomic_add(out, tets[t, 3], c3)
        wp.atomic_add(out, tets[t, 0], -(c1 + c2 + c3))

    # ------------------------------------------------------------------ kernels
    @wp.kernel(module="unique", enable_backward=False)
    def element_forces(
        # Model:
        tets: wp.array2d(dtype=wp.int32),
        dm_inv: wp.array(dtype=mat33),
        rest_volume: wp.array(dtype=S),
        mu10: S,
        mu01: S,
        mu20: S,
        kappa: S,
        kq: S,
        clamp: S,
        fibre_law: int,
        muscle_curves: wp.array(dtype=wp.int32),
        entry_start: wp.array(dtype=wp.int32),
        entry_muscle: wp.array(dtype=wp.int32),
        entry_direction: wp.array(dtype=vec3),
        entry_coef: wp.array(dtype=S),
        # State in:
        x: wp.array(dtype=vec3),
        activation: wp.array(dtype=S),
        # Out:
        forces_out: wp.array(dtype=vec3),
        energy_out: wp.array(dtype=S),
    ):
        """Total nodal forces f(x, a) (accumulated) and per-tet energy V0 (psi_ext + sum W)."""
        t = wp.tid()
        Dmi = dm_inv[t]
        F = deformation_gradient(x, tets, Dmi, t)
        energy, P = flesh_stress(F, mu10, mu01, mu20, kappa, kq, clamp)
        for e in range(entry_start[t], entry_start[t + 1]):
            d = entry_direction[e]
            m = entry_muscle[e]
            if fibre_law != 0:
                jc = clamp * clamp * clamp
                lam, lt, T, dT, W, g = deviatoric_fibre(F, d, activation[m], entry_coef[e], jc, muscle_curves[m])
                energy = energy + W
                P = P + T * g
                continue
            q = F * d
            lam = wp.length(q)
            T, dT, W = fibre_tension(lam, activation[m], entry_coef[e], muscle_curves[m])
            energy = energy + W
            if lam > S(1.0e-12):
                P = P + (T / lam) * wp.outer(q, d)
        V0 = rest_volume[t]
        energy_out[t] = V0 * energy
        scatter_stress(P, Dmi, -V0, tets, t, forces_out)

    @wp.kernel(module="unique", enable_backward=False)
    def element_energy(
        # Model:
        tets: wp.array2d(dtype=wp.int32),
        dm_inv: wp.array(dtype=mat33),
        rest_volume: wp.array(dtype=S),
        mu10: S,
        mu01: S,
        mu20: S,
        kappa: S,
        kq: S,
        clamp: S,
        fibre_law: int,
        muscle_curves: wp.array(dtype=wp.int32),
        entry_start: wp.array(dtype=wp.int32),
        entry_muscle: wp.array(dtype=wp.int32),
        entry_direction: wp.array(dtype=vec3),
        entry_coef: wp.array(dtype=S),
        # State in:
        x: wp.array(dtype=vec3),
        activation: wp.array(dtype=S),
        # Out:
        energy_out: wp.array(dtype=S),
    ):
        """Per-tet energy V0 (psi_ext(s) + sum over fibre entries of W)."""
        t = wp.tid()
        F = deformation_gradient(x, tets, dm_inv[t], t)
        energy = flesh_energy(F, mu10, mu01, mu20, kappa, kq, clamp)
        for e in range(entry_start[t], entry_start[t + 1]):
            lam = wp.length(F * entry_direction[e])
            if fibre_law != 0:
                phi, dphi, ddphi = volume_factor(wp.determinant(F), clamp * clamp * clamp)
                lam = phi * lam
            T, dT, W = fibre_tension(lam, activation[entry_muscle[e]], entry_coef[e], muscle_curves[entry_muscle[e]])
            energy = energy + W
        energy_out[t] = rest_volume[t] * energy

    @wp.func
    def fibre_nodal_forces(
        x: wp.array(dtype=vec3),
        tets: wp.array2d(dtype=wp.int32),
        Dmi: mat33,
        V0: S,
        t: int,
        d: vec3,
        k: S,
        clamp: S,
        fibre_law: int,
        curves: int,
        w: S,
    ):
        """The forces (c1, c2, c3) on nodes 1..3 of one fibre entry at activation ``w`` (node 0 gets minus
        their sum): the columns of H = -w V0 P_f Dm^-T, P_f at full activation."""
        F = deformation_gradient(x, tets, Dmi, t)
        q = F * d
        lam = wp.length(q)
        P = mat33()
        if lam > S(1.0e-12):
            if fibre_law != 0:
                lam0, lt, T, dT, W, g = deviatoric_fibre(F, d, S(0.0), k, clamp * clamp * clamp, curves)
                fl, dfl, gl = force_length(lt - S(1.0), curves)
                P = (k * fl) * g
            else:
                fl, dfl, gl = force_length(lam - S(1.0), curves)
                P = (k * fl / lam) * wp.outer(q, d)
        H = (-w * V0) * (P * wp.transpose(Dmi))
        return vec3(H[0, 0], H[1, 0], H[2, 0]), vec3(H[0, 1], H[1, 1], H[2, 1]), vec3(H[0, 2], H[1, 2], H[2, 2])

    @wp.kernel(module="unique", enable_backward=False)
    def muscle_forces(
        # Model:
        tets: wp.array2d(dtype=wp.int32),
        dm_inv: wp.array(dtype=mat33),
        rest_volume: wp.array(dtype=S),
        entry_tet: wp.array(dtype=wp.int32),
        entry_muscle: wp.array(dtype=wp.int32),
        entry_direction: wp.array(dtype=vec3),
        entry_coef: wp.array(dtype=S),
        clamp: S,
        fibre_law: int,
        muscle_curves: wp.array(dtype=wp.int32),
        # State in:
        x: wp.array(dtype=vec3),
        # Out:
        forces_out: wp.array2d(dtype=vec3),
    ):
        """f_i(x): active fibre force of each muscle at full activation, (M, n) accumulated
        (k f_L(lam) d lam/dF, with lam~ and d lam~/dF if ``fibre_law`` != 0)."""
        e = wp.tid()
        t = entry_tet[e]
        m = entry_muscle[e]
        c1, c2, c3 = fibre_nodal_forces(
            x,
            tets,
            dm_inv[t],
            rest_volume[t],
            t,
            entry_direction[e],
            entry_coef[e],
            clamp,
            fibre_law,
            muscle_curves[m],
            S(1.0),
        )
        wp.atomic_add(forces_out, m, tets[t, 1], c1)
        wp.atomic_add(forces_out, m, tets[t, 2], c2)
        wp.atomic_add(forces_out, m, tets[t, 3], c3)
        wp.atomic_add(forces_out, m, tets[t, 0], -(c1 + c2 + c3))

    @wp.kernel(module="unique", enable_backward=False)
    def muscle_force_sum(
        # Model:
        tets: wp.array2d(dtype=wp.int32),
        dm_inv: wp.array(dtype=mat33),
        rest_volume: wp.array(dtype=S),
        entry_tet: wp.array(dtype=wp.int32),
        entry_muscle: wp.array(dtype=wp.int32),
        entry_direction: wp.array(dtype=vec3),
        entry_coef: wp.array(dtype=S),
        clamp: S,
        fibre_law: int,
        muscle_curves: wp.array(dtype=wp.int32),
        # State in:
        x: wp.array(dtype=vec3),
        weights: wp.array(dtype=S),
        # Out:
        forces_out: wp.array(dtype=vec3),
    ):
        """sum_i w_i f_i(x), (n,) accumulated: ``muscle_forces`` weighted and summed over the muscles,
        without the (M, n) array (the load of a linear prediction, ``RowsLinearization.predict``)."""
        e = wp.tid()
        m = entry_muscle[e]
        w = weights[m]
        if w != S(0.0):
            t = entry_tet[e]
            coef = entry_coef[e]
            c1, c2, c3 = fibre_nodal_forces(
                x, tets, dm_inv[t], rest_volume[t], t, entry_direction[e], coef, clamp, fibre_law, muscle_curves[m], w
            )
            wp.atomic_add(forces_out, tets[t, 1], c1)
            wp.atomic_add(forces_out, tets[t, 2], c2)
            wp.atomic_add(forces_out, tets[t, 3], c3)
            wp.atomic_add(forces_out, tets[t, 0], -(c1 + c2 + c3))

    @wp.func
    def vec_outer_mode(U: mat33, V: mat33, i: int, j: int):
        """vec(u_i v_j^T) as a 9-vector (row-major)."""
        w = vec9()
        for r in range(3):
            for c in range(3):
                w[3 * r + c] = U[r, i] * V[c, j]
        return w

    @wp.kernel(module="unique", enable_backward=False)
    def element_tangent(
        # Model:
        tets: wp.array2d(dtype=wp.int32),
        dm_inv: wp.array(dtype=mat33),
        rest_volume: wp.array(dtype=S),
        mu10: S,
        mu01: S,
        mu20: S,
        kappa: S,
        kq: S,
        clamp: S,
        fibre_law: int,
        muscle_curves: wp.array(dtype=wp.int32),
        entry_start: wp.array(dtype=wp.int32),
        entry_muscle: wp.array(dtype=wp.int32),
        entry_direction: wp.array(dtype=vec3),
        entry_coef: wp.array(dtype=S),
        project: int,
        # State in:
        x: wp.array(dtype=vec3),
        activation: wp.array(dtype=S),
        # Out:
        tangent_out: wp.array(dtype=vec45),
    ):
        """Per-tet V0 dP/dF (symmetric 9x9 on row-major vec(F), stored packed: upper triangle row
        by row); projected to PSD if ``project``."""
        t = wp.tid()
        F = deformation_gradient(x, tets, dm_inv[t], t)
        U = mat33()
        s = vec3()
        V = mat33()
        wp.svd3(F, U, s, V)
        psi, G, A = flesh_response(s, mu10, mu01, mu20, kappa, kq, clamp)
        if fibre_law != 0:  # the fibres' isotropic part T lam d2 phi(J) joins the flesh's modes
            c_iso = S(0.0)
            for e in range(entry_start[t], entry_start[t + 1]):
                act = activation[entry_muscle[e]]
                lf, lt, T, dT, W, g = deviatoric_fibre(
                    F, entry_direction[e], act, entry_coef[e], clamp * clamp * clamp, muscle_curves[entry_muscle[e]]
                )
                c_iso = c_iso + T * lf
            phi, dphi, ddphi = volume_factor(s[0] * s[1] * s[2], clamp * clamp * clamp)
            G, A = isotropic_volume_terms(G, A, s, c_iso * dphi, c_iso * ddphi)
        # Nine eigen-modes of dP/dF (rows of Wm, orthonormal in vec(F)) and their eigenvalues.
        Q = mat33()
        lam = vec3()
        wp.eig3(A, Q, lam)
        Wm = mat99()
        ev = vec9()
        w0 = vec_outer_mode(U, V, 0, 0)
        w1 = vec_outer_mode(U, V, 1, 1)
        w2 = vec_outer_mode(U, V, 2, 2)
        for k in range(3):
            ev[k] = lam[k]
            for r in range(9):
                Wm[k, r] = Q[0, k] * w0[r] + Q[1, k] * w1[r] + Q[2, k] * w2[r]
        inv_sqrt2 = S(0.7071067811865476)
        for p in range(3):
            i = 0
            j = 1
            if p == 1:
                j = 2
            if p == 2:
                i = 1
                j = 2
            diff = s[i] - s[j]
            if wp.abs(diff) > S(tie_eps) * wp.max(wp.abs(s[i]), S(1.0)):
                ev[3 + p] = (G[i] - G[j]) / diff
            else:
                ev[3 + p] = A[i, i] - A[i, j]  # limit of (G_i - G_j)/(s_i - s_j)
            ev[6 + p] = (G[i] + G[j]) / wp.max(s[i] + s[j], S(tie_eps))
            wij = vec_outer_mode(U, V, i, j)
            wji = vec_outer_mode(U, V, j, i)
            for r in range(9):
                Wm[3 + p, r] = inv_sqrt2 * (wij[r] + wji[r])
                Wm[6 + p, r] = inv_sqrt2 * (wij[r] - wji[r])
        if project != 0:
            for m in range(9):
                ev[m] = wp.max(ev[m], S(0.0))
        C = mat99()
        for r in range(9):
            for c in range(9):
                if c >= r:
                    acc = S(0.0)
                    for m in range(9):
                        acc = acc + ev[m] * Wm[m, r] * Wm[m, c]
                    C[r, c] = acc
        for e in range(entry_start[t], entry_start[t + 1]):
            d = entry_direction[e]
            if fibre_law != 0:
                act = activation[entry_muscle[e]]
                jc = clamp * clamp * clamp
                curves = muscle_curves[entry_muscle[e]]
                C = deviatoric_fibre_tangent(C, F, d, act, entry_coef[e], jc, curves, project)
                continue
            q = F * d
            lf = wp.length(q)
            if lf > S(1.0e-12):
                T, dT, W = fibre_tension(lf, activation[entry_muscle[e]], entry_coef[e], muscle_curves[entry_muscle[e]])
                c1 = T / lf
                along = dT
                if project != 0:
                    c1 = wp.max(c1, S(0.0))
                    along = wp.max(along, S(0.0))
                c2 = (along - c1) / (lf * lf)
                Hq = c1 * wp.identity(n=3, dtype=S) + c2 * wp.outer(q, q)
                for i in range(3):
                    for k in range(3):
                        for j in range(3):
                            for l in range(3):
                                C[3 * i + k, 3 * j + l] = C[3 * i + k, 3 * j + l] + Hq[i, j] * d[k] * d[l]
        V0 = rest_volume[t]
        packed = vec45()
        slot = int(0)
        for r in range(9):
            for c in range(9):
                if c >= r:
                    packed[slot] = V0 * C[r, c]
                    slot = slot + 1
        tangent_out[t] = packed

    @wp.func
    def packed_entry(Cp: vec45, r: int, c: int):
        """Entry (r, c) of a symmetric 9x9 matrix stored as its packed upper triangle."""
        i = wp.min(r, c)
        j = wp.max(r, c)
        return Cp[i * 9 - (i * (i - 1)) / 2 + (j - i)]

    @wp.func
    def node_gradients(Dmi: mat33):
        """Rows r_1..r_3 of Dm^-1 and r_0 = -(r_1 + r_2 + r_3): dF = sum_a dx_a r_a^T."""
        r1 = vec3(Dmi[0, 0], Dmi[0, 1], Dmi[0, 2])
        r2 = vec3(Dmi[1, 0], Dmi[1, 1], Dmi[1, 2])
        r3 = vec3(Dmi[2, 0], Dmi[2, 1], Dmi[2, 2])
        return -(r1 + r2 + r3), r1, r2, r3

    @wp.func
    def pick(r0: vec3, r1: vec3, r2: vec3, r3: vec3, a: int):
        if a == 0:
            return r0
        if a == 1:
            return r1
        if a == 2:
            return r2
        return r3

    @wp.kernel(module="unique", enable_backward=False)
    def tangent_matvec(
        # Model:
        tets: wp.array2d(dtype=wp.int32),
        dm_inv: wp.array(dtype=mat33),
        tangent: wp.array(dtype=vec45),
        # State in:
        v: wp.array(dtype=vec3),
        # Out:
        kv_out: wp.array(dtype=vec3),
    ):
        """kv_out += K v with K = -df/dx (matrix-free, from the per-tet 9x9 tangents)."""
        t = wp.tid()
        r0, r1, r2, r3 = node_gradients(dm_inv[t])
        v0 = v[tets[t, 0]]
        dF = wp.outer(v[tets[t, 1]] - v0, r1) + wp.outer(v[tets[t, 2]] - v0, r2) + wp.outer(v[tets[t, 3]] - v0, r3)
        dFv = vec9()
        for r in range(3):
            for c in range(3):
                dFv[3 * r + c] = dF[r, c]
        Cp = tangent[t]
        dP = mat33()
        for r in range(9):
            acc = S(0.0)
            for c in range(9):
                acc = acc + packed_entry(Cp, r, c) * dFv[c]
            dP[r / 3, r % 3] = acc
        c1 = dP * r1
        c2 = dP * r2
        c3 = dP * r3
        wp.atomic_add(kv_out, tets[t, 1], c1)
        wp.atomic_add(kv_out, tets[t, 2], c2)
        wp.atomic_add(kv_out, tets[t, 3], c3)
        wp.atomic_add(kv_out, tets[t, 0], -(c1 + c2 + c3))

    @wp.func
    def tangent_block(C: vec45, ra: vec3, rb: vec3):
        """3x3 block (a, b) of the element stiffness: B_ij = sum_kl C[3i+k, 3j+l] ra_k rb_l."""
        B = mat33()
        for i in range(3):
            for j in range(3):
                acc = S(0.0)
                for k in range(3):
                    for l in range(3):
                        acc = acc + packed_entry(C, 3 * i + k, 3 * j + l) * ra[k] * rb[l]
                B[i, j] = acc
        return B

    @wp.kernel(module="unique", enable_backward=False)
    def tangent_assemble(
        # Model:
        dm_inv: wp.array(dtype=mat33),
        tangent: wp.array(dtype=vec45),
        block_index: wp.array2d(dtype=wp.int32),
        # Out:
        blocks_out: wp.array(dtype=mat33),
    ):
        """Scatter the 16 3x3 blocks of each element stiffness into BSR values (index -1: skipped)."""
        t = wp.tid()
        C = tangent[t]
        r0, r1, r2, r3 = node_gradients(dm_inv[t])
        for a in range(4):
            ra = pick(r0, r1, r2, r3, a)
            for b in range(4):
                idx = block_index[t, 4 * a + b]
                if idx >= 0:
                    wp.atomic_add(blocks_out, idx, tangent_block(C, ra, pick(r0, r1, r2, r3, b)))

    @wp.kernel(module="unique", enable_backward=False)
    def tangent_diagonal(
        # Model:
        tets: wp.array2d(dtype=wp.int32),
        dm_inv: wp.array(dtype=mat33),
        tangent: wp.array(dtype=vec45),
        # Out:
        diag_out: wp.array(dtype=vec3),
    ):
        """diag(K) per node (Jacobi preconditioner), accumulated."""
        t = wp.tid()
        C = tangent[t]
        r0, r1, r2, r3 = node_gradients(dm_inv[t])
        for a in range(4):
            ra = pick(r0, r1, r2, r3, a)
            B = tangent_block(C, ra, ra)
            wp.atomic_add(diag_out, tets[t, a], vec3(B[0, 0], B[1, 1], B[2, 2]))

    @wp.kernel(module="unique", enable_backward=False)
    def masked_axpby(
        # In:
        ax: wp.array(dtype=vec3),
        y: wp.array(dtype=vec3),
        mask: wp.array(dtype=S),
        alpha: S,
        beta: S,
        # Out:
        z_out: wp.array(dtype=vec3),
    ):
        """z = alpha mask * ax + beta y (mask = 1 on unknown nodes, 0 on Dirichlet nodes)."""
        i = wp.tid()
        z_out[i] = (alpha * mask[i]) * ax[i] + beta * y[i]

    @wp.kernel(module="unique", enable_backward=False)
    def diagonal_axpby(
        # In:
        inv_diag: wp.array(dtype=vec3),
        x: wp.array(dtype=vec3),
        y: wp.array(dtype=vec3),
        alpha: S,
        beta: S,
        # Out:
        z_out: wp.array(dtype=vec3),
    ):
        """z = alpha diag(inv_diag) x + beta y (Jacobi preconditioner)."""
        i = wp.tid()
        z_out[i] = alpha * wp.cw_mul(inv_diag[i], x[i]) + beta * y[i]

    class _Kernels:
        pass

    ns = _Kernels()
    ns.scalar = S
    ns.vec3 = vec3
    ns.mat33 = mat33
    ns.mat99 = mat99
    ns.vec45 = vec45
    for k in (
        element_forces,
        element_energy,
        muscle_forces,
        muscle_force_sum,
        element_tangent,
        tangent_matvec,
        tangent_assemble,
        tangent_diagonal,
        masked_axpby,
        diagonal_axpby,
    ):
        setattr(ns, k.func.__name__, k)
    ns.singular_values = flesh.singular_values
    ns.flesh_in_singular_values = flesh.flesh_in_singular_values
    ns.fibre_curves = fibre.fibre_curves
    return ns
