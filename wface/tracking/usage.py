"""The usage prior over a whole take: temporal sparse Bayesian learning (docs/design.md, "Priors chosen
by the data").

Each frame t of a first tracking pass is a Gaussian measurement of the activations a_t: its estimate
y_t with the information P_t = I_t / sigma^2 (I_t = J^T W J, the Schur complement over the bones'
rigid motion, m^2 per unit^2; sigma^2 the marker noise variance per coordinate, m^2). Each muscle's
time course x_i = (a_1,i .. a_F,i) is drawn from N(0, gamma_i B), B_ts = rho^|t - s| the correlation
of a stationary AR(1) process (an Ornstein-Uhlenbeck process sampled at the frames,
rho = exp(-1 / length_frames)): temporal sparse Bayesian learning (T-SBL; Zhang & Rao 2011, "Sparse
signal recovery with temporally correlated source vectors using sparse Bayesian learning", IEEE J.
Sel. Topics Signal Process. 5(5), with B shared by the muscles as there). gamma_i -> 0 holds a muscle
the performance does not use at rest; length_frames = 0 (rho = 0) is multiple-measurement SBL
(M-SBL; Wipf & Rao 2007), the frames independent.

Because B^-1 is tridiagonal the joint posterior's precision is block tridiagonal, and its block
elimination over the frames (``smooth``; O(F M^3); the Kalman filter and Rauch-Tung-Striebel smoother
in information form) is run in whitened coordinates u_i = x_i / sqrt(gamma_i) so that
a muscle with gamma_i -> 0 does not make the matrices singular. gamma is fitted by MacKay's fixed
point on the evidence (``fit_usage``), and the length by 5-fold cross-validation over frames
(``choose_length``): the held-out frames' predictive likelihood of their own measurements given the
others. Each frame is then estimated again under its *cavity* prior (``frame_priors``): the
posterior of a_t from every other frame, so that the frame's own markers enter once, through the
tracking objective.

numpy only; no dependence on the rig.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "CV_MAX_FRAMES",
    "LENGTHS_FRAMES",
    "UsageFit",
    "ar1_coefficient",
    "choose_length",
    "fit_usage",
    "frame_priors",
    "smooth",
]

LENGTHS_FRAMES = (0.0, 1.0, 2.0, 4.0, 8.0)  # AR(1) correlation lengths tried by cross-validation (frames)
_FOLDS = 5
_FLOOR = 1e-8  # smallest gamma (unit^2): a muscle held at rest
_HELD = 10.0 * _FLOOR  # a gamma at most this is a muscle held at rest (``UsageFit.held``)
_GAMMA_MAX = 1e3  # largest gamma an accelerated step may propose (unit^2; activations live in [0, 1])
_SQUAREM_ALPHA = 16.0  # largest SQUAREM step length |alpha| (``_fit_gamma_squarem``)
_FOLD_ITERATIONS = 30  # fixed-point steps of a fold's fit, started from the whole take's (4/5 of its data)
_RHO_MAX = 0.98  # largest AR(1) coefficient (keeps the prediction covariance away from singular)
CV_MAX_FRAMES = 300  # the length's cross-validation runs on at most this many consecutive frames (the
# take's middle): its batch of 25 fold fits costs ~0.3 s and ~1.6 MB per frame at 36 muscles


@dataclass
class UsageFit:
    """The take's usage prior: per-muscle variances, the AR(1) length, and how it was chosen."""

    gamma: np.ndarray  # (M,) unit^2
    length_frames: float
    noise_var_m2: float
    cv_score: dict | None = None  # length -> mean held-out log likelihood per frame (nats)
    iterations: int = 0

    @property
    def rho(self) -> float:
        return ar1_coefficient(self.length_frames)

    @property
    def held(self) -> np.ndarray:
        """(M,) bool: muscles the fit holds at rest, their variance at its floor (``_FLOOR``, up to 10x)."""
        return np.asarray(self.gamma) <= _HELD


def ar1_coefficient(length_frames: float) -> float:
    """rho = exp(-1 / length) of the AR(1) correlation over frames (0 for length 0: frames independent)."""
    if length_frames <= 0:
        return 0.0
    return min(float(np.exp(-1.0 / length_frames)), _RHO_MAX)


