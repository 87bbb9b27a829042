"""The search space of one property on one model, as integer arrays.

Both engines work on this: the states reachable under the attack window, each
transition's contribution to the objective and to the constraint measure, and
(optionally) exact suffix bounds. Every path measure is an aggregate, sum or
max, of non-negative per-step contributions, so it never decreases along a
path; this is what makes best-first search and dominance pruning exact.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple, Protocol

import numpy as np

from lesmc.common.errors import SpecError
from lesmc.language import monitors
from lesmc.language.semantics import BoundProperty
from lesmc.model import kernel
from lesmc.model.arrays import ArrayModel, Tracks, reference_states


def deviations(cm: ArrayModel, norm: float, components: tuple[int, ...]) -> np.ndarray:
    """dist(ρ_k, ρ̃_k) of every state against the reference state of its step (Eq. 4): the
    original path's (:func:`~lesmc.model.arrays.reference_states`)."""
    ref_states = reference_states(cm)
    ref = ref_states[np.minimum(cm.step, len(ref_states) - 1)]
    return kernel.deviation((cm.S - ref)[:, list(components)], norm)


def nearest_deviations(
    S: np.ndarray, steps: np.ndarray, ref_states: np.ndarray, tracks: Tracks, bp: BoundProperty
) -> np.ndarray:
    """``dist.nearest`` of states (rows of S at ``steps``): the least deviation from the
    reference path or a ground-truth track at the state's step (kernel.nearest)."""
    assert bp.near_components is not None
    comps = list(bp.near_components)
    ref = ref_states[np.minimum(steps, len(ref_states) - 1)]
    d0 = kernel.deviation((S - ref)[:, comps], bp.norm)
    k = np.minimum(steps, tracks.at.shape[1] - 1)
    return kernel.nearest(d0, (S[:, comps] - at[k] for at in tracks.at), bp.norm)


def monitor_tau(cm: ArrayModel, bp: BoundProperty) -> np.ndarray:
    """τ (Eq. 12) of every state over the monitor's components; zeros for a monitor that
    reads no τ (its components are ())."""
    assert bp.monitor_components is not None
    if not bp.monitor_components:
        return np.zeros(cm.n_states)
    return location_trace(cm, bp.monitor_components)


def location_trace(cm: ArrayModel, components: tuple[int, ...]) -> np.ndarray:
    """τ (Eq. 12) of every state, computed once per distinct covariance."""
    assert cm.cov is not None and cm.P_table is not None
    out: np.ndarray = kernel.tau(cm.P_table, components)[cm.cov]
    return out


