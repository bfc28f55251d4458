"""Muscle fibre curves (Warp device code, float64 and float32; docs/design.md, "Muscle fibres").

Fibre stretch lam = |F d|, x = lam - 1. Tension T(lam, a) = k (a f_L(lam) + f_P(lam)),
k = fraction * strength * sigma_max (Teran et al. 2005; Zajac 1989 force-length shape):
- force-length f_L = 1 - (25/6) x^2 for |x| < 0.4; (25/3)(|x| - 0.6)^2 for 0.4 <= |x| < 0.6; 0 beyond;
- passive f_P = 0.05 (exp(6.6 x) - 6.6 x - 1) for 0 < x <= 0.4, continued linearly (C1) above, 0 for x <= 0.
Blemker's curves (``curves`` 1, ``Material.fibre_stress = "blemker"``: ArtiSynth's BlemkerMuscle, Blemker et al.
2005): f_L = 1 - 4 x^2 for |x| < 0.4, 9 (|x| - 0.6)^2 to |x| = 0.6, 0 beyond; f_P = 0.05 (exp(6.6 x) - 1) for
0 < x <= 0.4 (not C1 at x = 0), continued linearly above. Generic curves (``curves`` 2, ArtiSynth's
GenericMuscle): f_L = 1 at every stretch and no passive stress (GenericMuscle's, 0.05 Pa (exp(6.6 x) - 1) / lam,
is not scaled by sigma_max: at most 0.65 Pa up to lam~ = 1.4, 6.5e-6 of its 1e5 Pa, so it is left out).
A muscle's curves are its own (``Material.muscle_curves``, index into ``FIBRE_CURVES``).
The fibre energy is the integral of T over the stretch from 1, in closed form per piece.

Deviatoric fibre stress (``Material.fibre_stress`` "deviatoric" or "blemker", ArtiSynth's muscle materials): the
same curves of the deviatoric stretch lam~ = phi(J) lam, phi(J) = J^-1/3 (J = det F), so the
Cauchy stress 2 W4 I4~ / J (a a^T - I/3) has no hydrostatic part. With cof F = dJ/dF,
    d lam~/dF = phi q d^T / lam + lam phi'(J) cof F            (= J^-1/3 q d^T / lam - (lam~/3) F^-T),
    d2 lam~ = (phi/lam) (I - n n^T) (x) d d^T + phi' (vec(n d^T) vec(cof)^T + its transpose)
              + lam (phi'' vec(cof) vec(cof)^T + phi' d2J),  n = q / lam,
the last term being lam times the Hessian of phi(J), an isotropic function of F. Below
J_c = c^3 (c the flesh's singular-value clamp, so J >= J_c wherever the flesh is unclamped) phi is
continued by its tangent line, phi(J) = phi(J_c) + phi'(J_c) (J - J_c): C1, finite for J <= 0.
"""

import functools

import warp as wp

wp.set_module_options({"enable_backward": False})

__all__ = ["fibre_functions"]