def _factor_information(info: np.ndarray) -> np.ndarray:
    """(F, M, M) L_t with L_t L_t^T = P_t (its positive part; the columns of unobserved directions zero)."""
    w, V = np.linalg.eigh(0.5 * (info + np.swapaxes(info, 1, 2)))
    w = np.where(w > 1e-12 * np.maximum(w.max(axis=1, keepdims=True), 1e-300), w, 0.0)
    return V * np.sqrt(w)[:, None, :]


@dataclass
class _Smoothed:
    mean: np.ndarray  # (B, F, M) whitened posterior means
    cov: np.ndarray  # (B, F, M, M) whitened posterior covariances
    lag: np.ndarray  # (B, F-1, M, M) Cov(u_t+1, u_t | data)


def _smooth_white(Lw, zs, observed, rho, *, diagonal: bool = False) -> _Smoothed:
    """The posterior of u_t = rho u_t-1 + sqrt(1 - rho^2) e_t, u_1 ~ N(0, I), given the measurements
    z_t = L_t^T u_t + N(0, I) on the observed frames; B problems at once (the lengths and folds of the
    cross-validation share every step). Lw (B, F, M, M) whitened factors, zs (F, M), observed (B, F)
    bool, rho (B,). Problems with rho = 0 (frames independent) in closed form, all frames at once
    (``_smooth_independent``); the others by block elimination over the frames (``_smooth_recursive``).
    ``diagonal``: only the diagonals of the covariances and lag covariances, (B, F, M) and (B, F-1, M)
    (all that MacKay's step needs; the full (B, F, M, M) arrays are most of a sweep's memory traffic)."""
    B = Lw.shape[0]
    rho = np.asarray(rho, dtype=np.float64).reshape(B)
    obs = np.asarray(observed, dtype=bool).reshape(B, -1)
    zero = rho == 0.0
    if not zero.any():
        return _smooth_recursive(Lw, zs, obs, rho, diagonal)
    if zero.all():
        return _smooth_independent(Lw, zs, obs, diagonal)
    a = _smooth_recursive(Lw[~zero], zs, obs[~zero], rho[~zero], diagonal)
    b = _smooth_independent(Lw[zero], zs, obs[zero], diagonal)
    out = []
    for name in ("mean", "cov", "lag"):
        part = np.empty((B, *getattr(a, name).shape[1:]))
        part[~zero], part[zero] = getattr(a, name), getattr(b, name)
        out.append(part)
    return _Smoothed(*out)


def _smooth_independent(Lw, zs, observed, diagonal: bool = False) -> _Smoothed:
    """``_smooth_white`` at rho = 0: each frame's posterior alone, precision I + L_t L_t^T and mean
    (I + L_t L_t^T)^-1 L_t z_t where observed, the prior N(0, I) where not; no lag covariance."""
    B, F, M, _ = Lw.shape
    eye = np.eye(M)
    cov = np.linalg.inv(eye + Lw @ np.swapaxes(Lw, 2, 3))
    cov = 0.5 * (cov + np.swapaxes(cov, 2, 3))
    mean = np.einsum("bfij,bfj->bfi", cov, np.einsum("bfij,fj->bfi", Lw, zs))
    held = ~np.asarray(observed, dtype=bool).reshape(B, F)
    cov[held], mean[held] = eye, 0.0
    if diagonal:
        return _Smoothed(mean, np.einsum("bfii->bfi", cov).copy(), np.zeros((B, max(F - 1, 0), M)))
    return _Smoothed(mean, cov, np.zeros((B, max(F - 1, 0), M, M)))


