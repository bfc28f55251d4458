"""Isotropic flesh in singular values (Warp device code, float64 and float32; docs/design.md, "Flesh").

psi(s) = mu10 u + mu01 (J^-4/3 I2 - 3) + mu20 u^2 + kappa/2 (ln J)^2 + kq/2 (J - 1)^2,  u = J^-2/3 I1 - 3,
J = s1 s2 s3, I1 = sum s_i^2, I2 = sum_{i<j} s_i^2 s_j^2, on the signed singular values of
F = U diag(s) V^T (det U = det V = +1, the smallest carrying the sign of det F: Irving et al. 2004).
The mu20 term is ArtiSynth's C20 (I1~ - 3)^2 (its ``MooneyRivlinMaterial``); with mu20 = 0 it is
skipped, so the other terms' arithmetic is that of the law without it, bit for bit. kq is the
modulus of ArtiSynth's quadratic bulk potential (``Material.bulk_potential``; the simulator passes
kappa or kq, the other 0); with kq = 0 it is skipped likewise.

Where no singular value is below the clamp, the energy and its first Piola stress are evaluated
from the invariants of C = F^T F instead (``flesh_invariants``: no SVD, about half the cost of a
force evaluation; docs/design.md, "Inversion safety"):
    psi = mu10 u + mu01 (J^-4/3 I2 - 3) + mu20 u^2 + kappa/2 (ln J)^2 + kq/2 (J - 1)^2,
    P = (mu10 + 2 mu20 u) J^-2/3 (2 F - 2/3 I1 F^-T) + mu01 J^-4/3 (2 (I1 F - F C) - 4/3 I2 F^-T)
        + (kappa ln J + kq (J - 1) J) F^-T,
the same function. The test for it is s_min >= 2 J / I1 >= c (the two larger eigenvalues of C
multiply to at most (I1 / 2)^2, so the smallest is at least 4 J^2 / I1^2): sufficient, never
wrong; near inversion it falls back to the SVD.

Below the clamp c the energy is continued by its first-order Taylor expansion in the clamped
values, psi_ext(s) = psi(s^) + sum_i g_i(s^)(s_i - s^_i) with s^ = max(s, c), so the stress is the
exact gradient of an energy (Stomakhin et al. 2012). psi is a sum of monomials c prod s_i^a_i
plus the volumetric term, so its first, second and third derivatives are closed form. The mu20
term's come by the chain rule from those of u (three monomials with coefficient 1, minus 3):
    d(u^2)_i = 2 u u_i,   d2(u^2)_ij = 2 (u_i u_j + u u_ij),
    d3(u^2)_ijl = 2 (u_il u_j + u_i u_jl + u_ij u_l + u u_ijl),
and the third derivative is only ever needed contracted with delta on its first index:
    sum_i delta_i d3(u^2)_ijl = 2 (u_j (U delta)_l + (U delta)_j u_l + (u . delta) u_jl + u sum_i delta_i u_ijl),
U = (u_ij).
"""

import functools

import warp as wp

from wface.kernels.fibre import fibre_functions

wp.set_module_options({"enable_backward": False})

__all__ = ["flesh_functions"]


