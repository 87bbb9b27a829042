"""The near-constant-velocity Kalman filter of section 6.7 (Eq. 16-18), two ways.

* :func:`reference_filter` builds a filterpy ``KalmanFilter``: the reference.
* :func:`predict_means`, :func:`innovation` and :func:`update_means` are the
  fast path the builder uses:
  P̂, S and the gain K depend only on the parent state, not on the observation,
  so one predict and one gain serve every candidate detection and only the
  means differ (x_j = x̂ + K(z_j − Hx̂), Eq. 2-3). The covariance update uses the
  Joseph form, as filterpy does, so both agree to rounding
  (tests/test_tracking.py checks 1e-9).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from filterpy.common import Q_continuous_white_noise
from filterpy.kalman import KalmanFilter

from lesmc.tracking.scene import TrackerConfig

H_POS = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])
"""Measurement matrix of Eq. 18: the detector observes the position."""


@dataclass(frozen=True)
class Matrices:
    """F, Q, H, R and P0 of one tracker configuration (Eq. 16-18)."""

    F: np.ndarray
    Q: np.ndarray
    H: np.ndarray
    R: np.ndarray
    P0: np.ndarray


def matrices(cfg: TrackerConfig, dt: float) -> Matrices:
    """Eq. 16 (F), Eq. 17 (Q = σ_q² · continuous white-noise acceleration), Eq. 18 (H, R)."""
    F = np.eye(4)
    F[0, 2] = F[1, 3] = dt
    Q = Q_continuous_white_noise(
        dim=2, dt=dt, spectral_density=cfg.sigma_q**2, block_size=2, order_by_dim=False
    )
    R = np.eye(2) * cfg.sigma_r**2
    P0 = np.diag(np.square(np.asarray(cfg.P0_sd, dtype=float)))
    return Matrices(F, np.asarray(Q, dtype=float), H_POS.copy(), R, P0)


def reference_filter(m: Matrices, x0: np.ndarray, P: np.ndarray | None = None) -> KalmanFilter:
    """A filterpy KalmanFilter in the given state (the reference implementation)."""
    kf = KalmanFilter(dim_x=4, dim_z=2)
    kf.F, kf.Q, kf.H, kf.R = m.F.copy(), m.Q.copy(), m.H.copy(), m.R.copy()
    kf.x = np.asarray(x0, dtype=float).reshape(4, 1).copy()
    kf.P = (m.P0 if P is None else P).copy()
    return kf


def warp(Hm: np.ndarray | None, xy: np.ndarray) -> np.ndarray:
    """Carry positions (…, 2) into the next frame's coordinates with a homography."""
    if Hm is None:
        return xy
    pts = np.asarray(xy, dtype=float).reshape(-1, 2)
    hom = np.c_[pts, np.ones(len(pts))] @ Hm.T
    out: np.ndarray = (hom[:, :2] / hom[:, 2:3]).reshape(np.shape(xy))
    return out


def predict(m: Matrices, x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 2: x̂ = F x, P̂ = F P Fᵀ + Q."""
    return predict_means(x, m.F[0, 2]), m.F @ P @ m.F.T + m.Q


@dataclass(frozen=True)
class Innovation:
    """What every candidate observation of one predicted state shares: S, S⁻¹, K, P⁺."""

    S: np.ndarray
    S_inv: np.ndarray
    K: np.ndarray
    P_post: np.ndarray


def innovation(m: Matrices, P_pred: np.ndarray) -> Innovation:
    """Eq. 3: S = H P̂ Hᵀ + R, K = P̂ Hᵀ S⁻¹; P⁺ in Joseph form (I−KH)P̂(I−KH)ᵀ + K R Kᵀ."""
    S = m.H @ P_pred @ m.H.T + m.R
    S_inv = np.linalg.inv(S)
    K = P_pred @ m.H.T @ S_inv
    I_KH = np.eye(4) - K @ m.H
    P_post = I_KH @ P_pred @ I_KH.T + K @ m.R @ K.T
    return Innovation(S, S_inv, K, P_post)


def predict_means(X: np.ndarray, dt: float) -> np.ndarray:
    """x̂ = F x for one state (4,) or many (n, 4), written out elementwise.

    Elementwise rather than a matrix product so the result does not depend on
    how many states are predicted together (BLAS kernels may round differently).
    """
    out = np.array(X, dtype=float, copy=True)
    out[..., :2] = X[..., :2] + dt * X[..., 2:]
    return out


def update_means(X_pred: np.ndarray, K: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """Eq. 2: x = x̂ + K (z − H x̂), row by row (elementwise, batch-size independent)."""
    y = Z - X_pred[..., :2]
    out: np.ndarray = X_pred + y[..., 0:1] * K[:, 0] + y[..., 1:2] * K[:, 1]
    return out


def mahalanobis2(y: np.ndarray, S_inv: np.ndarray) -> np.ndarray:
    """yᵀ S⁻¹ y for rows of y (n, 2), elementwise."""
    a, b, d = S_inv[0, 0], S_inv[0, 1] + S_inv[1, 0], S_inv[1, 1]
    out: np.ndarray = a * y[..., 0] ** 2 + b * y[..., 0] * y[..., 1] + d * y[..., 1] ** 2
    return out
