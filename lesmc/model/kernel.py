"""The semantics kernel: every equation of the paper that gives a path its meaning, once.

Engines, the scene unfolder, the tracker's monitor and the report all call
these functions; none has a copy of its own. Each works on one value or on a
whole array of them (numpy broadcasting), so hot paths call them on batches.

* :func:`deviation`: dist(ρ_k, ρ̃_k) = ‖s_k − s̃_k‖_p (Eq. 4).
* :func:`combined_payoffs`: the combined payoff of a transition, the sum of the
  payoffs of the transitions ≺ it out of the same state (Eq. 5, read strictly:
  docs/semantics.md).
* :func:`contributions`, :func:`aggregate`, :func:`tail`: the path measures
  (payoff sum/mean, Eq. 8; dist sum/at/max, Eq. 9 and dist^max) as running
  aggregates of non-negative per-step contributions.
* :data:`COMPARE` and :func:`holds`: the comparisons of constraints and verdicts.
* :func:`tau` and :func:`alarm`: the runtime monitor's uncertainty τ (Eq. 12)
  and its alarm Γ = 0 (Eq. 13); :func:`track_alarms`, :func:`transition_alarms` and
  :func:`monitor_cuts`: any registered monitor's alarms (lesmc/language/monitors.py)
  on a track, on transitions, and the transitions a monitored property drops.

The independent oracle in tests/oracle.py does not use this module.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from lesmc.language import monitors
from lesmc.language.measures import Quantities
from lesmc.language.properties import DEFAULT_MONITOR_TOLERANCE
from lesmc.language.semantics import BoundMeasure

#: Comparison operators of the language, on scalars and arrays alike.
COMPARE: dict[str, Callable[[Any, Any], Any]] = {
    ">": np.greater,
    ">=": np.greater_equal,
    "<": np.less,
    "<=": np.less_equal,
}

LOCATION = (0, 1)
"""Indices of the location block (x, y) of a tracker state (x, y, vx, vy): Eq. 12's Σ_ll."""

DEFAULT_TOLERANCE = DEFAULT_MONITOR_TOLERANCE
"""Relative rise of τ that the alarm ignores: only absorbs rounding (docs/language.md)."""


def compare(op: str, a: float, b: float) -> bool:
    """``a op b`` for one pair of numbers."""
    return bool(COMPARE[op](a, b))


def holds(holds_op: str, optimum: float, threshold: float) -> bool:
    """Section 4's verdict rule: the property holds iff ``optimum holds_op threshold``."""
    return compare(holds_op, optimum, threshold)


def deviation(diff: np.ndarray, norm: float) -> np.ndarray:
    """Eq. 4: ‖s − s̃‖_p of each row of ``diff`` = s − s̃ (last axis: the chosen components)."""
    out: np.ndarray = np.linalg.norm(diff, ord=norm, axis=-1)
    return out


def nearest(d_original: np.ndarray, track_diffs: Iterable[np.ndarray], norm: float) -> np.ndarray:
    """``dist.nearest``: Eq. 4 against the nearest acceptable track (section 4.2: recovery
    "to some path that does not necessarily have to be the original one, so long as it
    is acceptable"): the least of the deviation from the original path (``d_original``)
    and from each ground-truth track present at the step (``track_diffs``: s − g per
    track, NaN where the track is absent, which never counts)."""
    out = np.asarray(d_original, dtype=float)
    for diff in track_diffs:
        out = np.fmin(out, deviation(diff, norm))
    return out


