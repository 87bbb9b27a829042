"""The near-constant-velocity Kalman filter of section 6.7 (Eq. 16-18).

* The reference is filterpy's ``KalmanFilter`` (a test dependency only:
  ``tests/kf_reference.py`` builds one from :func:`matrices`).
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

from lesmc.scene import TrackerConfig
from lesmc.scene.frames import warp as warp  # re-exported: the tracker carries states with it

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
    Q = white_noise_q(dt, cfg.sigma_q**2)
    R = np.eye(2) * cfg.sigma_r**2
    P0 = np.diag(np.square(np.asarray(cfg.P0_sd, dtype=float)))
    return Matrices(F, Q, H_POS.copy(), R, P0)


def white_noise_q(dt: float, spectral_density: float) -> np.ndarray:
    """Eq. 17: discretised continuous white-noise acceleration for state (x, y, vx, vy).

    Per axis the block is [[dt³/3, dt²/2], [dt²/2, dt]]; x and y are independent,
    so with the state ordered by derivative each entry becomes that value times
    I₂. Bit for bit what filterpy's ``Q_continuous_white_noise(dim=2, dt,
    spectral_density, block_size=2, order_by_dim=False)`` returns (same
    expressions, same operations; tests/test_tracking.py checks it).
    """
    q = np.array([[dt**3 / 3.0, dt**2 / 2.0], [dt**2 / 2.0, dt]], dtype=float)
    out: np.ndarray = np.kron(q, np.eye(2)) * spectral_density
    return out


def predict(m: Matrices, x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 2: x̂ = F x, P̂ = F P Fᵀ + Q."""
    return predict_means(x, m.F[0, 2]), predict_covariances(m, P[None])[0]


def predict_covariances(m: Matrices, P: np.ndarray) -> np.ndarray:
    """Eq. 2 for a stack of covariances (k, 4, 4): P̂ = F P Fᵀ + Q.

    einsum's summation order per entry does not depend on k, so a covariance
    predicted alone or in a batch gives the same bits (states are shared by
    their covariance's exact value).
    """
    out: np.ndarray = np.einsum("ij,njk,lk->nil", m.F, P, m.F) + m.Q
    return out


@dataclass(frozen=True)
class Innovation:
    """What every candidate observation of one predicted state shares: S, S⁻¹, K, P⁺.

    Each field is one matrix, or a stack of them (k, …) from :func:`innovations`.
    """

    S: np.ndarray
    S_inv: np.ndarray
    K: np.ndarray
    P_post: np.ndarray


def innovation(m: Matrices, P_pred: np.ndarray) -> Innovation:
    """Eq. 3 for one predicted covariance (4, 4): :func:`innovations` of a stack of one."""
    inn = innovations(m, P_pred[None])
    return Innovation(inn.S[0], inn.S_inv[0], inn.K[0], inn.P_post[0])


def innovations(m: Matrices, P_pred: np.ndarray) -> Innovation:
    """Eq. 3 for a stack of predicted covariances (k, 4, 4).

    S = H P̂ Hᵀ + R, S⁻¹ (closed form of a 2×2 inverse), K = P̂ Hᵀ S⁻¹, and P⁺
    in Joseph form (I−KH)P̂(I−KH)ᵀ + K R Kᵀ. Written with einsum so that each
    result is the same whether computed alone or in a batch.
    """
    S = np.einsum("ij,njk,lk->nil", m.H, P_pred, m.H) + m.R
    a, b, c, d = S[:, 0, 0], S[:, 0, 1], S[:, 1, 0], S[:, 1, 1]
    det = a * d - b * c
    S_inv = np.empty_like(S)
    S_inv[:, 0, 0] = d / det
    S_inv[:, 0, 1] = -b / det
    S_inv[:, 1, 0] = -c / det
    S_inv[:, 1, 1] = a / det
    K = np.einsum("nij,kj,nkl->nil", P_pred, m.H, S_inv)
    I_KH = np.eye(P_pred.shape[-1]) - np.einsum("nij,jk->nik", K, m.H)
    P_post = np.einsum("nij,njk,nlk->nil", I_KH, P_pred, I_KH) + np.einsum(
        "nij,jk,nlk->nil", K, m.R, K
    )
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
    """Eq. 2: x = x̂ + K (z − H x̂), row by row (elementwise, batch-size independent).

    ``K`` is one gain (4, 2) for every row, or one per row (n, 4, 2).
    """
    y = Z - X_pred[..., :2]
    out: np.ndarray = X_pred + y[..., 0:1] * K[..., 0] + y[..., 1:2] * K[..., 1]
    return out


def mahalanobis2(y: np.ndarray, S_inv: np.ndarray) -> np.ndarray:
    """yᵀ S⁻¹ y for innovations y (..., 2), elementwise.

    ``S_inv`` is one matrix (2, 2), or one per leading row of y (n, 2, 2) for y (n, ..., 2).
    """
    a, b, d = S_inv[..., 0, 0], S_inv[..., 0, 1] + S_inv[..., 1, 0], S_inv[..., 1, 1]
    extra = (1,) * (y.ndim - 1 - np.ndim(a))
    a, b, d = (np.reshape(v, np.shape(v) + extra) for v in (a, b, d))
    out: np.ndarray = a * y[..., 0] ** 2 + b * y[..., 0] * y[..., 1] + d * y[..., 1] ** 2
    return out
