"""What the attacker does on a path of a model whose tracker keeps whole states (joint).

A model of the joint design stores only each state's primary estimate and covariance; the
whole joint state (refining tracks, pending detections) is the one the tracker reaches on
any path from the initial state, since the unfolder merges states by that whole state
(lesmc/unfold/unfold.py ``add``). :func:`walked_attack_of` rebuilds it by re-running the
tracker along one such path, outcome rank by outcome rank, and asks the tracker's
``attack_in`` which detections the cheapest way to an outcome hides and which candidates
it injects (lesmc/results/document.py lists them for a counterexample).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from lesmc.model.arrays import ArrayModel
from lesmc.tracking.design import Batch, Design


def predecessors(model: ArrayModel) -> np.ndarray:
    """(n,) for each state one transition into it (−1: the initial state or unreached)."""
    n = len(model.step)
    into = np.full(n, -1, dtype=np.int64)
    t = np.arange(len(model.dst), dtype=np.int64)
    into[model.dst[::-1]] = t[::-1]  # the first transition into each state
    into[0] = -1
    return into


def path_to(model: ArrayModel, into: np.ndarray, q: int) -> list[int]:
    """The transitions of one path from the initial state to ``q``, in order."""
    src = np.repeat(np.arange(len(model.ptr) - 1), np.diff(model.ptr))
    out: list[int] = []
    while q != 0:
        t = int(into[q])
        if t < 0:
            raise ValueError(f"state {q} is not reached from the initial state")
        out.append(t)
        q = int(src[t])
    return out[::-1]


def walk(design: Design, model: ArrayModel, path: list[int]) -> Batch:
    """The tracker's whole state after the transitions ``path`` from the initial state:
    at step k the outcome of the transition's rank (the model's window says which steps
    are attacked)."""
    lo, hi = (int(v) for v in model.meta["window"])
    first = int(model.meta.get("first_frame", 0))
    batch = design.initial()
    for k, t in enumerate(path, start=1):
        succ = design.successors(batch, first + k, lo <= k <= hi)
        i = np.flatnonzero(succ.rank == model.rank[t])
        if not i.size:
            raise AssertionError(f"step {k}: the tracker has no outcome of rank {model.rank[t]}")
        batch = succ.states.take(i[:1])
    return batch


def walked_attack_of(
    design: Any, model: ArrayModel
) -> Callable[[int, int, int], tuple[list[str], list[str]]]:
    """(state, step, rank) -> the ids of the detections hidden and of the candidates
    injected by the cheapest way to the outcome of that rank from model state ``state``
    (at step ``step``), from the tracker's ``attack_in`` on the whole state walked to."""
    into = predecessors(model)
    first = int(model.meta.get("first_frame", 0))
    seen: dict[int, Batch] = {}

    def of(q: int, k: int, rank: int) -> tuple[list[str], list[str]]:
        if q not in seen:
            seen[q] = walk(design, model, path_to(model, into, q))
        got: tuple[list[str], list[str]] = design.attack_in(seen[q], first + k, rank)
        return got

    return of
