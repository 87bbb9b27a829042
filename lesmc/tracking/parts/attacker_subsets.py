"""The attacker's options for multi-target trackers (``sort``, ``gnn``): the subset view of
the threat model of lesmc/tracking/parts/attacker.py (the two modules are one part;
docs/trackers.md, "Parts").

At an attacked step the attacker hides any subset of the frame's attackable detections
(:func:`attackable`: payoff finite, and ``within R`` of the target's reference), at the
sum of their payoffs: :func:`hidden_subsets` (``(frame, attacked, can) -> iterator of
index tuples``, the empty one first), :func:`subset_count` and :func:`subset_cost`
(``(payoffs (z,), subset) -> float``). With ``allow hide, inject`` (issue 61) it also
adds any subset of the frame's injection candidates (scene format 3) at their payoffs:
:func:`injected_subsets`, and :func:`subset_options` / :func:`option_count` (``(frame,
attacked, actions, can)``) combine both. lesmc/unfold/multi.py merges the options that
lead to the same successor.

The joint design under inject (lesmc/tracking/joint.py) offers, per state, the subsets of
only the candidates that can change its successor (:func:`relevant_candidates`; the
proof: docs/semantics.md, "Pruning injection candidates"): :func:`pruned_subsets`,
:func:`shown_and_cost`, and :func:`within_inject_budget` bounds their number.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator

import numpy as np

from lesmc.common.errors import BudgetError
from lesmc.scene import Frame

#: (state, hiding option, candidate subset) rows one attacked step under inject may build at
#: most (each runs the tracker: ~40,000 a second): past it the step is a BudgetError (exit 3)
#: before any subset is listed, not minutes of work or a memory blow-up
MAX_INJECT_ROWS = 1 << 20


def within_inject_budget(relevant: np.ndarray, step: int, options: np.ndarray) -> None:
    """A BudgetError unless every state's rows, its ``options`` hiding options × the subsets
    of its ``relevant`` (n, m) injection candidates (:func:`relevant_candidates`), 2^k for a
    state with k, fit in :data:`MAX_INJECT_ROWS` together (checked before listing any)."""
    k = relevant.sum(axis=1) if relevant.size else np.zeros(len(relevant), dtype=np.int64)
    big = int(k.max(initial=0))
    opts = np.maximum(np.asarray(options, dtype=np.int64).reshape(-1), 1).tolist()
    rows = sum(o << int(x) for o, x in zip(opts, k.tolist(), strict=True)) if big < 64 else 0
    if big < 64 and rows <= MAX_INJECT_ROWS:
        return
    most = max(opts, default=1)
    cap = max(0, (MAX_INJECT_ROWS // max(1, most * len(k))).bit_length() - 1)
    raise BudgetError(
        f"frame {step}: the joint design under inject would build {len(k)} state(s) × up "
        f"to {most} hiding option(s) × up to 2^{big} subsets of the frame's injection "
        f"candidates that can change it ({'more than 2^64' if big >= 64 else f'{rows:,}'} "
        f"rows, each a tracker step; the limit is {MAX_INJECT_ROWS:,}): every candidate "
        f"within the initiator's radius of the target counts; offer at most {cap} "
        "candidates a frame (perceive --inject-cap N, or a smaller --inject-within PX)"
    )


def relevant_candidates(
    n: int,
    nd: int,
    pairs: tuple[np.ndarray, np.ndarray],
    primary: tuple[np.ndarray, np.ndarray],
    births: np.ndarray,
) -> np.ndarray:
    """(n, m) which of the frame's m injection candidates can change state i's successor
    under the joint design (docs/semantics.md, "Pruning injection candidates"): those some
    track of the state gates (``pairs``: the gated (state, measurement) pairs, candidate j
    being measurement nd + j) and those in the initiator's birth region around a position
    the state's primary can take (``births`` (c, m): whether each candidate lies in the
    region around one of the positions c stands for; ``primary``: (state, c) pairs, that
    cover every position the state's primary may take: predicted, or updated with each
    measurement its gate admits). Any other
    candidate leaves the successor of every option unchanged and only adds its payoff, so
    every subset holding one is dominated by the same subset without it."""
    m = births.shape[1]
    rel = np.zeros((n, m), dtype=bool)
    ps, pz = pairs
    c = pz >= nd
    rel[ps[c], pz[c] - nd] = True
    st, centre = primary
    hit_s, hit_j = np.nonzero(births[centre])
    rel[st[hit_s], hit_j] = True
    return rel


def pruned_subsets(
    relevant: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[tuple[int, ...]]]:
    """Every state's subsets of its ``relevant`` (n, m) candidates, as rows: the state,
    each subset's place among its state's subsets (in the order of :func:`injected_subsets`
    restricted to them: by size, then lexicographic; 0 the empty one) and its index into
    the returned list of subsets (candidate indices). States with the same relevant
    candidates share their subsets' entries."""
    if not relevant.size:
        zero = np.zeros(len(relevant), dtype=np.int64)
        return np.arange(len(relevant)), zero, zero, [()]
    groups, inv = np.unique(relevant, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    subsets: list[tuple[int, ...]] = []
    first: list[int] = []
    size: list[int] = []
    for g in groups:
        idx = np.flatnonzero(g).tolist()
        first.append(len(subsets))
        subsets += [s for r in range(len(idx) + 1) for s in itertools.combinations(idx, r)]
        size.append(len(subsets) - first[-1])
    count = np.asarray(size, dtype=np.int64)[inv]
    state = np.repeat(np.arange(len(relevant)), count)
    local = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
    return state, local, np.asarray(first, dtype=np.int64)[inv[state]] + local, subsets


def attackable(frame: Frame, ref: np.ndarray | None, radius: float | None) -> np.ndarray:
    """Which of the frame's detections a multi-target tracker's attacker may hide: those
    of finite payoff and, with ``attack window L..U within R`` (``radius`` R), whose
    position lies within R px of the centre of the target's reference box ``ref``
    [x1, y1, x2, y2] (none where the reference does not exist). Injection candidates are
    not limited by R: the scene places them."""
    can = np.array([not math.isinf(d.payoff) for d in frame.detections], dtype=bool)
    if radius is None or not len(can):
        return can
    if ref is None:
        return np.zeros(len(can), dtype=bool)
    c = np.array([(ref[0] + ref[2]) / 2.0, (ref[1] + ref[3]) / 2.0])
    near: np.ndarray = can & (np.hypot(*(frame.positions() - c).T) <= radius)
    return near


def hidden_subsets(
    frame: Frame, attacked: bool, can: np.ndarray | None = None
) -> Iterator[tuple[int, ...]]:
    """The subsets of the frame's detections the attacker may hide (indices), the empty
    one (unattacked) first: every subset of the attackable ones (``can``, default
    :func:`attackable` without a radius) when ``attacked``."""
    if not attacked:
        yield ()
        return
    mask = attackable(frame, None, None) if can is None else can
    idx = np.nonzero(mask)[0].tolist()
    for r in range(len(idx) + 1):
        yield from itertools.combinations(idx, r)


def subset_count(frame: Frame, attacked: bool, can: np.ndarray | None = None) -> int:
    """How many subsets :func:`hidden_subsets` yields, counted without listing them."""
    mask = attackable(frame, None, None) if can is None else can
    return 2 ** int(mask.sum()) if attacked else 1


def subset_cost(payoffs: np.ndarray, subset: tuple[int, ...]) -> float:
    """What hiding the detections ``subset`` costs: the sum of their ``payoffs``."""
    return math.fsum(payoffs[list(subset)]) if subset else 0.0


def injected_subsets(frame: Frame, attacked: bool) -> Iterator[tuple[int, ...]]:
    """The subsets of the frame's injection candidates the attacker may inject (indices
    into its candidates), the empty one first: every subset when ``attacked``."""
    if not attacked:
        yield ()
        return
    for r in range(len(frame.candidates) + 1):
        yield from itertools.combinations(range(len(frame.candidates)), r)


def shown_and_cost(
    ids: np.ndarray, subsets: list[tuple[int, ...]], nd: int, nz: int, payoffs: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """For rows injecting ``subsets[ids[r]]`` (candidate indices; candidate j is
    measurement nd + j of nz): (rows, nz) which measurements each row sees (every
    detection, its subset's candidates) and what injecting its subset costs
    (:func:`subset_cost` of the candidates' ``payoffs``)."""
    u, inv = np.unique(ids, return_inverse=True)
    seen = np.zeros((u.size, nz), dtype=bool)
    seen[:, :nd] = True
    cost = np.zeros(u.size)
    for k, i in enumerate(u.tolist()):
        sub = subsets[i]
        seen[k, [nd + j for j in sub]] = True
        cost[k] = subset_cost(payoffs, sub)
    inv = inv.reshape(-1)
    return seen[inv], cost[inv]


def subset_options(
    frame: Frame, attacked: bool, actions: tuple[str, ...], can: np.ndarray | None = None
) -> list[tuple[int, ...]]:
    """Every option of a multi-target tracker's attacker taking ``actions``
    (lesmc/language/actions.py) at the frame, the unattacked one first: the detections
    hidden (indices i < n into ``can``, the attackable ones, n the frame's detections),
    then the candidates injected (n + j for candidate j)."""
    n = len(frame.detections)
    inject = attacked and "inject" in actions
    added = [tuple(n + j for j in s) for s in injected_subsets(frame, inject)]
    hidden = hidden_subsets(frame, attacked and "hide" in actions, can)
    return [h + a for h in hidden for a in added]


def option_count(
    frame: Frame, attacked: bool, actions: tuple[str, ...], can: np.ndarray | None = None
) -> int:
    """How many options :func:`subset_options` lists, counted without listing them."""
    adds = 2 ** len(frame.candidates) if attacked and "inject" in actions else 1
    return subset_count(frame, attacked and "hide" in actions, can) * adds