def _lower_ranks(
    ptr: np.ndarray, rank: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Eq. 5's sums for a CSR model whose rows are sorted by rank: each transition's
    rank group (``first``: the group's first transition; ``new_group``: where groups
    start), and per group (``lead``: its first transition) the row's start and the
    number of transitions of strictly lower rank before it (ties share a sum)."""
    m = len(rank)
    deg = np.diff(ptr)
    start = np.repeat(ptr[:-1], deg)
    pos = np.arange(m) - start
    new_group = (pos == 0) | np.r_[True, rank[1:] != rank[:-1]]
    first: np.ndarray = np.maximum.accumulate(np.where(new_group, np.arange(m), 0))
    lead = first[new_group]
    return first, new_group, lead, start[lead], lead - start[lead]


def exact_sum(values: Iterable[float]) -> float:
    """The exactly rounded sum (``math.fsum``) of non-negative ``values``; +inf where it
    exceeds the largest float (fsum raises on that instead)."""
    try:
        return math.fsum(values)
    except OverflowError:
        return math.inf


def prefix_sums(vals: list[float], starts: list[int], ends: list[int]) -> list[float]:
    """``exact_sum(vals[a:b])`` for each (a, b) of ``starts``, ``ends`` (pairs of one ``a``
    adjacent, ``b`` ascending), in time linear in a row's length, not quadratic: the exact
    partials of Shewchuk's summation (as ``math.fsum`` keeps them) carried from one ``b``
    to the next, each sum ``fsum`` of them. The same numbers: both are the correctly
    rounded exact sum. A partial past the largest float falls back to ``exact_sum``."""
    out: list[float] = []
    partials: list[float] = []
    a0, i, ok = -1, 0, True
    for a, b in zip(starts, ends, strict=True):
        if a != a0:
            a0, i, ok, partials = a, a, True, []
        while ok and i < b:
            ok = _add_exact(partials, vals[i])
            i += 1
        out.append(exact_sum(partials) if ok else exact_sum(vals[a:b]))
    return out


def _add_exact(partials: list[float], x: float) -> bool:
    """Add ``x`` to the non-overlapping ``partials`` exactly (Shewchuk; the recipe
    ``math.fsum`` is built on); False where a partial would leave the finite floats."""
    if not math.isfinite(x):
        return False
    j = 0
    for y in partials:
        if abs(x) < abs(y):
            x, y = y, x
        hi = x + y
        if not math.isfinite(hi):
            return False
        lo = y - (hi - x)
        if lo:
            partials[j] = lo
            j += 1
        x = hi
    partials[j:] = [x]
    return True


def combined_payoffs(ptr: np.ndarray, payoff: np.ndarray, rank: np.ndarray) -> np.ndarray:
    """Eq. 5 for every transition of a CSR model whose rows are sorted by rank.

    The combined payoff of a transition is the exactly rounded sum
    (``math.fsum``) of the payoffs of the transitions of strictly lower rank out
    of the same state. A sum of one or two terms is exactly rounded already, so
    those are vectorised and only longer prefixes are summed with fsum.
    """
    out = np.zeros(len(payoff))
    if not len(payoff):
        return out
    first, new_group, lead, row, n_terms = _lower_ranks(ptr, rank)
    sums = np.zeros(lead.size)
    one = n_terms == 1
    sums[one] = payoff[lead[one] - 1]
    two = n_terms == 2
    with np.errstate(over="ignore"):  # past the largest float: +inf, as exact_sum gives
        sums[two] = payoff[lead[two] - 2] + payoff[lead[two] - 1]
    many = np.nonzero(n_terms >= 3)[0]
    if many.size:
        sums[many] = prefix_sums(payoff.tolist(), row[many].tolist(), lead[many].tolist())
    out[new_group] = sums
    combined: np.ndarray = out[first]
    return combined


def combined_counts(ptr: np.ndarray, payoff: np.ndarray, rank: np.ndarray) -> np.ndarray:
    """Eq. 5 over unit payoffs: every transition's payoff replaced by 1, ∞ staying ∞ (an
    unattackable outcome stays out of reach), so that it counts the outcomes an attacker
    rules out. Without fsum: a sum of n ones is n, exactly; an infinite payoff among the
    lower ranks makes it ∞."""
    out = np.zeros(len(payoff))
    if not len(payoff):
        return out
    first, new_group, lead, row, n_terms = _lower_ranks(ptr, rank)
    infs = np.concatenate(([0], np.cumsum(~np.isfinite(payoff))))
    blocked = infs[lead] > infs[row]  # an unattackable outcome among the lower ranks
    out[new_group] = np.where(blocked, math.inf, n_terms)
    counts: np.ndarray = out[first]
    return counts


def contributions(
    m: BoundMeasure,
    k: np.ndarray,
    combined: np.ndarray,
    dist_dst: np.ndarray,
    counted: np.ndarray | None = None,
    rise: np.ndarray | None = None,
    near_dst: np.ndarray | None = None,
    identity: np.ndarray | None = None,
) -> np.ndarray:
    """Each transition's contribution to measure ``m``: it enters step ``k``.

    A payoff measure adds the (weighted) combined payoff of transitions entering
    its steps (Eq. 8; ``mean`` is the weight 1/(u−l+1)); a dist measure adds the
    deviation of the entered state (Eq. 9; ``at`` is a sum over one step).
    ``count`` is the payoff measure with unit payoffs (``counted``:
    :func:`combined_counts`), the number of outcomes hidden; ``frames`` adds 1 for each
    attacked step (a transition of rank > 0: its count is positive), ∞ where the
    count is. ``tau`` (``tau.rise``, aggregated by max) adds each transition's
    :func:`tau_rise` (``rise``); ``near`` (``dist.nearest``) the entered state's
    :func:`nearest` deviation (``near_dst``). ``switches`` and ``lost`` (multi-target
    designs) add the transition's identity indicator (``identity``:
    lesmc/model/identity.py ``indicators``). Which of these quantities a measure reads and
    how it weights them is its declaration's ``per_transition`` (lesmc/language/measures/).
    """
    inside = (k >= m.lo) & (k <= m.hi)
    q = Quantities(combined, dist_dst, counted, rise, near_dst, identity)
    return np.where(inside, m.declared.per_transition(m.source, m.weight, q), 0.0)


def initial_value(m: BoundMeasure, dist0: float, near0: float = 0.0) -> float:
    """A measure's value on the path prefix of step 0 alone (only deviations count step 0:
    ``dist0`` of Eq. 4, ``near0`` of :func:`nearest`)."""
    if m.lo != 0:
        return 0.0
    return m.declared.at_step0(m.source, dist0, near0)


def aggregate(is_max: bool, acc: float, c: float) -> float:
    """A measure after one more step: the running sum, or the running max (dist^max)."""
    return max(acc, c) if is_max else acc + c


def aggregate_arrays(is_max: bool, acc: np.ndarray, c: np.ndarray) -> np.ndarray:
    """:func:`aggregate` elementwise (a sum past the largest float is +inf)."""
    if is_max:
        top: np.ndarray = np.maximum(acc, c)
        return top
    with np.errstate(over="ignore"):
        out: np.ndarray = acc + c
    return out


def tail(m: BoundMeasure, h: int, end: int) -> float:
    """What the steps after a path's last state h add: nothing, or +∞ after a halt.

    A halted track has lost the target, so its deviation at every later step of
    a dist measure is infinite (docs/semantics.md), and so is the rise of its
    uncertainty (``tau.rise``: trace(P) passed ``max_trace``); payoffs add nothing.
    """
    if h >= end or not m.declared.halted_tail(m.source):
        return 0.0
    return math.inf if m.hi > h else 0.0


def tau(P: np.ndarray, components: Sequence[int] = LOCATION) -> np.ndarray:
    """Eq. 12: τ = tr(Σ_ll) of one covariance (d, d) or of a stack (n, d, d)."""
    idx = list(components)
    sub = P[..., idx, :][..., :, idx]
    out: np.ndarray = np.trace(sub, axis1=-2, axis2=-1)
    return out


def tau_rise(tau_src: ArrayLike, tau_dst: ArrayLike) -> np.ndarray:
    """Section 9.1's trend, per transition: how much τ (Eq. 12) rose on it, 0 when it fell
    or stayed (``tau.rise``; a non-increasing τ is "evidence that the system is managing
    the failure")."""
    out: np.ndarray = np.maximum(np.asarray(tau_dst) - np.asarray(tau_src), 0.0)
    return out


def alarm(
    tau_prev: ArrayLike, tau_next: ArrayLike, tolerance: float = DEFAULT_TOLERANCE
) -> np.ndarray:
    """Eq. 13's Γ = 0: τ rose from one step to the next beyond the relative tolerance
    (the ``tau_rise`` monitor's test, :func:`lesmc.language.monitors.rises`)."""
    return monitors.rises(np.asarray(tau_prev), np.asarray(tau_next), tolerance)


def track_alarms(
    kind: str, parameter: float, window: int, tau_track: ArrayLike, nis_track: ArrayLike | None
) -> np.ndarray:
    """The alarms of monitor ``kind`` (lesmc/language/monitors.py) at each step 0..n of a
    track (last axis), from τ (Eq. 12) and the NIS of the update entering each step (NaN:
    none, and at step 0); ``nis_track`` None: the monitor reads no NIS."""
    tau_a = np.asarray(tau_track, dtype=float)
    nis_a = np.full(tau_a.shape, np.nan) if nis_track is None else np.asarray(nis_track, float)
    return monitors.get(kind).alarm(parameter, window, tau_a, nis_a)


def transition_alarms(
    kind: str,
    parameter: float,
    tau_src: ArrayLike,
    tau_dst: ArrayLike,
    nis: ArrayLike | None = None,
) -> np.ndarray:
    """The alarm of a monitor that reads one transition (window 1) on each transition:
    :func:`track_alarms` on the two-step track source, target."""
    src, dst = np.broadcast_arrays(np.asarray(tau_src, float), np.asarray(tau_dst, float))
    tau2 = np.stack([src, dst], axis=-1)
    nis2 = None
    if nis is not None:
        nis2 = np.stack([np.full(dst.shape, np.nan), np.broadcast_to(nis, dst.shape)], axis=-1)
    out: np.ndarray = track_alarms(kind, parameter, 1, tau2, nis2)[..., 1]
    return out


def original_alarms(
    tau_original: np.ndarray,
    tolerance: float,
    kind: str = "tau_rise",
    nis_original: np.ndarray | None = None,
) -> np.ndarray:
    """Per step k = 0..e of the original (unattacked) path: the monitor's alarm fires
    entering k (Eq. 13 for ``tau_rise``; ``tolerance`` is the kind's parameter)."""
    out: np.ndarray = track_alarms(kind, tolerance, 1, tau_original, nis_original)
    return out


def monitor_cuts(
    l: int,
    k: np.ndarray,
    tau_src: np.ndarray,
    tau_dst: np.ndarray,
    tolerance: float,
    excused: np.ndarray | None = None,
    kind: str = "tau_rise",
    nis: np.ndarray | None = None,
) -> np.ndarray:
    """Transitions the monitored property drops: entering a step k ≥ l, the monitor's alarm
    fires (Eq. 13 for ``tau_rise``: τ rises; ``tolerance`` is the kind's parameter, ``nis``
    each transition's NIS for the monitors that read it).

    ``excused`` (per step, from :func:`original_alarms`) is the practitioner's
    monitor, ``monitor uncertainty ... except original``: an alarm at a step
    where the unattacked track raises one too is not the attack's doing and
    does not cut.
    """
    out: np.ndarray = (k >= l) & transition_alarms(kind, tolerance, tau_src, tau_dst, nis)
    if excused is not None and excused.size:
        out &= ~excused[np.minimum(k, excused.size - 1)]
    return out
