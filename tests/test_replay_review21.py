"""The review of round 21's findings in lesmc/replay/ (each test fails on the code before)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from lesmc.replay.joint_forcing import forcing_costs


def _eq5_by_hand(src: list[int], rank: list[int], payoff: list[float]) -> list[float]:
    """Eq. 5 outcome by outcome: the sum of the payoffs of the same source's strictly
    lower ranks (an independent loop, no cumulative sums)."""
    out = []
    for s, r in zip(src, rank, strict=True):
        lower = [p for s2, r2, p in zip(src, rank, payoff, strict=True) if s2 == s and r2 < r]
        out.append(math.inf if any(math.isinf(p) for p in lower) else math.fsum(lower))
    return out


def _succ(src: list[int], rank: list[int], payoff: list[float]) -> SimpleNamespace:
    return SimpleNamespace(
        src=np.array(src, dtype=np.int64),
        rank=np.array(rank, dtype=np.int64),
        payoff=np.array(payoff, dtype=float),
    )


def test_forcing_costs_with_an_infinite_payoff_is_not_nan() -> None:
    src, rank = [0, 0, 0, 1, 1, 1], [0, 1, 2, 0, 1, 2]
    payoff = [0.3, math.inf, 0.7, 0.2, 0.5, 0.1]
    got = forcing_costs(_succ(src, rank, payoff))  # type: ignore[arg-type]
    assert not np.isnan(got).any()
    assert got.tolist() == [0.0, 0.3, math.inf, 0.0, 0.2, 0.7]
    assert got.tolist() == _eq5_by_hand(src, rank, payoff)


def test_forcing_costs_unsorted_ties_and_a_source_without_outcomes() -> None:
    # source 1 has none; source 2's outcomes come out of order; ranks 1 tie (share a sum)
    src, rank = [2, 0, 2, 2, 0, 3], [1, 0, 0, 1, 1, 0]
    payoff = [0.25, 0.5, 0.125, 4.0, math.inf, 1.0]
    got = forcing_costs(_succ(src, rank, payoff))  # type: ignore[arg-type]
    assert got.tolist() == _eq5_by_hand(src, rank, payoff)
