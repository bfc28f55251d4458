"""A temporal prior on the activations whose strength the data choose (docs/design.md, "Tracking").

The tracker's per-frame estimate is a Gaussian measurement of the activations: with marker noise
of variance sigma^2 per coordinate, -log p(markers | c) = phi(c) / (2 sigma^2), so near the
solution the activations carry the information I_a / (2 sigma^2), where I_a is the Schur
complement of the Gauss-Newton Hessian 2 J^T W J over the bones' nine rigid degrees of freedom
(cranium rotation and translation, the jaw's opening, protrusion and yaw): what the markers say
about the muscles once head and jaw motion are allowed to explain what they can.

Between frames the activations follow a random walk, a_t = a_{t-1} + w_t with w_t ~ N(0, Q),
Q = diag(q_i^2): a Kalman filter in activation space (Kalman 1960). Frame t is estimated with the
prior N(a_{t-1}, P_{t-1} + Q), i.e. the term (a - a_{t-1})^T Lambda (a - a_{t-1}) added to phi with

    Lambda = sigma^2 (P_{t-1} + Q)^-1                     (m^2 per unit^2)
    P_t^-1 = I_a / (2 sigma^2) + (P_{t-1} + Q)^-1          (the posterior, unit^-2)

Both variances come from the take itself, so nothing is tuned per capture:

- sigma^2, the marker noise: the robustly weighted residual pooled over the frames so far,
  sum_t sum_k w_k |r_k|^2 / sum_t (sum_k 3 w_k - p_t), with p_t = tr(I_a,t P_t) / (2 sigma^2) + 9 the
  effective number of fitted controls (residual degrees of freedom, as in ordinary least squares);
- Q, the activation change per frame: covariance matching on the filter's corrections
  (Myers & Tapley 1976): q_i^2 = (sum_t d_t,i^2 + n0 q_0^2) / (n_t + n0) with d_t = a_t - a_{t-1}, shrunk
  toward q_0 = 1 (no prior) by n0 = 1 pseudo-frame, so the first frames are barely regularised and
  a muscle the performance moves keeps a weak prior while one it leaves alone is held.

The first frame of a take (or of a chunk without warm-up) has no prior. ``TemporalPrior`` is the
filter's state; ``to_arrays`` / ``from_arrays`` store it in each frame file, so ``--resume``
continues bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wface.tracking.identifiability import bone_motion_basis

__all__ = [
    "GaussianPrior",
    "TemporalPrior",
    "activation_information",
    "activation_measurement",
]

_Q0 = 1.0  # prior guess of the activation change per frame (unit): the whole range, i.e. no prior
_N0 = 1.0  # pseudo-frames of that guess


@dataclass
class GaussianPrior:
    """The term (a - mean)^T weight (a - mean) (m^2) of the tracking objective."""

    mean: np.ndarray  # (M,) activations
    weight: np.ndarray  # (M, M) symmetric positive semi-definite, m^2 per unit^2
    held: np.ndarray | None = None  # (M,) bool: muscles held at rest (a usage fit's variance at its floor),
    # whose Jacobian columns the tracker need not solve (``FaceRig.linearize``)


def activation_information(joint, controls: np.ndarray, data_hessian: np.ndarray, n_muscles: int) -> np.ndarray:
    """(M, M) I_a: the Schur complement of a Gauss-Newton Hessian over the controls (M + 24) onto the
    activations, the bones moving rigidly (``wface.tracking.identifiability.bone_motion_basis``)."""
    M = n_muscles
    B = bone_motion_basis(joint, np.asarray(controls[M:], dtype=np.float64))
    H = 0.5 * (data_hessian + data_hessian.T)
    Haa = H[:M, :M]
    Hab = H[:M, M:] @ B
    Hbb = B.T @ H[M:, M:] @ B
    info = Haa - Hab @ np.linalg.pinv(Hbb, rcond=1e-12, hermitian=True) @ Hab.T
    w, V = np.linalg.eigh(0.5 * (info + info.T))
    return (V * np.maximum(w, 0.0)) @ V.T


def activation_measurement(joint, system: dict, n_muscles: int) -> tuple[np.ndarray, np.ndarray] | None:
    """(I (M, M), h (M,)): what a frame's markers alone say about its activations, the Gauss-Newton model
    of the data term phi(c + dc) ~ phi + g^T dc + dc^T (J^T W J) dc at the controls c where its last
    system was formed (``FrameResult.system``: data_hessian = 2 J^T W J, data_gradient g = 2 J^T W r,
    data_at = c), minimised over the bones' rigid motion: I = J^T W J's Schur complement onto the
    activations (``activation_information`` / 2) and h = I a_c - g_red / 2, so that the data term's
    own minimiser z solves I z = h, whatever prior and bounds the frame was estimated under. None
    when the frame had no Gauss-Newton system."""
    if "data_gradient" not in system or "data_hessian" not in system:
        return None
    M = n_muscles
    c = np.asarray(system["data_at"], dtype=np.float64)
    B = bone_motion_basis(joint, c[M:])
    H = 0.5 * (system["data_hessian"] + system["data_hessian"].T)
    g = np.asarray(system["data_gradient"], dtype=np.float64)
    Hab = H[:M, M:] @ B
    Hbb_inv = np.linalg.pinv(B.T @ H[M:, M:] @ B, rcond=1e-12, hermitian=True)
    info = 0.5 * activation_information(joint, c, H, M)
    g_red = g[:M] - Hab @ Hbb_inv @ (B.T @ g[M:])
    return info, info @ c[:M] - 0.5 * g_red


class TemporalPrior:
    """The Kalman-style temporal prior's state over a take (see module docstring)."""

    def __init__(self, n_muscles: int):
        M = int(n_muscles)
        self.mean: np.ndarray | None = None  # (M,) last frame's activations
        self.cov = np.zeros((M, M))  # (M, M) their posterior covariance (unit^2)
        self.rss_m2 = 0.0  # pooled weighted squared residual
        self.dof = 0.0  # pooled residual degrees of freedom
        self.change_sq = np.zeros(M)  # sum of squared frame-to-frame corrections
        self.changes = 0  # how many
        self.last_information: np.ndarray | None = None

    @property
    def n_muscles(self) -> int:
        return len(self.change_sq)

    @property
    def noise_var_m2(self) -> float | None:
        """sigma^2: marker noise variance per coordinate (m^2) pooled over the frames seen; None before."""
        return self.rss_m2 / self.dof if self.dof > 0 else None

    @property
    def process_var(self) -> np.ndarray:
        """q_i^2: expected squared activation change per frame, per muscle (unit^2)."""
        return (self.change_sq + _N0 * _Q0**2) / (self.changes + _N0)

    def _predicted_cov(self) -> np.ndarray:
        return self.cov + np.diag(self.process_var)

    def prior(self) -> GaussianPrior | None:
        """The prior for the next frame, or None at the start of a take."""
        sigma2 = self.noise_var_m2
        if self.mean is None or sigma2 is None:
            return None
        weight = sigma2 * np.linalg.inv(self._predicted_cov())
        return GaussianPrior(self.mean.copy(), 0.5 * (weight + weight.T))

    def update(self, joint, result) -> None:
        """Take in a frame's estimate (a ``wface.tracking.estimator.FrameResult``)."""
        M = self.n_muscles
        a = np.asarray(result.controls[:M], dtype=np.float64)
        system = result.system
        pred_cov = self._predicted_cov() if self.mean is not None else None
        info_prior = np.linalg.inv(pred_cov) if pred_cov is not None else np.zeros((M, M))
        info_data = None
        if "data_hessian" in system:
            info_data = activation_information(joint, result.controls, system["data_hessian"], M)
        self.last_information = info_data  # I_a of this frame (m^2 per unit^2), kept for the usage prior
        # pooled noise: the residual with its degrees of freedom
        sigma2 = self.noise_var_m2
        if info_data is not None:
            first_guess = system["weighted_rss_m2"] / max(system["weighted_count"] - M - 9, 1.0)
            s2 = sigma2 if sigma2 is not None else first_guess
            post_info = info_data / (2.0 * s2) + info_prior
            post_cov = np.linalg.pinv(post_info, hermitian=True)
            p_eff = float(np.trace(info_data / (2.0 * s2) @ post_cov)) + 9.0
            self.rss_m2 += float(system["weighted_rss_m2"])
            self.dof += max(float(system["weighted_count"]) - p_eff, 1.0)
            sigma2 = self.noise_var_m2
            post_info = info_data / (2.0 * sigma2) + info_prior
            self.cov = np.linalg.pinv(post_info, hermitian=True)
        elif pred_cov is not None:
            self.cov = pred_cov  # no measurement (a carried frame): the prediction stands
        else:
            self.cov = np.diag(np.full(M, _Q0**2))
        if self.mean is not None:
            self.change_sq += (a - self.mean) ** 2
            self.changes += 1
        self.mean = a.copy()

    def predict_only(self) -> None:
        """A frame without a measurement (carried): the activations are held, their uncertainty grows."""
        if self.mean is not None:
            self.cov = self._predicted_cov()

    # ------------------------------------------------------------------ frame files
    def to_arrays(self) -> dict[str, np.ndarray]:
        """The state as arrays (for a frame file); ``from_arrays`` restores it exactly."""
        if self.mean is None:
            return {}
        return {
            "prior_mean": self.mean,
            "prior_cov": self.cov,
            "prior_noise": np.array([self.rss_m2, self.dof]),
            "prior_change_sq": self.change_sq,
            "prior_changes": np.array(self.changes),
        }

    @classmethod
    def from_arrays(cls, n_muscles: int, arrays: dict) -> TemporalPrior:
        """The state stored by ``to_arrays`` (a fresh prior when the arrays are absent)."""
        out = cls(n_muscles)
        if "prior_mean" in arrays and len(arrays["prior_mean"]) == n_muscles:
            out.mean = np.array(arrays["prior_mean"], dtype=np.float64)
            out.cov = np.array(arrays["prior_cov"], dtype=np.float64)
            out.rss_m2, out.dof = (float(v) for v in arrays["prior_noise"])
            out.change_sq = np.array(arrays["prior_change_sq"], dtype=np.float64)
            out.changes = int(arrays["prior_changes"])
        return out