@functools.cache
def flesh_functions(dtype):
    """Namespace with the flesh wp.funcs (``clamp_values``, ``flesh_derivatives``,
    ``flesh_gradient_s``, ``flesh_response``; ``flesh_invariants``,
    ``flesh_stress_svd``, ``flesh_stress``, ``flesh_energy`` on F) and the test kernels ``singular_values``,
    ``flesh_in_singular_values`` and ``flesh_stress_paths`` for scalar ``dtype``."""
    S = dtype
    vec3 = wp.types.vector(3, S)
    mat33 = wp.types.matrix((3, 3), S)
    M2_3, M4_3 = -2.0 / 3.0, -4.0 / 3.0  # folded in double precision (see fibre.py)
    C2_3, C4_3 = 2.0 / 3.0, 4.0 / 3.0
    cofactor = fibre_functions(S).cofactor  # cof F = J F^-T

    @wp.func
    def add_monomial(g: vec3, H: mat33, Tc: mat33, a: vec3, m: S, inv: vec3, delta: vec3, order: int):
        """(g, H, Tc) plus the gradient, Hessian (order >= 2) and third derivative contracted with delta
        (order >= 3) of the monomial m = c prod_i s_i^a_i (its value at s^; inv = 1 / s^)."""
        g_out = g
        H_out = H
        T_out = Tc
        for i in range(3):
            g_out[i] = g_out[i] + a[i] * m * inv[i]
        if order >= 2:
            for i in range(3):
                for j in range(3):
                    dij = S(0.0)
                    if i == j:
                        dij = S(1.0)
                    hij = a[i] * (a[j] - dij) * m * inv[i] * inv[j]
                    H_out[i, j] = H_out[i, j] + hij
                    if order >= 3:
                        for l in range(3):
                            dil = S(0.0)
                            djl = S(0.0)
                            if i == l:
                                dil = S(1.0)
                            if j == l:
                                djl = S(1.0)
                            T_out[j, l] = T_out[j, l] + delta[i] * hij * (a[l] - dil - djl) * inv[l]
        return g_out, H_out, T_out

    @wp.func
    def c20_derivatives(sh: vec3, delta: vec3, j23: S, inv: vec3, mu20: S, order: int):
        """mu20 u^2 (u = J^-2/3 I1 - 3) at s^: value, gradient, Hessian (order >= 2) and third
        derivative contracted with delta (order >= 3), from u's derivatives (module docstring)."""
        u = S(-3.0)
        du = vec3()
        ddu = mat33()
        dddu = mat33()  # sum_i delta_i u_ijl
        for k in range(3):
            a = vec3(S(M2_3), S(M2_3), S(M2_3))
            a[k] = a[k] + S(2.0)
            m = j23 * sh[k] * sh[k]
            u = u + m
            du, ddu, dddu = add_monomial(du, ddu, dddu, a, m, inv, delta, order)
        c = S(2.0) * mu20
        H = mat33()
        Tc = mat33()
        if order >= 2:
            H = c * (wp.outer(du, du) + u * ddu)
        if order >= 3:
            dd = ddu * delta
            Tc = c * (wp.outer(du, dd) + wp.outer(dd, du) + wp.dot(du, delta) * ddu + u * dddu)
        return mu20 * u * u, c * u * du, H, Tc

    @wp.func
    def quadratic_bulk_derivatives(sh: vec3, delta: vec3, inv: vec3, kq: S, order: int):
        """kq/2 (J - 1)^2 (J = prod s^_i) at s^: value, gradient, Hessian (order >= 2) and third
        derivative contracted with delta (order >= 3), from J_i = J / s_i, J_ij = J / (s_i s_j) (i != j)
        and J_ijl = J / (s_i s_j s_l) (i, j, l distinct), the others 0 (module docstring)."""
        J = sh[0] * sh[1] * sh[2]
        up = kq * (J - S(1.0))  # U'(J); U'' = kq, U''' = 0
        Ji = vec3(J * inv[0], J * inv[1], J * inv[2])
        g = up * Ji
        H = mat33()
        Tc = mat33()
        if order >= 2:
            for i in range(3):
                for j in range(3):
                    jij = S(0.0)
                    if i != j:
                        jij = Ji[i] * inv[j]
                    H[i, j] = kq * Ji[i] * Ji[j] + up * jij
                    if order >= 3:
                        for l in range(3):
                            jil = S(0.0)
                            jjl = S(0.0)
                            jijl = S(0.0)
                            if i != l:
                                jil = Ji[i] * inv[l]
                            if j != l:
                                jjl = Ji[j] * inv[l]
                            if i != j and i != l and j != l:
                                jijl = jij * inv[l]
                            t = kq * (jil * Ji[j] + Ji[i] * jjl + jij * Ji[l]) + up * jijl
                            Tc[j, l] = Tc[j, l] + delta[i] * t
        return S(0.5) * kq * (J - S(1.0)) * (J - S(1.0)), g, H, Tc

    @wp.func
    def flesh_derivatives(sh: vec3, delta: vec3, mu10: S, mu01: S, mu20: S, kappa: S, kq: S, order: int):
        """psi, gradient, Hessian (order >= 2) at s^ (all > 0), and the third derivative contracted
        with delta (order >= 3); higher-order outputs are zero when not requested."""
        psi = S(-3.0) * (mu10 + mu01)
        g = vec3()
        H = mat33()
        Tc = mat33()
        inv = vec3(S(1.0) / sh[0], S(1.0) / sh[1], S(1.0) / sh[2])
        L = wp.log(sh[0]) + wp.log(sh[1]) + wp.log(sh[2])
        j23 = wp.exp(S(M2_3) * L)  # J^(-2/3)
        for k in range(6):
            # monomial m = c prod s_i^a_i: mu10 J^-2/3 s_k^2 (k < 3), mu01 J^-4/3 s_i^2 s_j^2 (pairs)
            a = vec3(S(M2_3), S(M2_3), S(M2_3))
            m = S(0.0)
            if k < 3:
                a[k] = a[k] + S(2.0)
                m = mu10 * j23 * sh[k] * sh[k]
            else:
                a = vec3(S(M4_3), S(M4_3), S(M4_3))
                p = k - 3  # pairs (0,1), (0,2), (1,2)
                i0 = 0
                i1 = 1
                if p == 1:
                    i1 = 2
                if p == 2:
                    i0 = 1
                    i1 = 2
                a[i0] = a[i0] + S(2.0)
                a[i1] = a[i1] + S(2.0)
                m = mu01 * j23 * j23 * sh[i0] * sh[i0] * sh[i1] * sh[i1]
            psi = psi + m
            g, H, Tc = add_monomial(g, H, Tc, a, m, inv, delta, order)
        psi = psi + S(0.5) * kappa * L * L
        for i in range(3):
            g[i] = g[i] + kappa * L * inv[i]
        if order >= 2:
            for i in range(3):
                for j in range(3):
                    H[i, j] = H[i, j] + kappa * inv[i] * inv[j]
                    if i == j:
                        H[i, j] = H[i, j] - kappa * L * inv[i] * inv[i]
                    if order >= 3:
                        for l in range(3):
                            t = S(0.0)
                            if i == l:
                                t = t - kappa * inv[i] * inv[j] * inv[l]
                            if j == l:
                                t = t - kappa * inv[i] * inv[j] * inv[l]
                            if i == j:
                                t = t - kappa * inv[i] * inv[i] * inv[l]
                                if i == l:
                                    t = t + S(2.0) * kappa * L * inv[i] * inv[i] * inv[i]
                            Tc[j, l] = Tc[j, l] + delta[i] * t
        if kq != S(0.0):
            pq, gq, Hq, Tq = quadratic_bulk_derivatives(sh, delta, inv, kq, order)
            psi = psi + pq
            g = g + gq
            H = H + Hq
            Tc = Tc + Tq
        if mu20 != S(0.0):
            p20, g20, H20, T20 = c20_derivatives(sh, delta, j23, inv, mu20, order)
            psi = psi + p20
            g = g + g20
            H = H + H20
            Tc = Tc + T20
        return psi, g, H, Tc

    @wp.func
    def clamp_values(s: vec3, clamp: S):
        sh = vec3()
        delta = vec3()
        for i in range(3):
            sh[i] = wp.max(s[i], clamp)
            delta[i] = s[i] - sh[i]
        return sh, delta

    @wp.func
    def flesh_gradient_s(s: vec3, mu10: S, mu01: S, mu20: S, kappa: S, kq: S, clamp: S):
        """psi_ext and its gradient G in singular values."""
        sh, delta = clamp_values(s, clamp)
        order = 1
        if delta[0] != S(0.0) or delta[1] != S(0.0) or delta[2] != S(0.0):
            order = 2
        psi, g, H, Tc = flesh_derivatives(sh, delta, mu10, mu01, mu20, kappa, kq, order)
        G = g
        Hd = H * delta
        for j in range(3):
            if s[j] >= clamp:
                G[j] = G[j] + Hd[j]
        return psi + wp.dot(g, delta), G

    @wp.func
    def flesh_invariants(F: mat33, mu10: S, mu01: S, mu20: S, kappa: S, kq: S, clamp: S):
        """(ok, psi, P) from the invariants of F (module docstring); ok = 0 where the singular values
        may reach below ``clamp`` (then psi = 0, P = 0: use the SVD)."""
        J = wp.determinant(F)
        C = wp.transpose(F) * F
        I1 = wp.trace(C)
        if J <= S(0.0) or S(2.0) * J < clamp * I1:
            return 0, S(0.0), mat33()
        finv_t = cofactor(F) * (S(1.0) / J)  # F^-T
        L = wp.log(J)
        j23 = wp.exp(S(M2_3) * L)
        FC = F * C
        I2 = S(0.5) * (I1 * I1 - wp.ddot(C, C))
        u = j23 * I1 - S(3.0)
        psi = mu10 * u + mu01 * (j23 * j23 * I2 - S(3.0)) + mu20 * u * u + S(0.5) * kappa * L * L
        d1 = j23 * (S(2.0) * F - S(C2_3) * I1 * finv_t)
        d2 = (j23 * j23) * (S(2.0) * (I1 * F - FC) - S(C4_3) * I2 * finv_t)
        P = (mu10 + S(2.0) * mu20 * u) * d1 + mu01 * d2 + (kappa * L) * finv_t
        if kq != S(0.0):  # kq/2 (J - 1)^2: dJ/dF = J F^-T
            psi = psi + S(0.5) * kq * (J - S(1.0)) * (J - S(1.0))
            P = P + (kq * (J - S(1.0)) * J) * finv_t
        return 1, psi, P

    @wp.func
    def flesh_stress_svd(F: mat33, mu10: S, mu01: S, mu20: S, kappa: S, kq: S, clamp: S):
        """(psi_ext, P = U diag(G) V^T) by the signed SVD: the path near and past inversion."""
        U = mat33()
        s = vec3()
        V = mat33()
        wp.svd3(F, U, s, V)
        psi, G = flesh_gradient_s(s, mu10, mu01, mu20, kappa, kq, clamp)
        return psi, U * wp.diag(G) * wp.transpose(V)

    @wp.func
    def flesh_stress(F: mat33, mu10: S, mu01: S, mu20: S, kappa: S, kq: S, clamp: S):
        """(psi_ext, P = d psi_ext / dF) of the flesh at F: the invariants where no singular value is
        near the clamp, else the signed SVD (module docstring)."""
        ok, psi, P = flesh_invariants(F, mu10, mu01, mu20, kappa, kq, clamp)
        if ok == 0:
            psi, P = flesh_stress_svd(F, mu10, mu01, mu20, kappa, kq, clamp)
        return psi, P

    @wp.func
    def flesh_energy(F: mat33, mu10: S, mu01: S, mu20: S, kappa: S, kq: S, clamp: S):
        """psi_ext at F: the invariants where no singular value is near the clamp, else the SVD."""
        ok, psi, P = flesh_invariants(F, mu10, mu01, mu20, kappa, kq, clamp)
        if ok == 0:
            psi, P = flesh_stress_svd(F, mu10, mu01, mu20, kappa, kq, clamp)
        return psi

    @wp.kernel(module="unique", enable_backward=False)
    def flesh_stress_paths(
        # In:
        F: wp.array(dtype=mat33),
        mu10: S,
        mu01: S,
        mu20: S,
        kappa: S,
        kq: S,
        clamp: S,
        # Out:
        ok_out: wp.array(dtype=wp.int32),
        psi_inv_out: wp.array(dtype=S),
        P_inv_out: wp.array(dtype=mat33),
        psi_svd_out: wp.array(dtype=S),
        P_svd_out: wp.array(dtype=mat33),
    ):
        """Both evaluations of the flesh stress at F (tests: they agree wherever the invariants apply)."""
        i = wp.tid()
        ok, psi, P = flesh_invariants(F[i], mu10, mu01, mu20, kappa, kq, clamp)
        ok_out[i] = ok
        psi_inv_out[i] = psi
        P_inv_out[i] = P
        psi_s, P_s = flesh_stress_svd(F[i], mu10, mu01, mu20, kappa, kq, clamp)
        psi_svd_out[i] = psi_s
        P_svd_out[i] = P_s

    @wp.kernel(module="unique", enable_backward=False)
    def singular_values(
        # In:
        F: wp.array(dtype=mat33),
        # Out:
        U_out: wp.array(dtype=mat33),
        s_out: wp.array(dtype=vec3),
        V_out: wp.array(dtype=mat33),
    ):
        """wp.svd3 as used by the FEM (tests pin its sign and order convention)."""
        t = wp.tid()
        U = mat33()
        s = vec3()
        V = mat33()
        wp.svd3(F[t], U, s, V)
        U_out[t] = U
        s_out[t] = s
        V_out[t] = V

    @wp.func
    def flesh_response(s: vec3, mu10: S, mu01: S, mu20: S, kappa: S, kq: S, clamp: S):
        """psi_ext, its gradient G and Hessian A in the signed singular values s."""
        sh, delta = clamp_values(s, clamp)
        order = 2
        if delta[0] != S(0.0) or delta[1] != S(0.0) or delta[2] != S(0.0):
            order = 3
        psi, g, H, Tc = flesh_derivatives(sh, delta, mu10, mu01, mu20, kappa, kq, order)
        G = g
        Hd = H * delta
        A = mat33()
        for i in range(3):
            if s[i] >= clamp:
                G[i] = G[i] + Hd[i]
            for j in range(3):
                ui = s[i] >= clamp
                uj = s[j] >= clamp
                if ui and uj:
                    A[i, j] = H[i, j] + Tc[i, j]
                elif ui or uj:
                    A[i, j] = H[i, j]
        return psi + wp.dot(g, delta), G, A

    @wp.kernel(module="unique", enable_backward=False)
    def flesh_in_singular_values(
        # In:
        s: wp.array(dtype=vec3),
        mu10: S,
        mu01: S,
        mu20: S,
        kappa: S,
        kq: S,
        clamp: S,
        # Out:
        psi_out: wp.array(dtype=S),
        grad_out: wp.array(dtype=vec3),
        hess_out: wp.array(dtype=mat33),
    ):
        """The flesh energy density psi_ext(s), its gradient and Hessian (tests, plots)."""
        i = wp.tid()
        psi, G, A = flesh_response(s[i], mu10, mu01, mu20, kappa, kq, clamp)
        psi_out[i] = psi
        grad_out[i] = G
        hess_out[i] = A

    class _Functions:
        pass

    ns = _Functions()
    for f in (
        clamp_values,
        c20_derivatives,
        quadratic_bulk_derivatives,
        flesh_derivatives,
        flesh_gradient_s,
        flesh_response,
        flesh_invariants,
        flesh_stress_svd,
        flesh_stress,
        flesh_energy,
    ):
        setattr(ns, f.func.__name__, f)
    ns.singular_values = singular_values
    ns.flesh_stress_paths = flesh_stress_paths
    ns.flesh_in_singular_values = flesh_in_singular_values
    return ns
