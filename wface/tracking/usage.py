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

Because B^-1 is tridiagonal the joint posterior is a Kalman filter and Rauch-Tung-Striebel smoother
over the frames (``smooth``; O(F M^3)), run in whitened coordinates u_i = x_i / sqrt(gamma_i) so that
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
_RHO_MAX = 0.98  # largest AR(1) coefficient (keeps the prediction covariance away from singular)


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


def ar1_coefficient(length_frames: float) -> float:
    """rho = exp(-1 / length) of the AR(1) correlation over frames (0 for length 0: frames independent)."""
    if length_frames <= 0:
        return 0.0
    return min(float(np.exp(-1.0 / length_frames)), _RHO_MAX)


def _factor_information(info: np.ndarray) -> list[np.ndarray]:
    """L_t (M, r_t) with L_t L_t^T = P_t (positive part), per frame."""
    out = []
    for P in info:
        w, V = np.linalg.eigh(0.5 * (P + P.T))
        keep = w > 1e-12 * max(float(w.max()), 1e-300)
        out.append(V[:, keep] * np.sqrt(w[keep]))
    return out


@dataclass
class _Smoothed:
    mean: np.ndarray  # (F, M) whitened posterior means
    cov: np.ndarray  # (F, M, M) whitened posterior covariances
    lag: np.ndarray  # (F-1, M, M) Cov(u_t+1, u_t | data)
    loglik: np.ndarray  # (F,) log predictive likelihood of each observed frame's measurement (nats)


def _smooth_white(Ls, zs, observed, rho: float, M: int) -> _Smoothed:
    """Kalman filter + RTS smoother of u_t = rho u_t-1 + sqrt(1 - rho^2) e_t, u_1 ~ N(0, I), with the
    measurements z_t = L_t^T u_t + N(0, I) (whitened L_t) on the observed frames."""
    F = len(Ls)
    q = 1.0 - rho * rho
    mf = np.zeros((F, M))
    Cf = np.zeros((F, M, M))
    mp = np.zeros((F, M))
    Cp = np.zeros((F, M, M))
    loglik = np.zeros(F)
    m, C = np.zeros(M), np.eye(M)
    for t in range(F):
        if t > 0:
            m, C = rho * m, rho * rho * C + q * np.eye(M)
        mp[t], Cp[t] = m, C
        L = Ls[t]
        if observed[t] and L.shape[1]:
            S = L.T @ C @ L + np.eye(L.shape[1])
            e = zs[t] - L.T @ m
            cS = np.linalg.cholesky(S)
            sol = np.linalg.solve(cS, e)
            loglik[t] = -0.5 * (sol @ sol) - np.log(np.diag(cS)).sum() - 0.5 * len(e) * np.log(2 * np.pi)
            K = np.linalg.solve(S, L.T @ C).T  # C L S^-1
            m = m + K @ e
            C = C - K @ L.T @ C
            C = 0.5 * (C + C.T)
        mf[t], Cf[t] = m, C
    ms, Cs = mf.copy(), Cf.copy()
    lag = np.zeros((max(F - 1, 0), M, M))
    for t in range(F - 2, -1, -1):
        G = np.linalg.solve(Cp[t + 1], rho * Cf[t]).T  # rho Cf_t Cp_t+1^-1 (both symmetric)
        ms[t] = mf[t] + G @ (ms[t + 1] - mp[t + 1])
        Cs[t] = Cf[t] + G @ (Cs[t + 1] - Cp[t + 1]) @ G.T
        Cs[t] = 0.5 * (Cs[t] + Cs[t].T)
        lag[t] = Cs[t + 1] @ G.T
    return _Smoothed(ms, Cs, lag, loglik)


def _whitened(Ls, ys, gamma):
    """Whitened measurement factors L_t' = diag(sqrt gamma) L_t and z_t = L_t^T y_t."""
    g = np.sqrt(gamma)
    return [g[:, None] * L for L in Ls], [L.T @ y for L, y in zip(Ls, ys, strict=True)]


def smooth(activations, informations, noise_var_m2: float, gamma, length_frames: float, observed=None):
    """(means (F, M), covariances (F, M, M)) of the activations given every frame's measurement under
    the prior N(0, gamma_i B) per muscle (module docstring)."""
    Y = np.asarray(activations, dtype=np.float64)
    P = np.asarray(informations, dtype=np.float64) / max(float(noise_var_m2), 1e-30)
    gamma = np.maximum(np.asarray(gamma, dtype=np.float64), _FLOOR)
    observed = np.ones(len(Y), bool) if observed is None else np.asarray(observed, bool)
    Lw, zs = _whitened(_factor_information(P), Y, gamma)
    sm = _smooth_white(Lw, zs, observed, ar1_coefficient(length_frames), Y.shape[1])
    g = np.sqrt(gamma)
    return sm.mean * g, sm.cov * g[:, None] * g[None, :]


