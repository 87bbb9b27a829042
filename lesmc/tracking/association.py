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

from dataclasses import dataclass

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

    One row of :func:`attack_option_rows` (ties in distance go to the lower index).
    """
    order = np.argsort(dist, kind="stable")
    rows = attack_option_rows(
        np.asarray(gated, bool)[order][None, :],
        np.asarray(payoffs, float)[order][None, :],
        np.ones((1, len(order)), dtype=bool),
    )
    return [
        Option(None if c < 0 else int(order[c]), float(p))
        for c, p in zip(rows.col.tolist(), rows.payoff.tolist(), strict=True)
    ]


@dataclass(frozen=True)
class OptionRows:
    """The options of many rows, flattened in (row, rank) order.

    ``col`` is the candidate column the option updates with, −1 for the skip.
    """

    row: np.ndarray
    col: np.ndarray
    payoff: np.ndarray


def attack_option_rows(
    gated: np.ndarray, payoffs: np.ndarray, valid: np.ndarray, same: np.ndarray | None = None
) -> OptionRows:
    """The attacker's options for many predictions at once (g rows of k candidates).

    Each row lists its candidate detections nearest first (``valid`` marks real
    ones). Scanning a row: a gated candidate is an update outcome (reached by
    hiding every nearer one); the first non-gated one is the skip outcome (the
    nearest visible detection fails the gate). Later non-gated candidates lead
    to the same skip, so their payoffs fold into the previous outcome's own
    payoff, which keeps every later combined payoff (Eq. 5) exact. An
    unattackable candidate (payoff ∞) ends the row: nothing beyond it can be
    reached, and the last outcome's own payoff, never part of a combined
    payoff, is 0. Hiding everything skips (own payoff 0).

    ``same`` (g, k), optional, identifies candidates at identical positions: a
    gated one that repeats an earlier outcome's detection leads to the same
    state and is dropped, its own payoff added to the outcome before it (so
    later combined payoffs do not change).

    Payoffs are accumulated column by column, left to right, so every own
    payoff is summed in the order of the scan whatever the batch.
    """
    k = int(gated.shape[1])
    cols = np.arange(k)
    finite = np.isfinite(payoffs)
    bad = valid & ~finite
    included = valid & ((np.cumsum(bad, axis=1) - bad) == 0)
    broke = (included & bad).any(axis=1)
    nongated = included & ~gated
    first_ng = nongated & (np.cumsum(nongated, axis=1) == 1)
    update = included & gated
    produce = update | first_ng
    own = np.where(produce, payoffs, 0.0)
    prev = np.maximum.accumulate(np.where(produce, cols, -1), axis=1)
    fold = included & ~produce
    for j in np.nonzero(fold.any(axis=0))[0]:
        r = np.nonzero(fold[:, j])[0]
        own[r, prev[r, j]] += payoffs[r, j]
    # a row that broke off at an unattackable candidate: its last outcome costs nothing
    last = np.where(produce, cols, -1).max(axis=1, initial=-1)
    rb = np.nonzero(broke)[0]
    own[rb, last[rb]] = 0.0
    if same is not None:
        produce = _drop_repeats(update, produce, own, same)
    return _collect(produce, first_ng, broke, own)


def _drop_repeats(
    update: np.ndarray, produce: np.ndarray, own: np.ndarray, same: np.ndarray
) -> np.ndarray:
    """``produce`` without the gated candidates that repeat an earlier outcome's detection.

    Each dropped candidate's own payoff is added (in place, to ``own``) to the
    outcome before it in its row, so later combined payoffs do not change.
    """
    k = int(update.shape[1])
    cols = np.arange(k)
    dup = np.zeros_like(update)
    for c in range(1, k):
        earlier = update[:, :c] & (same[:, :c] == same[:, c : c + 1])
        dup[:, c] = update[:, c] & earlier.any(axis=1)
    if not dup.any():
        return produce
    for j in np.nonzero(dup.any(axis=0))[0]:
        keep = produce & ~dup
        keep[:, j:] = False
        before = np.where(keep, cols, -1).max(axis=1, initial=-1)
        r = np.nonzero(dup[:, j])[0]
        own[r, before[r]] += own[r, j]
    kept: np.ndarray = produce & ~dup
    return kept


def _collect(
    produce: np.ndarray, first_ng: np.ndarray, broke: np.ndarray, own: np.ndarray
) -> OptionRows:
    """The outcomes as flat rows, in (row, column) order, each row's skip last (column k)."""
    k = int(produce.shape[1])
    r_idx, c_idx = np.nonzero(produce)
    trailing = np.nonzero(~broke & ~first_ng.any(axis=1))[0]
    row = np.concatenate([r_idx, trailing])
    col = np.concatenate([c_idx, np.full(trailing.size, k)])
    order = np.lexsort((col, row))
    row, col = row[order], col[order]
    is_skip = col == k
    skip_col = np.zeros(col.size, dtype=bool)
    skip_col[~is_skip] = first_ng[row[~is_skip], col[~is_skip]]
    pay = np.zeros(col.size)
    pay[~is_skip] = own[row[~is_skip], col[~is_skip]]
    out_col = np.where(is_skip | skip_col, -1, col)
    return OptionRows(row, out_col, pay)
