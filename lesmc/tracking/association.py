"""The gate of gated association (Eq. 11, 19): which innovations pass it, and how far from
the prediction a detection that passes can lie.

The point trackers' hypothesiser (lesmc/tracking/parts/hypothesiser.py,
:class:`~lesmc.tracking.parts.hypothesiser.GateHypothesiser`) applies it; what an
attacker can make of it is the attacker's options part (lesmc/tracking/parts/attacker.py).
"""

from __future__ import annotations

import numpy as np

from lesmc.tracking.kalman import Innovation, mahalanobis2


def gate_mask(
    y: np.ndarray, inn: Innovation, spread: float, gate: float, gate_type: str
) -> np.ndarray:
    """Which innovations y (n, 2) of one predicted state pass the gate (:func:`gate_test`)."""
    return gate_test(y, inn.S_inv, np.asarray(spread), gate, gate_type)


def gate_test(
    y: np.ndarray, S_inv: np.ndarray, spread: np.ndarray, gate: float, gate_type: str
) -> np.ndarray:
    """Which innovations y (..., 2) pass the gate; ``S_inv`` (2, 2) and ``spread`` (a number)
    serve every row, or (n, 2, 2) and (n,) one leading row of y each.

    ``spread`` is trace(H P̂ Hᵀ) (kalman.position_spread: P̂₀₀ + P̂₁₁ for the paper's
    model). ``mahalanobis`` (paper Eq. 19): sqrt(yᵀ S⁻¹ y) ≤ g. ``euclidean`` (the
    paper's public code): ‖y‖ ≤ k · sqrt(spread).
    """
    if gate_type == "euclidean":
        radius = gate * np.sqrt(spread)
        radius = np.reshape(radius, np.shape(radius) + (1,) * (y.ndim - 1 - np.ndim(radius)))
        out: np.ndarray = y[..., 0] ** 2 + y[..., 1] ** 2 <= radius * radius
        return out
    return mahalanobis_gate(mahalanobis2(y, S_inv), gate)


def mahalanobis_gate(d2: np.ndarray, gate: float) -> np.ndarray:
    """Eq. 19 from the squared Mahalanobis distances d² = yᵀ S⁻¹ y: sqrt(d²) ≤ g."""
    res: np.ndarray = np.sqrt(np.maximum(d2, 0.0)) <= gate
    return res


def gate_radius(inn: Innovation, spread: float, gate: float, gate_type: str) -> float:
    """No detection farther than this (Euclidean) from the prediction can pass the gate."""
    return float(gate_radii(inn.S[None], np.array([spread]), gate, gate_type)[0])


def gate_radii(S: np.ndarray, spread: np.ndarray, gate: float, gate_type: str) -> np.ndarray:
    """:func:`gate_radius` for stacks S (k, 2, 2) and spreads trace(H P̂ Hᵀ) (k,).

    ``mahalanobis``: g times the square root of S's largest eigenvalue (closed
    form for a symmetric 2×2); ``euclidean``: k · sqrt(spread). The radius
    only preselects candidates for the exact gate test, so it is widened by a
    relative 1e-12 against rounding.
    """
    if gate_type == "euclidean":
        out: np.ndarray = gate * np.sqrt(spread) * (1 + 1e-12)
        return out
    half_trace = 0.5 * (S[:, 0, 0] + S[:, 1, 1])
    half_gap = 0.5 * (S[:, 0, 0] - S[:, 1, 1])
    off = 0.5 * (S[:, 0, 1] + S[:, 1, 0])
    top = half_trace + np.sqrt(half_gap * half_gap + off * off)
    res: np.ndarray = gate * np.sqrt(top) * (1 + 1e-12)
    return res