def _quadratic_b_inverse(x2: np.ndarray, xx: np.ndarray, rho: float) -> np.ndarray:
    """sum over frames of x^T B^-1 x per muscle from E[x_t^2] (F, M) and E[x_t+1 x_t] (F-1, M):
    B^-1 of the AR(1) correlation is tridiagonal, (1 - rho^2) B^-1 = tridiag(-rho; 1, 1 + rho^2 .., 1; -rho)."""
    if rho == 0.0:
        return x2.sum(axis=0)
    inner = x2.sum(axis=0) + rho * rho * x2[1:-1].sum(axis=0) - 2.0 * rho * xx.sum(axis=0)
    return inner / (1.0 - rho * rho)


def _fit_gamma(Ls, Y, observed, rho, gamma0, iterations, rtol):
    """MacKay's fixed point for gamma on the evidence: gamma_i <- mu_i^T B^-1 mu_i / (F - tr(B^-1 S_ii) / gamma_i)."""
    F, M = Y.shape
    gamma = gamma0.copy()
    n = int(observed.sum())
    it = 0
    for it in range(1, iterations + 1):  # noqa: B007
        Lw, zs = _whitened(Ls, Y, gamma)
        sm = _smooth_white(Lw, zs, observed, rho, M)
        mu = sm.mean
        diag = np.einsum("tii->ti", sm.cov)
        lag_d = np.einsum("tii->ti", sm.lag) if F > 1 else np.zeros((0, M))
        mean_q = _quadratic_b_inverse(mu**2, mu[1:] * mu[:-1], rho)
        cov_q = _quadratic_b_inverse(diag, lag_d, rho)
        # whitened: gamma_new = gamma * mean_q / (F - cov_q), the frames' own count F (unobserved frames
        # contribute prior mass only, cov_q ~ 1 each, so they cancel in F - cov_q)
        denom = np.maximum(F - cov_q, 1e-3 * max(n, 1))
        new = np.maximum(gamma * mean_q / denom, _FLOOR)
        scale = np.maximum(np.maximum(gamma, new), 1e-4 * float(new.max()))  # a pruned muscle has settled
        done = np.max(np.abs(new - gamma) / scale) < rtol
        gamma = new
        if done:
            break
    return gamma, it


def _noise_update(I, Y, rho, gamma, noise_var_m2, residual_m2, dof) -> float:
    """sigma^2's EM update: the expected data term under the posterior over its degrees of freedom,
    sum_t (phi_min,t + (mu_t - z_t)^T I_t (mu_t - z_t) + tr(I_t S_t)) / sum_t dof_t (phi = phi_min +
    (a - z)^T I (a - z), the linearised weighted residual; Wipf & Rao 2007 learn the noise the same way)."""
    F, M = Y.shape
    Ls = _factor_information(I / noise_var_m2)
    Lw, zs = _whitened(Ls, Y, gamma)
    sm = _smooth_white(Lw, zs, np.ones(F, bool), rho, M)
    g = np.sqrt(gamma)
    mu = sm.mean * g
    total = float(np.sum(residual_m2))
    for t in range(F):
        d = mu[t] - Y[t]
        total += float(d @ I[t] @ d) + float(np.sum(I[t] * (sm.cov[t] * g[:, None] * g[None, :])))
    return total / float(np.sum(dof))


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
    noise_rounds: int = 8,
) -> UsageFit:
    """The usage prior of a pass: gamma by evidence maximisation, (``length_frames`` None) the AR(1)
    length by 5-fold cross-validation over frames among ``lengths``, and (with ``residual_m2`` and
    ``dof``) the marker noise sigma^2 with gamma by EM.

    Args:
        activations: (F, M) the pass's data-only measurements z_t of the activations.
        informations: (F, M, M) their data information J^T W J (m^2 per unit^2).
        noise_var_m2: sigma^2, marker noise variance per coordinate (m^2): fixed, or the EM's start.
        residual_m2: (F,) the weighted squared marker residual at z_t (m^2), phi_min,t.
        dof: (F,) the residual's degrees of freedom per frame (3 sum w_k minus the bones' 9).
        noise_rounds: alternations of sigma^2's update and gamma's fit at most.
    """
    Y = np.asarray(activations, dtype=np.float64)
    I = np.asarray(informations, dtype=np.float64)
    F, M = Y.shape
    s2 = max(float(noise_var_m2), 1e-30)
    every = np.ones(F, bool)
    gamma0 = np.full(M, max(float(np.mean(Y**2)), _FLOOR))  # every fit starts here: a muscle the
    # fixed point has pruned (gamma at the floor) would never come back from a warm start
    gamma = gamma0
    learn_noise = residual_m2 is not None and dof is not None
    scores, its = None, 0
    rho = 0.0 if length_frames is None else ar1_coefficient(length_frames)
    for _ in range(noise_rounds if learn_noise else 1):
        start = np.maximum(gamma, 1e-2 * gamma0)  # warm, a pruned muscle lifted so that it may come back
        gamma, n = _fit_gamma(_factor_information(I / s2), Y, every, rho, start, iterations, rtol)
        its += n
        if not learn_noise:
            break
        new = _noise_update(I, Y, rho, gamma, s2, residual_m2, dof)
        done = abs(new - s2) < 1e-3 * s2
        s2 = new
        if done:
            break
    if length_frames is None:
        Ls = _factor_information(I / s2)
        scores = choose_length(Ls, Y, gamma0, lengths, iterations=iterations, rtol=rtol)
        length_frames = max(scores, key=lambda k: (scores[k], -k))
        gamma, n = _fit_gamma(Ls, Y, every, ar1_coefficient(length_frames), gamma0, iterations, rtol)
        its += n
    return UsageFit(gamma, float(length_frames), float(s2), scores, its)