def _smooth_recursive(Lw, zs, observed, rho, diagonal: bool = False) -> _Smoothed:
    """``_smooth_white`` for rho > 0 by block elimination of the posterior's block-tridiagonal
    precision. In whitened coordinates the prior precision is B^-1 (x) I_M, whose off-diagonal
    blocks are c I with c = -rho / (1 - rho^2), so the posterior precision A has diagonal blocks
    A_t = d_t I + L_t L_t^T (d_t = (1 + rho^2) / (1 - rho^2) inside, 1 / (1 - rho^2) at the ends)
    and off-diagonal blocks c I. Its block LDL^T, U_1 = A_1, U_t = A_t - c^2 U_t-1^-1, gives the
    means by two substitutions and the covariances by selected inversion (Takahashi et al. 1973):
    S_F = U_F^-1, S_t+1,t = -c S_t+1 U_t^-1, S_t = U_t^-1 + c^2 U_t^-1 S_t+1 U_t^-1. One inverse and
    three products per frame, where the Kalman filter and RTS smoother take two solves and five
    products (docs/design.md, "Priors chosen by the data"); the posterior is the same."""
    B, F, M, _ = Lw.shape
    rho = np.asarray(rho, dtype=np.float64).reshape(B)
    obs = np.asarray(observed, dtype=np.float64).reshape(B, F)
    q = 1.0 / (1.0 - rho * rho)
    d = np.repeat(((1.0 + rho * rho) * q)[:, None], F, axis=1)
    d[:, 0] = d[:, -1] = q
    if F == 1:
        d[:] = 1.0
    c = (-rho * q)[:, None, None]
    eye = np.eye(M)
    Ui = np.empty((B, F, M, M))  # U_t^-1
    w = np.empty((B, F, M))  # the forward substitution L w = h
    for t in range(F):  # per frame: whole (B, F, M, M) temporaries cost more in memory traffic than flops
        Lo = Lw[:, t] * obs[:, t, None, None]  # an unobserved frame has no data
        U = Lo @ np.swapaxes(Lo, 1, 2) + d[:, t, None, None] * eye  # the data's precision L_t L_t^T + prior
        w[:, t] = Lo @ zs[t]  # the data's information vector L_t z_t
        if t > 0:
            U -= c * c * Ui[:, t - 1]
            w[:, t] -= c[:, :, 0] * np.einsum("bij,bj->bi", Ui[:, t - 1], w[:, t - 1])
        inv = np.linalg.inv(U)
        Ui[:, t] = 0.5 * (inv + np.swapaxes(inv, 1, 2))
    mean = np.empty((B, F, M))
    shape = (M,) if diagonal else (M, M)
    cov, lag = np.empty((B, F, *shape)), np.zeros((B, max(F - 1, 0), *shape))
    S = Ui[:, F - 1]
    mean[:, F - 1] = np.einsum("bij,bj->bi", S, w[:, F - 1])
    cov[:, F - 1] = np.einsum("bii->bi", S) if diagonal else S
    for t in range(F - 2, -1, -1):
        mean[:, t] = np.einsum("bij,bj->bi", Ui[:, t], w[:, t] - c[:, :, 0] * mean[:, t + 1])
        P = S @ Ui[:, t]  # S_t+1 U_t^-1
        S = Ui[:, t] + c * c * (Ui[:, t] @ P)
        S = 0.5 * (S + np.swapaxes(S, 1, 2))
        if diagonal:
            cov[:, t], lag[:, t] = np.einsum("bii->bi", S), -c[:, :, 0] * np.einsum("bii->bi", P)
        else:
            cov[:, t], lag[:, t] = S, -c * P
    return _Smoothed(mean, cov, lag)


def _whitened(L, Y, gamma):
    """(whitened factors diag(sqrt gamma_b) L_t (B, F, M, M), z_t = L_t^T y_t (F, M)) for gamma (B, M)."""
    g = np.sqrt(np.atleast_2d(gamma))
    return g[:, None, :, None] * L[None], np.einsum("tij,ti->tj", L, Y)


def smooth(activations, informations, noise_var_m2: float, gamma, length_frames: float, observed=None):
    """(means (F, M), covariances (F, M, M)) of the activations given every frame's measurement under
    the prior N(0, gamma_i B) per muscle (module docstring)."""
    Y = np.asarray(activations, dtype=np.float64)
    P = np.asarray(informations, dtype=np.float64) / max(float(noise_var_m2), 1e-30)
    gamma = np.maximum(np.asarray(gamma, dtype=np.float64), _FLOOR)
    observed = np.ones((1, len(Y)), bool) if observed is None else np.asarray(observed, bool)[None]
    Lw, zs = _whitened(_factor_information(P), Y, gamma[None])
    sm = _smooth_white(Lw, zs, observed, [ar1_coefficient(length_frames)])
    g = np.sqrt(gamma)
    return sm.mean[0] * g, sm.cov[0] * g[:, None] * g[None, :]


