"""Gated nearest-neighbour association (Eq. 11, 19) and what an attacker can make of it.

The tracker takes the visible detection nearest (Euclidean) to the predicted
position and accepts it if it passes the gate; otherwise it skips the update.
An attacker who hides detections (payoff each) chooses the outcome: to make
the tracker take the j-th nearest, hide the j−1 nearer ones. :func:`attack_options`
lists the distinct outcomes in that order, which is the partial order ≺ of the
LTS (rank = position), with per-transition payoffs such that the combined
payoff of Eq. 5 (sum over strictly lower ranks) is exactly the cost of hiding
every nearer detection.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lesmc.tracking.kalman import Innovation, mahalanobis2


def gate_mask(
    y: np.ndarray, inn: Innovation, P_pred: np.ndarray, gate: float, gate_type: str
) -> np.ndarray:
    """Which innovations y (n, 2) pass the gate.

    ``mahalanobis`` (paper Eq. 19): sqrt(yᵀ S⁻¹ y) ≤ g. ``euclidean`` (the paper's
    public code): ‖y‖ ≤ k · sqrt(P̂₀₀ + P̂₁₁).
    """
    if gate_type == "euclidean":
        radius = gate * math.sqrt(P_pred[0, 0] + P_pred[1, 1])
        out: np.ndarray = y[..., 0] ** 2 + y[..., 1] ** 2 <= radius * radius
        return out
    d2 = mahalanobis2(y, inn.S_inv)
    res: np.ndarray = np.sqrt(np.maximum(d2, 0.0)) <= gate
    return res


def gate_radius(inn: Innovation, P_pred: np.ndarray, gate: float, gate_type: str) -> float:
    """No detection farther than this (Euclidean) from the prediction can pass the gate."""
    if gate_type == "euclidean":
        return gate * math.sqrt(P_pred[0, 0] + P_pred[1, 1])
    return gate * math.sqrt(float(np.max(np.linalg.eigvalsh(inn.S))))


@dataclass(frozen=True)
class Option:
    """One outcome the attacker can force: update with ``detection`` (index) or skip (None).

    ``payoff`` is the transition's own payoff in the LTS; the combined payoff of
    the option at rank r is the sum of the payoffs of the options before it.
    """

    detection: int | None
    payoff: float


def attack_options(dist: np.ndarray, gated: np.ndarray, payoffs: np.ndarray) -> list[Option]:
    """The outcomes, nearest first, for detections at distances ``dist`` from the prediction.

    Scanning detections by distance: a gated one is an update outcome (reached by
    hiding all nearer ones); the first non-gated one is the skip outcome (the
    nearest visible detection fails the gate). Later non-gated detections lead to
    the same skip, so their payoffs fold into the previous outcome's payoff, which
    keeps every later combined payoff exact. An unattackable detection (payoff ∞)
    ends the list: nothing beyond it can be reached. Hiding everything skips.
    """
    order = np.argsort(dist, kind="stable")
    options: list[Option] = []
    skip_seen = False
    for i in order:
        p = float(payoffs[i])
        if gated[i]:
            options.append(Option(int(i), p))
        elif not skip_seen:
            options.append(Option(None, p))
            skip_seen = True
        else:
            last = options[-1]
            options[-1] = Option(last.detection, last.payoff + p)
        if not math.isfinite(p):
            break
    else:
        if not skip_seen:
            options.append(Option(None, 0.0))
    if options and not math.isfinite(options[-1].payoff):
        last = options[-1]
        options[-1] = Option(last.detection, 0.0)  # never part of a combined payoff
    return options
