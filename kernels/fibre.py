"""Muscle fibre curves (Warp device code, float64 and float32; docs/design.md, "Muscle fibres").

Fibre stretch lam = |F d|, x = lam - 1. Tension T(lam, a) = k (a f_L(lam) + f_P(lam)),
k = fraction * strength * sigma_max (Teran et al. 2005; Zajac 1989 force-length shape):
- force-length f_L = 1 - (25/6) x^2 for |x| < 0.4; (25/3)(|x| - 0.6)^2 for 0.4 <= |x| < 0.6; 0 beyond;
- passive f_P = 0.05 (exp(6.6 x) - 6.6 x - 1) for 0 < x <= 0.4, continued linearly (C1) above, 0 for x <= 0.
The fibre energy is the integral of T over the stretch from 1, in closed form per piece.
"""

import functools

import warp as wp

wp.set_module_options({"enable_backward": False})

__all__ = ["fibre_functions"]


@functools.cache
def fibre_functions(dtype):
    """Namespace with ``force_length``, ``passive_curve``, ``fibre_tension`` (wp.func) and the
    ``fibre_curves`` kernel for scalar ``dtype``."""
    S = dtype
    # Constant expressions are folded here in double precision: inside a kernel, S(25.0 / 6.0)
    # would be evaluated in float32 first.
    C25_18, C25_6, C25_3, C50_3, C25_9 = 25.0 / 18.0, 25.0 / 6.0, 25.0 / 3.0, 50.0 / 3.0, 25.0 / 9.0
    C033 = 0.05 * 6.6

    @wp.func
    def force_length(x: S):
        """f_L, df_L/dlam and the integral from 1 of f_L, at lam = 1 + x."""
        ax = wp.abs(x)
        sg = S(1.0)
        if x < S(0.0):
            sg = S(-1.0)
        g04 = S(0.4) - S(C25_18) * S(0.064)
        if ax < S(0.4):
            return S(1.0) - S(C25_6) * x * x, -S(C25_3) * x, x - S(C25_18) * x * x * x
        if ax < S(0.6):
            y = ax - S(0.6)
            return S(C25_3) * y * y, sg * S(C50_3) * y, sg * (g04 + S(C25_9) * (y * y * y + S(0.008)))
        return S(0.0), S(0.0), sg * (g04 + S(C25_9) * S(0.008))

    @wp.func
    def passive_curve(x: S):
        """f_P, df_P/dlam and the integral from 1 of f_P, at lam = 1 + x (C1, linear beyond 1.4)."""
        if x <= S(0.0):
            return S(0.0), S(0.0), S(0.0)
        xe = wp.min(x, S(0.4))
        e = wp.exp(S(6.6) * xe)
        f = S(0.05) * (e - S(6.6) * xe - S(1.0))
        df = S(C033) * (e - S(1.0))
        g = S(0.05) * ((e - S(1.0)) / S(6.6) - S(3.3) * xe * xe - xe)
        if x > S(0.4):
            y = x - S(0.4)
            g = g + f * y + S(0.5) * df * y * y
            f = f + df * y
        return f, df, g

    @wp.func
    def fibre_tension(lam: S, act: S, k: S):
        """T, dT/dlam, energy W for one fibre entry (k = fraction * strength * sigma_max)."""
        fl, dfl, gl = force_length(lam - S(1.0))
        fp, dfp, gp = passive_curve(lam - S(1.0))
        return k * (act * fl + fp), k * (act * dfl + dfp), k * (act * gl + gp)

    @wp.kernel(module="unique", enable_backward=False)
    def fibre_curves(
        # In:
        lam: wp.array(dtype=S),
        # Out:
        curves_out: wp.array2d(dtype=S),
    ):
        """Columns: f_L, f_L', int f_L, f_P, f_P', int f_P at each stretch (integrals from 1)."""
        i = wp.tid()
        fl, dfl, gl = force_length(lam[i] - S(1.0))
        fp, dfp, gp = passive_curve(lam[i] - S(1.0))
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
    return ns