def ranges(
    lo: np.ndarray, hi: np.ndarray, values: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Concatenate the index ranges lo[i]:hi[i]: (i of each entry, the index or values[index])."""
    deg = hi - lo
    owner = np.repeat(np.arange(lo.size, dtype=np.int64), deg)
    starts = np.cumsum(deg) - deg
    idx = np.arange(int(deg.sum()), dtype=np.int64) - np.repeat(starts - lo, deg)
    return owner, (idx if values is None else values[idx])


def excused_steps(
    bp: BoundProperty, tau_original: np.ndarray, nis_original: np.ndarray | None = None
) -> np.ndarray | None:
    """The original track's alarm steps when the monitor excuses them (``except original``)."""
    if not bp.monitor_except_original:
        return None
    return original_alarms(bp, tau_original, nis_original)


def original_alarms(
    bp: BoundProperty, tau_original: np.ndarray, nis_original: np.ndarray | None
) -> np.ndarray:
    """Per step 0..e of the original path: the property's monitor fires entering it."""
    return kernel.original_alarms(tau_original, bp.monitor_parameter, bp.monitor_kind, nis_original)


def unattacked_alarm_steps(
    bp: BoundProperty, tau_original: np.ndarray, nis_original: np.ndarray | None
) -> list[int]:
    """The steps l..end where the unattacked (original) track raises the property's
    monitor's alarm (``tau_original``, ``nis_original``: per step 0..e of that path)."""
    fired = original_alarms(bp, tau_original, nis_original)
    return [k for k in range(bp.l, min(bp.end, len(fired) - 1) + 1) if fired[k]]


def monitor_reads_nis(bp: BoundProperty) -> bool:
    """The property's monitor reads the NIS of the transitions' updates (nis, misses)."""
    return monitors.get(bp.monitor_kind).reads == "nis"


def transition_nis(cm: Any, bp: BoundProperty) -> np.ndarray | None:
    """The NIS of every transition when the monitor reads it (else None); a model without
    them cannot be checked under such a monitor (the binding refuses it first when the
    model is known)."""
    if not monitor_reads_nis(bp):
        return None
    nis: np.ndarray | None = cm.nis
    if nis is None:
        raise SpecError(
            f"property '{bp.name}': the {bp.monitor_kind} monitor needs the NIS of every "
            "transition's update, which this model does not carry (docs/lts-format.md)"
        )
    return nis


def original_nis(cm: Any, nis: np.ndarray | None) -> np.ndarray | None:
    """The NIS of the update entering each step of the original path (NaN at step 0)."""
    if nis is None:
        return None
    orig = cm.original.tolist()
    out = np.full(len(orig), np.nan)
    for j in range(1, len(orig)):
        out[j] = nis[cm.edge(orig[j - 1], orig[j])]
    return out


class SearchSpace(Protocol):
    """What the engines and reports need: the explicit :class:`Space` or the lazy one."""

    @property
    def bp(self) -> BoundProperty: ...

    @property
    def cm(self) -> Any: ...  # an ArrayModel, or a GrowingModel (lazy.py): the same array names

    @property
    def dist(self) -> Any: ...

    @property
    def c_obj(self) -> Any: ...

    @property
    def c_con(self) -> Any: ...

    root: int
    root_obj: float
    root_con: float

    @property
    def obj_max(self) -> bool: ...

    @property
    def con_max(self) -> bool: ...

    @property
    def con_up(self) -> bool: ...

    def violates(self, con: float) -> bool: ...

    def satisfies(self, con: Any, bound: Any) -> Any: ...

    def tail_at(self, h: int) -> tuple[float, float]: ...

    def tails(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...

    def agg(self, is_max: bool, acc: float, c: float) -> float: ...

    def is_leaf(self, q: int) -> bool: ...

    def leaves(self, q: np.ndarray | None = None) -> np.ndarray: ...

    def successors(self, q: int) -> Sequence[int] | np.ndarray: ...

    def successors_batch(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...

    def tail(self, q: int) -> tuple[float, float]: ...

    def entering(self, q0: int, q1: int) -> int: ...


class SpaceOps:
    """Operations shared by the explicit :class:`Space` and the on-the-fly one (lazy.py)."""

    bp: BoundProperty
    cm: Any  # an ArrayModel or a GrowingModel
    satisfies: Callable[[float, float], bool]

    @property
    def obj_max(self) -> bool:
        return self.bp.objective.aggregate == "max"

    @property
    def con_max(self) -> bool:
        return self.bp.constraint.aggregate == "max"

    @property
    def con_up(self) -> bool:
        """True when a larger constraint value brings a path closer to violating."""
        return self.bp.op in (">", ">=")

    def violates(self, con: float) -> bool:
        """The constraint holds for this value: the path is in P+ (breaks the system)."""
        return self.satisfies(con, self.bp.bound)

    agg = staticmethod(kernel.aggregate)

    def sync(self) -> None:
        """Read what another space sharing the model unfolded since the last call (a
        whole model has nothing to read: every state is there)."""

    def is_leaf(self, q: int) -> bool:
        """A path ends here: the property's last step, or the track halted."""
        return bool(self.cm.step[q] >= self.bp.end or self.cm.halted[q])

    def leaves(self, q: np.ndarray | None = None) -> np.ndarray:
        """:meth:`is_leaf` of states ``q`` (of every state when None), as a mask."""
        cm = self.cm
        if q is None:
            out: np.ndarray = (cm.step >= self.bp.end) | cm.halted
            return out
        out = (cm.step[q] >= self.bp.end) | cm.halted[q]
        return out

    def tail(self, q: int) -> tuple[float, float]:
        return self.tail_at(int(self.cm.step[q]))

    def tail_at(self, h: int) -> tuple[float, float]:
        """Contributions of the steps after a leaf at step h: +inf deviation after a halt."""
        bp = self.bp
        return kernel.tail(bp.objective, h, bp.end), kernel.tail(bp.constraint, h, bp.end)

    def tails(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`tail` of leaves ``q``, as arrays (computed once per distinct step)."""
        steps = self.cm.step[q]
        to, tc = np.zeros(q.size), np.zeros(q.size)
        for h in np.unique(steps).tolist():
            at = steps == h
            to[at], tc[at] = self.tail_at(int(h))
        return to, tc


class LevelMoves(NamedTuple):
    """A level's states that are not leaves and their allowed transitions in order, each
    state's offset into them (for ``ufunc.reduceat``), and which states have any."""

    inner: np.ndarray
    t: np.ndarray
    seg: np.ndarray
    has: np.ndarray


@dataclass
class Space(SpaceOps):
    """One property's search space on an explicit model: allowed transitions, contributions.

    ``adj_ptr``/``adj`` list, per state, the transitions an attacked path may
    take (all of them when the entered step is in the window, else only the
    rank-minimal one; minus those the monitor forbids), in rank order.
    """

    cm: ArrayModel
    bp: BoundProperty
    dist: np.ndarray
    adj_ptr: np.ndarray
    adj: np.ndarray
    c_obj: np.ndarray  # per transition
    c_con: np.ndarray
    root: int
    root_obj: float
    root_con: float
    satisfies: Callable[[float, float], bool]
    #: per transition: the monitor drops it (Eq. 13 entering a step l..end); None: no monitor
    cut: np.ndarray | None = None
    #: per state: ``dist.nearest`` (kernel.nearest); None: the property has no such measure
    near: np.ndarray | None = None
    _levels: tuple[np.ndarray, ...] | None = field(
        default=None, init=False, repr=False, compare=False
    )
    _moves: tuple[LevelMoves, ...] = field(default=(), init=False, repr=False, compare=False)

    def successors(self, q: int) -> np.ndarray:
        return self.adj[self.adj_ptr[q] : self.adj_ptr[q + 1]]

    def successors_batch(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The allowed transitions of states ``q``: (position in ``q``, transition), in order."""
        return ranges(self.adj_ptr[q], self.adj_ptr[q + 1], self.adj)

    def allowed(self, states: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The allowed transitions of ``states`` in order, each state's offset into them
        (for ``ufunc.reduceat``), and which states have any."""
        lo, hi = self.adj_ptr[states], self.adj_ptr[states + 1]
        _, t = ranges(lo, hi, self.adj)
        deg = hi - lo
        return t, np.concatenate(([0], np.cumsum(deg))), deg > 0

    def reachable_levels(self) -> tuple[np.ndarray, ...]:
        """The states reachable from the root under the window, one array per step
        (computed once per space; every bound pass starts from it)."""
        if self._levels is None:
            self._levels, self._moves = self._reachable_levels()
        return self._levels

    def level_moves(self, i: int) -> LevelMoves:
        """Level i of :meth:`reachable_levels`: its states that are not leaves and their
        allowed transitions, as :meth:`allowed` gives them (found once, in the forward
        pass; every backward bound pass reads them)."""
        self.reachable_levels()
        return self._moves[i]

    def _reachable_levels(self) -> tuple[tuple[np.ndarray, ...], tuple[LevelMoves, ...]]:
        leaf = self.leaves()
        seen = np.zeros(self.cm.n_states, dtype=bool)
        level = np.array([self.root], dtype=np.int64)
        seen[self.root] = True
        levels, moves = [level], []
        while True:
            inner = level[~leaf[level]]
            t, seg, has = self.allowed(inner)
            moves.append(LevelMoves(inner, t, seg, has))
            nxt = np.unique(self.cm.dst[t])
            nxt = nxt[~seen[nxt]]
            if not nxt.size:
                return tuple(levels), tuple(moves)
            seen[nxt] = True
            levels.append(nxt)
            level = nxt

    def entering(self, q0: int, q1: int) -> int:
        """The transition from q0 to q1."""
        return self.cm.edge(q0, q1)


def _monitor_cut(cm: ArrayModel, bp: BoundProperty, k: np.ndarray) -> np.ndarray:
    """The transitions the property's monitor drops (kernel.monitor_cuts), ``k`` the step
    each enters."""
    tau = monitor_tau(cm, bp)
    nis = transition_nis(cm, bp)
    excused = excused_steps(bp, tau[cm.original], original_nis(cm, nis))
    return kernel.monitor_cuts(
        bp.l, k, tau[cm.src], tau[cm.dst], bp.monitor_parameter, excused, bp.monitor_kind, nis
    )


def build_space(cm: ArrayModel, bp: BoundProperty) -> Space:
    """Compile a bound property against a model: allowed transitions and contributions."""
    dist = deviations(cm, bp.norm, bp.components)
    m = cm.n_transitions
    n = cm.n_states
    src = cm.src
    k = cm.step[cm.dst] if m else np.zeros(0, dtype=np.int64)
    in_window = (k >= bp.l) & (k <= bp.u)
    first = np.zeros(m, dtype=bool)
    first[cm.ptr[:-1][np.diff(cm.ptr) > 0]] = True  # rank-minimal transition of each state
    allowed = in_window | first
    cut = None
    if bp.monitor_components is not None:
        cut = _monitor_cut(cm, bp, k)
        allowed &= ~cut
    adj = np.nonzero(allowed)[0]
    counts = np.bincount(src[adj], minlength=n) if m else np.zeros(n, int)
    adj_ptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    combined, counted = cm.combined, cm.counted
    rise = None
    if bp.tau_components is not None:  # tau.rise: section 9.1's trend of τ (Eq. 12)
        tau_r = location_trace(cm, bp.tau_components)
        rise = kernel.tau_rise(tau_r[src], tau_r[cm.dst])
    near = None
    if bp.near_components is not None:  # dist.nearest: any acceptable track (section 4.2)
        assert cm.tracks is not None
        near = nearest_deviations(cm.S, cm.step, reference_states(cm), cm.tracks, bp)
    near_dst = None if near is None else near[cm.dst]
    dst_dist = dist[cm.dst]
    c_obj = kernel.contributions(bp.objective, k, combined, dst_dist, counted, rise, near_dst)
    c_con = kernel.contributions(bp.constraint, k, combined, dst_dist, counted, rise, near_dst)
    # the common prefix: steps 0..l−1 follow the original path
    q0 = int(cm.original[0])
    d0, n0 = float(dist[q0]), 0.0 if near is None else float(near[q0])
    obj = kernel.initial_value(bp.objective, d0, n0)
    con = kernel.initial_value(bp.constraint, d0, n0)
    obj_max, con_max = bp.objective.aggregate == "max", bp.constraint.aggregate == "max"
    for kk in range(1, bp.l):
        t = cm.edge(int(cm.original[kk - 1]), int(cm.original[kk]))
        obj = kernel.aggregate(obj_max, obj, float(c_obj[t]))
        con = kernel.aggregate(con_max, con, float(c_con[t]))
    return Space(
        cm=cm,
        bp=bp,
        dist=dist,
        adj_ptr=adj_ptr,
        adj=adj,
        c_obj=c_obj,
        c_con=c_con,
        root=int(cm.original[bp.l - 1]),
        root_obj=obj,
        root_con=con,
        satisfies=kernel.COMPARE[bp.op],
        cut=cut,
        near=near,
    )