def _quadratic_b_inverse(x2: np.ndarray, xx: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """(B, M) sum over frames of x^T B^-1 x per muscle from E[x_t^2] (B, F, M) and E[x_t+1 x_t]
    (B, F-1, M): B^-1 of the AR(1) correlation is tridiagonal,
    (1 - rho^2) B^-1 = tridiag(-rho; 1, 1 + rho^2, .., 1 + rho^2, 1; -rho)."""
    r = rho[:, None]
    inner = x2.sum(axis=1) + r * r * x2[:, 1:-1].sum(axis=1) - 2.0 * r * xx.sum(axis=1)
    return inner / (1.0 - r * r)


def _mackay_step(L, Y, observed, rho, gamma, *, diagonal: bool = True):
    """One step of MacKay's fixed point, B problems at once: (gamma_new (B, M), the smoother's sweep at
    ``gamma``, live): gamma_i <- mu_i^T B^-1 mu_i / (n - tr(B^-1 S_ii) / gamma_i) (``_fit_gamma``).

    A muscle every problem of the batch holds at rest (gamma <= ``_HELD``) is left out of the sweep,
    its activation fixed at 0 (the data's information vector P_t y_t still taken whole), and its gamma
    set to the floor, where the step would clamp it (its ratio mean_q / (F - cov_q) is ~gamma times the
    data's evidence, << 1); the sweep then covers only the muscles in use (its cost is cubic in them),
    and its arrays only those: ``sm`` is over the muscles of ``live`` (M,) bool, also returned."""
    F = Y.shape[0]
    live = np.any(gamma > _HELD, axis=0)
    if not live.all():
        new = np.full_like(gamma, _FLOOR)
        zs = np.einsum("tij,ti->tj", L, Y)
        new[:, live], sm = _mackay_live(L[:, live], zs, F, observed, rho, gamma[:, live], diagonal=diagonal)
        return new, sm, live
    Lw, zs = _whitened(L, Y, gamma)
    return (*_mackay_live(Lw, zs, F, observed, rho, gamma, whitened=True, diagonal=diagonal), live)


def _mackay_live(L, zs, F, observed, rho, gamma, *, whitened: bool = False, diagonal: bool = True):
    """``_mackay_step`` on the muscles of ``gamma`` (B, m): L (F, m, M) their rows of the information's
    factors (or, ``whitened``, already (B, F, m, M)), zs (F, M) the measurements z_t = L_t^T y_t."""
    Lw = L if whitened else np.sqrt(gamma)[:, None, :, None] * L[None]
    sm = _smooth_white(Lw, zs, observed, rho, diagonal=diagonal)
    mu = sm.mean
    diag = sm.cov if diagonal else np.einsum("btii->bti", sm.cov)
    lag_d = sm.lag if diagonal else np.einsum("btii->bti", sm.lag)
    mean_q = _quadratic_b_inverse(mu**2, mu[:, 1:] * mu[:, :-1], rho)
    cov_q = _quadratic_b_inverse(diag, lag_d, rho)
    # whitened: gamma_new = gamma * mean_q / (F - cov_q); an unobserved frame adds ~1 to both F and
    # cov_q (its posterior is its prior), so it cancels
    denom = np.maximum(F - cov_q, 1e-3)
    return np.maximum(gamma * mean_q / denom, _FLOOR), sm


def _settled_rows(gamma, new, rtol) -> np.ndarray:
    """(B,) bool: a fixed-point step changed no gamma of the problem by more than ``rtol`` of itself; a
    pruned one (below 1e-3 of its problem's largest) counts as settled."""
    scale = np.maximum(np.maximum(gamma, new), 1e-3 * new.max(axis=1, keepdims=True))
    return np.max(np.abs(new - gamma) / scale, axis=1) < rtol


def _settled(gamma, new, rtol) -> bool:
    """Every problem of the batch settled (``_settled_rows``)."""
    return bool(np.all(_settled_rows(gamma, new, rtol)))


def _fit_gamma(L, Y, observed, rho, gamma0, iterations, rtol, *, noise_var_m2=1.0, noise=None):
    """MacKay's fixed point for gamma on the evidence, B problems at once (observed (B, F), rho (B,),
    gamma0 (B, M)): gamma_i <- mu_i^T B^-1 mu_i / (n - tr(B^-1 S_ii) / gamma_i), n the frames. ``L``
    factors the information in units of ``noise_var_m2``; with ``noise`` = (I, residual_m2, dof)
    (B = 1, every frame observed) sigma^2 takes its EM step from the same sweep (``_noise_update``),
    else the steps are accelerated (``_fit_gamma_squarem``). Returns (gamma (B, M), sigma^2, steps)."""
    gamma = np.array(gamma0, dtype=np.float64)
    rho = np.asarray(rho, dtype=np.float64)
    s2 = float(noise_var_m2)
    if noise is None:
        gamma, it = _fit_gamma_squarem(L, Y, observed, rho, gamma, iterations, rtol)
        return gamma, s2, it
    it = 0
    for it in range(1, iterations + 1):  # noqa: B007
        new, sm, live = _mackay_step(L, Y, observed, rho, gamma, diagonal=False)  # the noise step needs S_t whole
        done = _settled(gamma, new, rtol)
        s2_new = _noise_update(noise, Y, sm, gamma[0], s2, live)
        done = done and abs(s2_new - s2) < rtol * s2
        L = L * np.sqrt(s2 / s2_new)  # the information in units of the new sigma^2
        s2 = s2_new
        gamma = new
        if done:
            break
    return gamma, s2, it


def _fit_gamma_squarem(L, Y, observed, rho, gamma, iterations, rtol) -> tuple[np.ndarray, int]:
    """(gamma, fixed-point steps): MacKay's steps accelerated by SQUAREM (Varadhan & Roland 2008,
    scheme S3) in x = log gamma, each problem of the batch with its own step: from x0 two steps give
    r = x1 - x0 and v = x2 - 2 x1 + x0, alpha = -|r| / |v| (at most -1: two plain steps; at least
    -``_SQUAREM_ALPHA``), x' = x0 - 2 alpha r + alpha^2 v, and one more plain step from x' keeps the
    iteration stable. A problem is done where a plain step settles (``_settled_rows``) and leaves the
    batch there (the sweeps' cost is per problem): the same fixed point as the plain iteration, in 2-5x
    fewer steps (docs/design.md, "Priors chosen by the data"). Steps: the most any problem took."""
    lo, hi = np.log(_FLOOR), np.log(_GAMMA_MAX)
    out = np.array(gamma, dtype=np.float64)
    rho, observed = np.asarray(rho, dtype=np.float64), np.asarray(observed)
    live = np.arange(len(out))  # the problems not yet settled
    g0, it = out.copy(), 0

    def step(g_from):
        nonlocal it
        it += 1
        return _mackay_step(L, Y, observed[live], rho[live], g_from)[0]

    def retire(done, g_final, *others):
        """Record the settled problems' gamma, keep the rest (and the rows of ``others``)."""
        nonlocal live
        done = done | (it >= iterations)
        out[live[done]] = g_final[done]
        live = live[~done]
        return [a[~done] for a in (g_final, *others)]

    while live.size:
        g1 = step(g0)
        g1, g0 = retire(_settled_rows(g0, g1, rtol), g1, g0)
        if not live.size:
            break
        g2 = step(g1)
        g2, g1, g0 = retire(_settled_rows(g1, g2, rtol), g2, g1, g0)
        if not live.size:
            break
        x0, x1, x2 = np.log(g0), np.log(g1), np.log(g2)
        r, v = x1 - x0, x2 - 2.0 * x1 + x0
        nr, nv = np.linalg.norm(r, axis=1), np.linalg.norm(v, axis=1)
        alpha = np.clip(-nr / np.maximum(nv, 1e-300), -_SQUAREM_ALPHA, -1.0)[:, None]
        jump = np.exp(np.clip(x0 - 2.0 * alpha * r + alpha * alpha * v, lo, hi))
        g3 = step(jump)
        lost = ~np.all(np.isfinite(g3), axis=1)  # the extrapolation left the fixed point's basin: plain steps
        jump[lost], g3[lost] = g1[lost], g2[lost]
        (g0,) = retire(_settled_rows(jump, g3, rtol), g3)
    return out, it


def _noise_update(noise, Y, sm: _Smoothed, gamma, noise_var_m2: float, live) -> float:
    """sigma^2's fixed-point step (MacKay 1992's form of the EM update, which converges in a few steps
    where EM creeps): the data term at the posterior mean over the degrees of freedom the activations
    leave, sum_t (phi_min,t + (mu_t - z_t)^T I_t (mu_t - z_t)) / (sum_t dof_t - sum_t tr(P_t S_t)),
    phi = phi_min + (a - z)^T I (a - z) the linearised weighted residual, P_t = I_t / sigma^2.
    ``noise`` = (I (F, M, M), residual_m2 (F,), dof (F,)); ``sm`` the smoother's sweep (batch 0) over
    the muscles of ``live`` (M,) bool, the others held at 0 (``_mackay_step``)."""
    I, residual_m2, dof = noise
    g = np.sqrt(gamma[live])
    mean = np.zeros_like(Y)
    mean[:, live] = sm.mean[0] * g
    d = mean - Y
    cov = sm.cov[0] * g[:, None] * g[None, :]
    fitted = float(np.sum(residual_m2)) + float(np.einsum("ti,tij,tj->", d, I, d))  # phi at the posterior mean
    used = float(np.sum(I[:, live][:, :, live] * cov)) / noise_var_m2  # tr(P_t S_t): what the data determine
    return fitted / max(float(np.sum(dof)) - used, 1.0)


def fit_usage(
    activations,
    informations,
    noise_var_m2: float,
    *,
    length_frames: float | None = None,
    lengths=LENGTHS_FRAMES,
    iterations: int = 300,
    rtol: float = 1e-3,
    residual_m2=None,
    dof=None,
    cv_frames: int = CV_MAX_FRAMES,
    progress=None,
) -> UsageFit:
    """The usage prior of a pass: gamma by evidence maximisation, (``length_frames`` None) the AR(1)
    length by 5-fold cross-validation over frames among ``lengths``, and (with ``residual_m2`` and
    ``dof``) the marker noise sigma^2 with gamma by EM (at length 0, before the length is chosen).

    Args:
        activations: (F, M) the pass's data-only measurements z_t of the activations.
        informations: (F, M, M) their data information J^T W J (m^2 per unit^2).
        noise_var_m2: sigma^2, marker noise variance per coordinate (m^2): fixed, or the EM's start.
        residual_m2: (F,) the weighted squared marker residual at z_t (m^2), phi_min,t.
        dof: (F,) the residual's degrees of freedom per frame (3 sum w_k minus the bones' 9).
        cv_frames: a longer take chooses its length on its middle ``cv_frames`` frames (the correlation
            length is a property of the motion, not of the take's length) and fits gamma at that length
            on every frame: the cross-validation's time and memory stay bounded on long takes.
        progress: None, or a callable given one line (str) as each stage of the fit starts.
    """
    Y = np.asarray(activations, dtype=np.float64)
    I = np.asarray(informations, dtype=np.float64)
    F, M = Y.shape
    s2 = max(float(noise_var_m2), 1e-30)
    every = np.ones((1, F), bool)
    gamma0 = np.full((1, M), max(float(np.mean(Y**2)), _FLOOR))  # every fit starts here: a muscle the
    # fixed point has pruned (gamma at the floor) does not come back from a warm start
    noise = None if residual_m2 is None or dof is None else (I, np.asarray(residual_m2), np.asarray(dof))
    rho = 0.0 if length_frames is None else ar1_coefficient(length_frames)
    say = progress or (lambda line: None)
    what = "the marker noise and the usage variances" if noise is not None else "the usage variances"
    at = "the frames independent" if length_frames is None else f"correlation length {length_frames:g} frames"
    say(f"{what} on {F} frames ({at})")
    L = _factor_information(I / s2)
    gamma, s2, its = _fit_gamma(L, Y, every, [rho], gamma0, iterations, rtol, noise_var_m2=s2, noise=noise)
    scores = None
    if length_frames is None:
        L = _factor_information(I / s2)
        s0 = max(0, (F - int(cv_frames)) // 2)
        window = slice(s0, min(F, s0 + max(int(cv_frames), _FOLDS)))
        n = window.stop - window.start
        say(f"the correlation length: {len(lengths)} lengths x {min(_FOLDS, n)}-fold cross-validation on {n} frames")
        scores, fits = choose_length(L[window], Y[window], gamma0[0], lengths, iterations=iterations, rtol=rtol)
        length_frames = max(scores, key=lambda k: (scores[k], -k))
        gamma = fits[length_frames][None]
        if n < F:  # gamma of the chosen length on the whole take
            say(f"the usage variances on {F} frames (correlation length {length_frames:g} frames)")
            rho = [ar1_coefficient(length_frames)]
            gamma, _, _ = _fit_gamma(L, Y, every, rho, gamma0, iterations, rtol)
    return UsageFit(gamma[0], float(length_frames), float(s2), scores, its)


def choose_length(L, Y, gamma0, lengths, *, iterations: int = 300, rtol: float = 1e-3) -> tuple[dict, dict]:
    """({length: mean held-out log predictive likelihood per frame (nats)}, {length: gamma on every
    frame}): 5 interleaved folds of frames (frame t in fold t mod 5; leave-one-out below 5 frames),
    gamma fitted on the other folds (30 fixed-point steps from the whole take's fit), the held-out frames'
    measurements predicted by the smoother from them. All lengths and folds run as one batch."""
    F, M = Y.shape
    lengths = [float(v) for v in lengths]
    rhos = np.array([ar1_coefficient(v) for v in lengths])
    nL = len(lengths)
    full, _, _ = _fit_gamma(L, Y, np.ones((nL, F), bool), rhos, np.tile(gamma0, (nL, 1)), iterations, rtol)
    folds = min(_FOLDS, F)
    held = (np.arange(F)[None, :] % folds) == np.arange(folds)[:, None]  # (folds, F)
    observed = np.tile(~held, (nL, 1))  # (nL * folds, F), length-major
    rho_b = np.repeat(rhos, folds)
    start = np.repeat(np.maximum(full, 1e-2 * gamma0[None]), folds, axis=0)
    gamma, _, _ = _fit_gamma(L, Y, observed, rho_b, start, _FOLD_ITERATIONS, rtol)
    Lw, zs = _whitened(L, Y, gamma)
    sm = _smooth_white(Lw, zs, observed, rho_b)
    Lt = np.swapaxes(Lw, 2, 3)  # (B, F, M, M)
    S = Lt @ sm.cov @ Lw + np.eye(M)
    e = zs[None] - np.einsum("btij,btj->bti", Lt, sm.mean)
    cS = np.linalg.cholesky(S)
    sol = np.linalg.solve(cS, e[..., None])[..., 0]
    ll = -0.5 * np.sum(sol**2, axis=2) - np.log(np.diagonal(cS, axis1=2, axis2=3)).sum(axis=2)
    ll = (ll - 0.5 * M * np.log(2.0 * np.pi)) * ~observed  # the held-out frames only
    per_length = ll.reshape(nL, folds, F).sum(axis=(1, 2)) / F
    scores = {v: float(per_length[i]) for i, v in enumerate(lengths)}
    return scores, {v: full[i] for i, v in enumerate(lengths)}


def frame_priors(activations, informations, fit: UsageFit) -> tuple[np.ndarray, np.ndarray]:
    """(means (F, M), precisions (F, M, M), unit^-2): each frame's cavity prior, the posterior of a_t
    from every other frame's measurement under ``fit`` (for length 0: N(0, diag(gamma)) for every frame).
    The tracking objective's weight is sigma^2 times the precision."""
    Y = np.asarray(activations, dtype=np.float64)
    P = np.asarray(informations, dtype=np.float64) / max(fit.noise_var_m2, 1e-30)
    F, M = Y.shape
    gamma = np.maximum(fit.gamma, _FLOOR)
    g = np.sqrt(gamma)
    Lw, zs = _whitened(_factor_information(P), Y, gamma[None])
    sm = _smooth_white(Lw, zs, np.ones((1, F), bool), [fit.rho])
    Lw, mean, cov = Lw[0], sm.mean[0], sm.cov[0]
    means = np.zeros((F, M))
    precisions = np.zeros((F, M, M))
    for t in range(F):
        post_info = np.linalg.inv(cov[t])
        cav_info = post_info - Lw[t] @ Lw[t].T  # whitened: the other frames and the prior
        cav_info = 0.5 * (cav_info + cav_info.T)
        w, V = np.linalg.eigh(cav_info)
        cav_info = (V * np.maximum(w, 1e-9)) @ V.T  # round-off can leave it slightly indefinite
        h = post_info @ mean[t] - Lw[t] @ zs[t]
        means[t] = g * np.linalg.solve(cav_info, h)
        precisions[t] = cav_info / g[:, None] / g[None, :]
    return means, precisions