def choose_length(Ls, Y, gamma0, lengths, *, iterations: int = 300, rtol: float = 1e-3) -> dict:
    """length -> mean held-out log predictive likelihood per frame (nats), 5 interleaved folds of frames
    (frame t in fold t mod 5): gamma fitted on the other folds, the held-out frames predicted by the
    smoother from them. With fewer than 5 frames, leave-one-frame-out."""
    F, M = Y.shape
    folds = min(_FOLDS, F)
    out = {}
    for length in lengths:
        rho = ar1_coefficient(length)
        full, _ = _fit_gamma(Ls, Y, np.ones(F, bool), rho, gamma0, iterations, rtol)
        start = np.maximum(full, 1e-2 * gamma0)  # each fold starts near the whole take's fit
        total, count = 0.0, 0
        for k in range(folds):
            held = (np.arange(F) % folds) == k
            if held.all() or not held.any():
                continue
            gamma, _ = _fit_gamma(Ls, Y, ~held, rho, start, iterations, rtol)
            Lw, zs = _whitened(Ls, Y, gamma)
            sm = _smooth_white(Lw, zs, ~held, rho, M)
            for t in np.flatnonzero(held):
                L = Lw[t]
                if not L.shape[1]:
                    continue
                S = L.T @ sm.cov[t] @ L + np.eye(L.shape[1])
                e = zs[t] - L.T @ sm.mean[t]
                cS = np.linalg.cholesky(S)
                sol = np.linalg.solve(cS, e)
                total += -0.5 * (sol @ sol) - np.log(np.diag(cS)).sum() - 0.5 * len(e) * np.log(2 * np.pi)
                count += 1
        out[float(length)] = total / max(count, 1)
    return out


def frame_priors(activations, informations, fit: UsageFit) -> tuple[np.ndarray, np.ndarray]:
    """(means (F, M), precisions (F, M, M), unit^-2): each frame's cavity prior, the posterior of a_t
    from every other frame's measurement under ``fit`` (for length 0: N(0, diag(gamma)) for every frame).
    The tracking objective's weight is sigma^2 times the precision."""
    Y = np.asarray(activations, dtype=np.float64)
    P = np.asarray(informations, dtype=np.float64) / max(fit.noise_var_m2, 1e-30)
    F, M = Y.shape
    gamma = np.maximum(fit.gamma, _FLOOR)
    g = np.sqrt(gamma)
    Ls = _factor_information(P)
    Lw, zs = _whitened(Ls, Y, gamma)
    sm = _smooth_white(Lw, zs, np.ones(F, bool), fit.rho, M)
    means = np.zeros((F, M))
    precisions = np.zeros((F, M, M))
    for t in range(F):
        post_info = np.linalg.inv(sm.cov[t])
        Pw = Lw[t] @ Lw[t].T
        cav_info = post_info - Pw  # whitened: the other frames and the prior
        cav_info = 0.5 * (cav_info + cav_info.T)
        w, V = np.linalg.eigh(cav_info)
        cav_info = (V * np.maximum(w, 1e-9)) @ V.T  # round-off can leave it slightly indefinite
        h = post_info @ sm.mean[t] - Lw[t] @ zs[t]
        means[t] = g * np.linalg.solve(cav_info, h)
        precisions[t] = cav_info / g[:, None] / g[None, :]
    return means, precisions