@functools.cache
def fibre_functions(dtype):
    """Namespace with ``force_length``, ``passive_curve``, ``fibre_tension``, the deviatoric entry's
    ``volume_factor``, ``deviatoric_fibre``, ``deviatoric_fibre_tangent``, ``isotropic_volume_terms``,
    ``cofactor`` (wp.func) and the ``fibre_curves`` kernel for scalar ``dtype``."""
    S = dtype
    vec3 = wp.types.vector(3, S)
    mat33 = wp.types.matrix((3, 3), S)
    mat99 = wp.types.matrix((9, 9), S)
    M1_3, C4_9 = -1.0 / 3.0, 4.0 / 9.0
    tiny = 1.0e-12 if S == wp.float64 else 1.0e-6  # relative size below which b is taken parallel to a
    # Constant expressions are folded here in double precision: inside a kernel, S(25.0 / 6.0)
    # would be evaluated in float32 first.
    C25_18, C25_6, C25_3, C50_3, C25_9 = 25.0 / 18.0, 25.0 / 6.0, 25.0 / 3.0, 50.0 / 3.0, 25.0 / 9.0
    C4_3 = 4.0 / 3.0
    C033 = 0.05 * 6.6

    @wp.func
    def force_length(x: S, curves: int):
        """f_L, df_L/dlam and the integral from 1 of f_L, at lam = 1 + x; ``curves`` 0 wface's, 1 Blemker's
        (1 - 4 x^2 for |x| < 0.4, 9 (|x| - 0.6)^2 to |x| = 0.6, 0 beyond), 2 generic (1 everywhere)."""
        if curves == 2:
            return S(1.0), S(0.0), x
        ax = wp.abs(x)
        sg = S(1.0)
        if x < S(0.0):
            sg = S(-1.0)
        # f = 1 - c_in x^2 inside |x| < 0.4, c_out (|x| - 0.6)^2 outside; c2_* = 2 c_*, c3_* = c_* / 3
        c_in = S(C25_6)
        c2_in = S(C25_3)
        c3_in = S(C25_18)
        c_out = S(C25_3)
        c2_out = S(C50_3)
        c3_out = S(C25_9)
        if curves == 1:
            c_in = S(4.0)
            c2_in = S(8.0)
            c3_in = S(C4_3)
            c_out = S(9.0)
            c2_out = S(18.0)
            c3_out = S(3.0)
        g04 = S(0.4) - c3_in * S(0.064)
        if ax < S(0.4):
            return S(1.0) - c_in * x * x, -c2_in * x, x - c3_in * x * x * x
        if ax < S(0.6):
            y = ax - S(0.6)
            return c_out * y * y, sg * c2_out * y, sg * (g04 + c3_out * (y * y * y + S(0.008)))
        return S(0.0), S(0.0), sg * (g04 + c3_out * S(0.008))

    @wp.func
    def passive_curve(x: S, curves: int):
        """f_P, df_P/dlam and the integral from 1 of f_P, at lam = 1 + x, linear (C1) beyond 1.4; ``curves``
        0 wface's 0.05 (exp(6.6 x) - 6.6 x - 1), 1 Blemker's 0.05 (exp(6.6 x) - 1) (a kink at lam = 1), 2 none."""
        if x <= S(0.0) or curves == 2:
            return S(0.0), S(0.0), S(0.0)
        xe = wp.min(x, S(0.4))
        e = wp.exp(S(6.6) * xe)
        f = S(0.05) * (e - S(6.6) * xe - S(1.0))
        df = S(C033) * (e - S(1.0))
        g = S(0.05) * ((e - S(1.0)) / S(6.6) - S(3.3) * xe * xe - xe)
        if curves == 1:
            f = S(0.05) * (e - S(1.0))
            df = S(C033) * e
            g = S(0.05) * ((e - S(1.0)) / S(6.6) - xe)
        if x > S(0.4):
            y = x - S(0.4)
            g = g + f * y + S(0.5) * df * y * y
            f = f + df * y
        return f, df, g

    @wp.func
    def fibre_tension(lam: S, act: S, k: S, curves: int):
        """T, dT/dlam, energy W for one fibre entry (k = fraction * strength * sigma_max)."""
        fl, dfl, gl = force_length(lam - S(1.0), curves)
        fp, dfp, gp = passive_curve(lam - S(1.0), curves)
        return k * (act * fl + fp), k * (act * dfl + dfp), k * (act * gl + gp)

    @wp.func
    def volume_factor(J: S, jc: S):
        """phi(J) = J^-1/3, phi', phi'' for J >= jc; below jc phi's tangent line at jc (module docstring)."""
        if J >= jc:
            phi = wp.pow(J, S(M1_3))
            return phi, S(M1_3) * phi / J, S(C4_9) * phi / (J * J)
        phic = wp.pow(jc, S(M1_3))
        slope = S(M1_3) * phic / jc
        return phic + slope * (J - jc), slope, S(0.0)

    @wp.func
    def cofactor(F: mat33):
        """cof F = dJ/dF (columns f2 x f3, f3 x f1, f1 x f2 of F's columns f_i; J F^-T when J != 0)."""
        f1 = vec3(F[0, 0], F[1, 0], F[2, 0])
        f2 = vec3(F[0, 1], F[1, 1], F[2, 1])
        f3 = vec3(F[0, 2], F[1, 2], F[2, 2])
        return wp.matrix_from_cols(wp.cross(f2, f3), wp.cross(f3, f1), wp.cross(f1, f2))

    @wp.func
    def deviatoric_fibre(F: mat33, d: vec3, act: S, k: S, jc: S, curves: int):
        """One deviatoric fibre entry: lam = |F d|, lam~, T(lam~), dT/dlam~, W(lam~) and d lam~/dF
        (zero where lam <= 1e-12: there lam~ ~ 0 and T = 0)."""
        q = F * d
        lam = wp.length(q)
        phi, dphi, ddphi = volume_factor(wp.determinant(F), jc)
        lt = phi * lam
        T, dT, W = fibre_tension(lt, act, k, curves)
        grad = mat33()
        if lam > S(1.0e-12):
            grad = (phi / lam) * wp.outer(q, d) + (lam * dphi) * cofactor(F)
        return lam, lt, T, dT, W, grad

    @wp.func
    def add_outer(C: mat99, X: mat33, Y: mat33, w: S):
        """C + w vec(X) vec(Y)^T (row-major vec)."""
        for r in range(9):
            for c in range(9):
                C[r, c] = C[r, c] + w * X[r / 3, r % 3] * Y[c / 3, c % 3]
        return C

    @wp.func
    def projected_plane(C: mat99, Am: mat33, Bm: mat33, ga: S, gb: S, tp: S, beta: S):
        """C + the PSD part of tp g g^T + beta (a b^T + b a^T), g = ga a + gb b (a = vec Am,
        b = vec Bm): the 2x2 matrix in an orthonormal basis e1, e2 of span{a, b} (Gram-Schmidt),
        its eigenvalues clamped at 0. Where b is parallel to a the span is e1 alone."""
        na = wp.max(wp.sqrt(wp.ddot(Am, Am)), S(tiny))
        e1 = Am / na
        b1 = wp.ddot(Bm, e1)
        R = Bm - b1 * e1
        b2 = wp.sqrt(wp.ddot(R, R))
        e2 = mat33()
        if b2 > S(tiny) * wp.sqrt(wp.ddot(Bm, Bm)):
            e2 = R / b2
        else:
            b2 = S(0.0)
        g1 = ga * na + gb * b1
        g2 = gb * b2
        m11 = tp * g1 * g1 + S(2.0) * beta * na * b1
        m12 = tp * g1 * g2 + beta * na * b2
        m22 = tp * g2 * g2
        half = S(0.5) * (m11 - m22)
        mean = S(0.5) * (m11 + m22)
        rad = wp.sqrt(half * half + m12 * m12)
        th = S(0.5) * wp.atan2(m12, half)  # eigenvector (cos th, sin th) of the larger eigenvalue
        u1 = wp.cos(th) * e1 + wp.sin(th) * e2
        u2 = wp.cos(th) * e2 - wp.sin(th) * e1
        C = add_outer(C, u1, u1, wp.max(mean + rad, S(0.0)))
        return add_outer(C, u2, u2, wp.max(mean - rad, S(0.0)))

    @wp.func
    def isotropic_volume_terms(G: vec3, A: mat33, s: vec3, c1: S, c2: S):
        """G + dh/ds and A + d2h/ds2 of h(s) = c(phi(J)), J = s1 s2 s3, given c1 = dh/dJ, c2 = d2h/dJ2:
        dh/ds_i = c1 p_i, d2h/ds_i ds_j = c2 p_i p_j + c1 [i != j] s_k (p_i = J / s_i, k the third index)."""
        p = vec3(s[1] * s[2], s[0] * s[2], s[0] * s[1])
        for i in range(3):
            G[i] = G[i] + c1 * p[i]
            for j in range(3):
                A[i, j] = A[i, j] + c2 * p[i] * p[j]
                if i != j:
                    A[i, j] = A[i, j] + c1 * s[3 - i - j]
        return G, A

    @wp.func
    def deviatoric_fibre_tangent(C: mat99, F: mat33, d: vec3, act: S, k: S, jc: S, curves: int, project: int):
        """C + the anisotropic part of d2W/dF2 for one deviatoric entry (module docstring):
        T' g g^T + T phi' (a b^T + b a^T) + (T phi / lam) (I - n n^T) (x) d d^T, g = d lam~/dF,
        a = vec(n d^T), b = vec(cof F); the isotropic part T lam d2 phi(J) goes to the flesh's modes.
        ``project``: the (I - n n^T) block's coefficient and the 2x2 block on span{a, b} clamped at 0."""
        lam, lt, T, dT, W, g = deviatoric_fibre(F, d, act, k, jc, curves)
        if lam <= S(1.0e-12):
            return C
        phi, dphi, ddphi = volume_factor(wp.determinant(F), jc)
        n = (F * d) / lam
        Am = wp.outer(n, d)
        Bm = cofactor(F)
        c1 = T * phi / lam
        if project == 0:
            C = add_outer(C, g, g, dT)
            C = add_outer(C, Am, Bm, T * dphi)
            C = add_outer(C, Bm, Am, T * dphi)
        else:
            c1 = wp.max(c1, S(0.0))
            C = projected_plane(C, Am, Bm, phi, lam * dphi, dT, T * dphi)
        Hq = c1 * (wp.identity(n=3, dtype=S) - wp.outer(n, n))
        for r in range(9):
            for c in range(9):
                C[r, c] = C[r, c] + Hq[r / 3, c / 3] * d[r % 3] * d[c % 3]
        return C

    @wp.kernel(module="unique", enable_backward=False)
    def fibre_curves(
        # In:
        lam: wp.array(dtype=S),
        curves: int,
        # Out:
        curves_out: wp.array2d(dtype=S),
    ):
        """Columns: f_L, f_L', int f_L, f_P, f_P', int f_P at each stretch (integrals from 1), of ``curves``
        (0 wface's, 1 Blemker's)."""
        i = wp.tid()
        fl, dfl, gl = force_length(lam[i] - S(1.0), curves)
        fp, dfp, gp = passive_curve(lam[i] - S(1.0), curves)
        curves_out[i, 0] = fl
        curves_out[i, 1] = dfl
        curves_out[i, 2] = gl
        curves_out[i, 3] = fp
        curves_out[i, 4] = dfp
        curves_out[i, 5] = gp

    class _Functions:
        pass

    ns = _Functions()
    ns.force_length = force_length
    ns.passive_curve = passive_curve
    ns.fibre_tension = fibre_tension
    ns.fibre_curves = fibre_curves
    ns.volume_factor = volume_factor
    ns.deviatoric_fibre = deviatoric_fibre
    ns.deviatoric_fibre_tangent = deviatoric_fibre_tangent
    ns.isotropic_volume_terms = isotropic_volume_terms
    ns.cofactor = cofactor
    return ns
