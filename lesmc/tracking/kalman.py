"""The tracker's Kalman filter: the paper's near-constant-velocity model (section 6.7,
Eq. 16-18), a constant-acceleration preset, or the matrices a scene declares.

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

from collections.abc import Iterable
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from lesmc.scene import TrackerConfig
from lesmc.scene.frames import warp as warp  # re-exported: the tracker carries states with it
from lesmc.scene.tracker_model import EntryFault, measured, preset_R, state_names, velocity

H_POS = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])
"""Measurement matrix of Eq. 18: the detector observes the position."""


@dataclass(frozen=True)
class Matrices:
    """F, Q, H, R and P0 of one tracker configuration (Eq. 1-3; the paper's are Eq. 16-18).

    ``state`` names the d components; ``pos`` is the pair H measures (the track's
    position, lesmc/scene/tracker_model.py); ``vel`` the pair named vx, vy, if any.
    """

    F: np.ndarray
    Q: np.ndarray
    H: np.ndarray
    R: np.ndarray
    P0: np.ndarray
    state: tuple[str, ...] = ("x", "y", "vx", "vy")
    pos: tuple[int, int] = (0, 1)
    vel: tuple[int, int] | None = (2, 3)

    @property
    def dim(self) -> int:
        return int(self.F.shape[0])

    @cached_property
    def selects(self) -> bool:
        """H's rows are the unit rows of ``pos``: H x is a copy of the position (every
        model but one whose H a fault changed, lesmc/scene/tracker_model.py)."""
        unit = np.zeros_like(self.H)
        unit[0, self.pos[0]] = unit[1, self.pos[1]] = 1.0
        return bool(np.array_equal(self.H, unit))

    @cached_property
    def f_columns(self) -> tuple[tuple[int, np.ndarray | None, np.ndarray], ...]:
        """Per column j of F with a non-zero: (j, the rows it reaches or None for all of
        them, those entries), for :func:`predict_means` (computed once, not per batch)."""
        out: list[tuple[int, np.ndarray | None, np.ndarray]] = []
        for j in range(self.dim):
            rows = np.flatnonzero(self.F[:, j])
            if rows.size == self.dim:
                out.append((j, None, self.F[:, j].copy()))
            elif rows.size:
                out.append((j, rows, self.F[rows, j].copy()))
        return tuple(out)


def matrices(cfg: TrackerConfig, dt: float) -> Matrices:
    """The model's matrices: a preset's from its parameters, or the declared ones."""
    model = cfg.model
    if isinstance(model, str):
        F, Q, H = (cv2d if model == "cv2d" else ca2d)(dt, cfg.sigma_q**2)
        R = preset_R(cfg.sigma_r)
        P0 = np.diag(np.square(np.asarray(cfg.P0_sd, dtype=float)))
    else:
        F, H, Q, R, P0 = (model.matrix(name) for name in ("F", "H", "Q", "R", "P0"))
    return Matrices(F, Q, H, R, P0, state_names(model), measured(model), velocity(model))


def with_faults(m: Matrices, faults: Iterable[EntryFault]) -> Matrices:
    """``m`` with the entries of ``faults`` failed (section 9.2: "missing or perturbed
    values in the matrices F, H, Q and R")."""
    mats = {"F": m.F.copy(), "H": m.H.copy(), "Q": m.Q.copy(), "R": m.R.copy()}
    for f in faults:
        f.apply(mats[f.matrix])
    return replace(m, F=mats["F"], H=mats["H"], Q=mats["Q"], R=mats["R"])


def cv2d(dt: float, q: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eq. 16 (F), Eq. 17 (Q = σ_q² · continuous white-noise acceleration), Eq. 18 (H)."""
    F = np.eye(4)
    F[0, 2] = F[1, 3] = dt
    return F, white_noise_q(dt, q), H_POS.copy()


def ca2d(dt: float, q: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Constant acceleration, state (x, y, vx, vy, ax, ay): per axis F = [[1, dt, dt²/2],
    [0, 1, dt], [0, 0, 1]] and Q = σ_q² · continuous white-noise jerk (what filterpy's
    ``Q_continuous_white_noise(dim=3, dt, σ_q², block_size=2, order_by_dim=False)``
    returns); H measures x, y."""
    f = np.array([[1.0, dt, dt * dt / 2.0], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    qb = np.array(
        [
            [dt**5 / 20.0, dt**4 / 8.0, dt**3 / 6.0],
            [dt**4 / 8.0, dt**3 / 3.0, dt**2 / 2.0],
            [dt**3 / 6.0, dt**2 / 2.0, dt],
        ]
    )
    H = np.zeros((2, 6))
    H[0, 0] = H[1, 1] = 1.0
    return np.kron(f, np.eye(2)), np.kron(qb, np.eye(2)) * q, H


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


def initial_mean(m: Matrices, start: tuple[float, float], vel: tuple[float, float]) -> np.ndarray:
    """A track's first mean (d,): the position at the measured components, the velocity at
    vx, vy (the scene loader refuses a non-zero velocity without them), zeros elsewhere."""
    x0 = np.zeros(m.dim)
    x0[list(m.pos)] = start
    if m.vel is not None:
        x0[list(m.vel)] = vel
    return x0


def predict(m: Matrices, x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 2: x̂ = F x, P̂ = F P Fᵀ + Q."""
    return predict_means(m, x), predict_covariances(m, P[None])[0]


def predict_covariances(m: Matrices, P: np.ndarray) -> np.ndarray:
    """Eq. 2 for a stack of covariances (k, d, d): P̂ = F P Fᵀ + Q.

    A stacked matrix product multiplies each covariance on its own (one small
    product per matrix of the stack), so a covariance predicted alone or in a batch
    gives the same bits (states are shared by their covariance's exact value;
    tests/test_tracking.py).
    """
    out: np.ndarray = m.F @ P @ m.F.T + m.Q
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
    """Eq. 3 for one predicted covariance (d, d): :func:`innovations` of a stack of one."""
    inn = innovations(m, P_pred[None])
    return Innovation(inn.S[0], inn.S_inv[0], inn.K[0], inn.P_post[0])


def innovations(m: Matrices, P_pred: np.ndarray) -> Innovation:
    """Eq. 3 for a stack of predicted covariances (k, d, d).

    S = H P̂ Hᵀ + R, S⁻¹ (closed form of a 2×2 inverse; LAPACK's per matrix for a
    larger measurement), K = P̂ Hᵀ S⁻¹, and P⁺
    in Joseph form (I−KH)P̂(I−KH)ᵀ + K R Kᵀ. Stacked matrix products (one per
    matrix of the stack), so that each result is the same whether computed alone
    or in a batch.
    """
    S = m.H @ P_pred @ m.H.T + m.R
    if S.shape[-1] == 2:
        a, b, c, d = S[:, 0, 0], S[:, 0, 1], S[:, 1, 0], S[:, 1, 1]
        det = a * d - b * c
        S_inv = np.empty_like(S)
        S_inv[:, 0, 0] = d / det
        S_inv[:, 0, 1] = -b / det
        S_inv[:, 1, 0] = -c / det
        S_inv[:, 1, 1] = a / det
    else:  # a box tracker's measurement (cx, cy, s, r): one LAPACK inverse per matrix
        S_inv = np.linalg.inv(S)
    K = P_pred @ m.H.T @ S_inv
    I_KH = np.eye(P_pred.shape[-1]) - K @ m.H
    P_post = I_KH @ P_pred @ I_KH.transpose(0, 2, 1) + K @ m.R @ K.transpose(0, 2, 1)
    return Innovation(S, S_inv, K, P_post)


def predict_means(m: Matrices, X: np.ndarray) -> np.ndarray:
    """x̂ = F x for one state (d,) or many (n, d), summed column by column.

    Not a matrix product: BLAS kernels round differently with the number of
    states, and a state must not depend on which others were predicted with it.
    The columns are summed in order and exact zeros of F are skipped, so for the
    paper's F each x̂ is x + dt·vx bit for bit.
    """
    X = np.asarray(X, dtype=float)
    out = np.zeros(X.shape)
    for j, rows, f in m.f_columns:
        if rows is None:
            out += X[..., j : j + 1] * f
        else:
            out[..., rows] += X[..., j : j + 1] * f
    return out


def positions(m: Matrices, X: np.ndarray) -> np.ndarray:
    """H x for states (..., d): the measured components (..., 2), copied exactly."""
    return X[..., list(m.pos)]


def measure(m: Matrices, X: np.ndarray) -> np.ndarray:
    """H x for states (..., d): the predicted measurement (..., 2; a box tracker's (..., 4)).
    A copy of the position when H selects it (:attr:`Matrices.selects`), else summed term by
    term in column order (elementwise: a state's value does not depend on the batch)."""
    if m.selects:
        return positions(m, X)
    out = np.zeros((*X.shape[:-1], m.H.shape[0]))
    for j in range(m.dim):
        out += X[..., j : j + 1] * m.H[:, j]
    return out


def update_means(m: Matrices, X_pred: np.ndarray, K: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """Eq. 2: x = x̂ + K (z − H x̂), row by row (elementwise, batch-size independent).

    ``K`` is one gain (d, m) for every row, or one per row (n, d, m); m = 2 for a point
    tracker (a box tracker's is 4), the terms summed in order.
    """
    y = Z - measure(m, X_pred)
    out: np.ndarray = X_pred + y[..., 0:1] * K[..., 0]
    for i in range(1, y.shape[-1]):
        out = out + y[..., i : i + 1] * K[..., i]
    return out


def position_spread(m: Matrices, P: np.ndarray) -> np.ndarray:
    """trace(H P Hᵀ) of covariances (..., d, d): the measured components' variances summed
    (P₀₀ + P₁₁ for the paper's model); the Euclidean gate's scale."""
    if not m.selects:
        out_h: np.ndarray = np.trace(m.H @ P @ m.H.T, axis1=-2, axis2=-1)
        return out_h
    i, j = m.pos
    out: np.ndarray = P[..., i, i] + P[..., j, j]
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


#: The state of a box tracker (Bewley et al., SORT, 2016): the box's centre, its area
#: s = w·h and aspect ratio r = w/h, and the velocities of the centre and of the area.
BOX_STATE = ("cx", "cy", "s", "r", "vcx", "vcy", "vs")


def sort_box() -> Matrices:
    """SORT's constant-velocity box model, as its ``KalmanBoxTracker`` sets filterpy's
    defaults (identities) up: F adds each velocity to its component, H measures
    (cx, cy, s, r), R = diag(1, 1, 10, 10), P0 = diag(10, 10, 10, 10, 10⁴, 10⁴, 10⁴),
    Q = diag(1, 1, 1, 1, 0.01, 0.01, 10⁻⁴) (the same products of the same numbers)."""
    F = np.eye(7)
    F[0, 4] = F[1, 5] = F[2, 6] = 1.0
    H = np.eye(4, 7)
    R = np.eye(4)
    R[2:, 2:] *= 10.0
    P0 = np.eye(7)
    P0[4:, 4:] *= 1000.0
    P0 *= 10.0
    Q = np.eye(7)
    Q[-1, -1] *= 0.01
    Q[4:, 4:] *= 0.01
    return Matrices(F, Q, H, R, P0, BOX_STATE, (0, 1), (4, 5))
