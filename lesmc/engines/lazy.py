"""On-the-fly search space: a model given by its successor function, unfolded where looked at.

The model is a :class:`~lesmc.model.growing.GrowingModel`: its arrays grow
when :meth:`~lesmc.model.growing.GrowingModel.expand` is called for a batch of
states. This space asks for successors the first time the ``bnb`` engine pops
a state; outside the attack window (one successor per state) it expands every
state of that step still waiting, in one batch. Deviations, τ and the
contributions of new transitions are computed per batch with the kernel,
exactly as :func:`lesmc.engines.space.build_space` computes them for a
whole model, so both give the same answers (tests/test_builder.py).

The model may have been unfolded for a wider attack window than the property's
(one model serves every window of a campaign, lesmc/campaign): as in
``build_space``, a transition entering a step outside the property's window is
allowed only if it is rank-minimal (the unattacked outcome).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from lesmc.common.budget import Budget
from lesmc.engines.space import (
    SpaceOps,
    excused_steps,
    monitor_reads_nis,
    nearest_deviations,
    original_nis,
    ranges,
    transition_nis,
    unattacked_alarm_steps,
)
from lesmc.language.semantics import BoundProperty
from lesmc.model import kernel
from lesmc.model.arrays import reference_states
from lesmc.model.growing import BATCH_WORK, GrowArray, GrowingModel, counted_batch

#: Most states expanded together outside the window (bounds one batch's temporaries).
BATCH = 65_536
#: Under a monitor that reads only covariances, ask the model's expander whether the
#: window's root has any completion the monitor allows (docs/semantics.md, "A root no
#: monitored path leaves"); a root without one is not expanded at all. Asked only where
#: the property can be vacuous: the unattacked path (a path from the root) alarms in
#: l..end and the monitor does not excuse it (``except original``).
DEAD_ROOT = True


class LazySpace(SpaceOps):
    """A :class:`~lesmc.engines.space.SearchSpace` over a model unfolded on demand."""

    cm: GrowingModel

    def __init__(
        self, model: GrowingModel, bp: BoundProperty, budget: Budget | None = None
    ) -> None:
        self.cm = model
        self.bp = bp
        self.satisfies = kernel.COMPARE[bp.op]
        self._dist = GrowArray(np.float64)
        self._tau = GrowArray(np.float64)
        self._tau_table = GrowArray(np.float64)  # τ per entry of the model's covariance table
        self._trend_tau = GrowArray(np.float64)  # the same on tau.rise's components
        self._c_obj = GrowArray(np.float64)
        self._c_con = GrowArray(np.float64)
        self._allowed: dict[int, np.ndarray] = {}  # per expanded state: its allowed transitions
        self._mask = GrowArray(np.bool_)
        self._t_known = 0  # transitions whose contributions are computed
        self._waiting: dict[int, list[int]] = {}  # per step outside the window: unexpanded states
        self._queued: set[int] = set()  # every state ever put in _waiting
        self._known = 0  # states whose deviation and τ are computed
        self._ref = reference_states(model)
        self._excused: np.ndarray | None = None
        self._near = GrowArray(np.float64)  # dist.nearest per state, when the property asks
        #: the root has no completion the monitor allows (its transitions are not allowed)
        self.dead_root = False
        self._sync()
        q0 = int(model.original[0])
        d0 = float(self.dist[q0])
        n0 = float(self._near.data[q0]) if bp.near_components is not None else 0.0
        obj = kernel.initial_value(bp.objective, d0, n0)
        con = kernel.initial_value(bp.constraint, d0, n0)
        for k in range(1, bp.l):  # the common prefix follows the original path
            t = self.entering(int(model.original[k - 1]), int(model.original[k]))
            obj = self.agg(self.obj_max, obj, float(self.c_obj[t]))
            con = self.agg(self.con_max, con, float(self.c_con[t]))
        self.root = int(model.original[bp.l - 1])
        self.root_obj, self.root_con = obj, con
        self.dead_root = DEAD_ROOT and self._root_dead(budget or Budget())
        if self.dead_root and model.expanded(self.root):  # later ones: _sync leaves them out
            self._mask.data[int(model.out_lo[self.root]) : int(model.out_hi[self.root])] = False

    def _root_dead(self, budget: Budget) -> bool:
        """Whether the model's expander proves that no path from the root passes the
        property's monitor to the end (False when it cannot tell, or when the unattacked
        path shows it does: see DEAD_ROOT). The question stops, answering False, at the
        budget's deadline or past its ``max_states`` relaxed nodes."""
        ask = getattr(self.cm.expander, "primary_alive", None)
        cut = self.monitor_cut()
        if ask is None or cut is None or self.cm.halted[self.root]:  # a halted root is a leaf
            return False
        if self.bp.monitor_except_original or not self._unattacked_alarms():
            return False
        seconds = budget.check_seconds()
        deadline = None if seconds is None else time.monotonic() + seconds
        return ask(self.root, self.bp.end, cut, budget.max_states, deadline) is False

    def _unattacked_alarms(self) -> bool:
        """The monitor alarms on the unattacked path in l..end (no monitor reading the
        NIS: :meth:`monitor_cut`)."""
        tau = self._tau.data[np.asarray(self.cm.original)]
        return bool(unattacked_alarm_steps(self.bp, tau, None))

    def monitor_cut(self) -> Callable[[int, np.ndarray, np.ndarray], bool] | None:
        """The property's monitor as a function of a transition's step entered and the
        covariances P before and after it (True: the transition is cut); None without a
        monitor, or for one that reads more than P (the NIS)."""
        bp = self.bp
        comps = bp.monitor_components
        if comps is None or monitor_reads_nis(bp):
            return None

        def cut(k: int, p0: np.ndarray, p1: np.ndarray) -> bool:
            t = kernel.tau(np.stack([p0, p1]), comps)
            ks = np.array([k])
            return bool(
                kernel.monitor_cuts(
                    bp.l, ks, t[:1], t[1:], bp.monitor_parameter, self._excused, bp.monitor_kind
                )[0]
            )

        return cut

    @property
    def dist(self) -> np.ndarray:
        return self._dist.data

    @property
    def c_obj(self) -> np.ndarray:
        return self._c_obj.data

    @property
    def c_con(self) -> np.ndarray:
        return self._c_con.data

    @property
    def states_built(self) -> int:
        return self.cm.n_states

    def sync(self) -> None:
        """Compute what this space reads of the states and transitions another space (one
        sharing the model) has unfolded since the last call."""
        self._sync()

    def _sync(self) -> None:
        """Deviation (Eq. 4) and τ (Eq. 12) of the states added since the last call, then
        the contributions and monitor flags of the transitions added since then."""
        cm, bp = self.cm, self.bp
        new = np.arange(self._known, cm.n_states)
        if new.size:
            steps = cm.step[new]
            diff = (cm.S[new] - self._ref[steps])[:, list(bp.components)]
            self._dist.extend(kernel.deviation(diff, bp.norm))
            if bp.near_components is not None:
                assert cm.tracks is not None
                self._near.extend(nearest_deviations(cm.S[new], steps, self._ref, cm.tracks, bp))
            if bp.monitor_components is not None:
                self._tau.extend(self._tau_of_table()[cm.cov[new]])
                if self._excused is None:  # the original path is unfolded before the search
                    nis = original_nis(cm, transition_nis(cm, bp))
                    self._excused = excused_steps(bp, self._tau.data[cm.original], nis)
            self._known = cm.n_states
        t = np.arange(self._t_known, cm.n_transitions)
        if not t.size:
            return
        dst = cm.dst[t]
        ks = cm.step[dst].astype(np.int64)
        comb, cnt = cm.combined[t], cm.counted[t]
        rise = None
        if bp.tau_components is not None:  # tau.rise: section 9.1's trend of τ (Eq. 12)
            table = cm.P_table
            if len(table) > self._trend_tau.n:  # τ of each new covariance, once
                new_p = table[self._trend_tau.n :]
                self._trend_tau.extend(kernel.tau(new_p, bp.tau_components))
            tau_r = self._trend_tau.data
            rise = kernel.tau_rise(tau_r[cm.cov[cm.src[t]]], tau_r[cm.cov[dst]])
        dist = self.dist[dst]
        near = self._near.data[dst] if bp.near_components is not None else None
        self._c_obj.extend(kernel.contributions(bp.objective, ks, comb, dist, cnt, rise, near))
        self._c_con.extend(kernel.contributions(bp.constraint, ks, comb, dist, cnt, rise, near))
        allowed = ((ks >= bp.l) & (ks <= bp.u)) | (cm.rank[t] == 0)
        if self.dead_root:
            allowed &= cm.src[t] != self.root
        if bp.monitor_components is not None:
            tau = self._tau.data
            src = cm.src[t]
            nis = transition_nis(cm, bp)
            allowed &= ~kernel.monitor_cuts(
                bp.l,
                ks,
                tau[src],
                tau[dst],
                bp.monitor_parameter,
                self._excused,
                bp.monitor_kind,
                None if nis is None else nis[t],
            )
        self._mask.extend(allowed)
        self._t_known = cm.n_transitions

    def _tau_of_table(self) -> np.ndarray:
        """τ (Eq. 12) of every covariance in the model's table, computed once per entry."""
        table = self.cm.P_table
        known = self._tau_table.n
        if len(table) > known:
            assert self.bp.monitor_components is not None
            self._tau_table.extend(kernel.tau(table[known:], self.bp.monitor_components))
        return self._tau_table.data

    def allowed_mask(self) -> np.ndarray:
        """Per transition built so far: the property allows it (window, monitor; none of
        a dead root's)."""
        return self._mask.data

    def successors(self, q: int) -> np.ndarray:
        got = self._allowed.get(q)
        if got is None and q == self.root and self.dead_root:
            got = self._allowed[q] = np.zeros(0, dtype=np.int64)
        if got is None:
            if not self.cm.expanded(q):
                self._expand(q)
            lo, hi = int(self.cm.out_lo[q]), int(self.cm.out_hi[q])
            got = np.arange(lo, hi)[self._mask.data[lo:hi]]
            self._allowed[q] = got
            self._queue(self.cm.dst[got])
        return got

    def successors_batch(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The allowed transitions of states ``q``: (position in ``q``, transition), in order.

        States not yet expanded are expanded together, one batch per step.
        """
        cm = self.cm
        u = np.unique(q)
        todo = u[cm.out_lo[u] < 0]
        steps = cm.step[todo]
        for k in np.unique(steps).tolist():
            group = todo[steps == k]
            while group.size:  # batches of about BATCH_WORK, so that deadlines hold
                n = self._cap(BATCH)
                self._expand_batch(group[:n], int(k))
                group = group[n:]
        owner, t = ranges(cm.out_lo[q], cm.out_hi[q])
        ok = self._mask.data[t]
        return owner[ok], t[ok]

    def slice_size(self) -> int:
        """How many states to hand :meth:`successors_batch` at once: about BATCH_WORK of
        unfolding, so that the caller's clock and budgets are read often enough."""
        return self._cap(64)

    def _cap(self, unmeasured: int) -> int:
        """States whose expansion does about BATCH_WORK work at the model's work per
        state so far (``unmeasured`` before any state is expanded). Counted, not timed, so
        that the batches, and so the states a search or walk stopped between them has
        built, are the same on every run whatever the machine's load."""
        return counted_batch(self.cm.work, self.cm.states_expanded, BATCH, unmeasured, BATCH_WORK)

    def _expand_batch(self, states: np.ndarray, k: int) -> None:
        """Expand ``states`` (all at step k) and sync the new arrays."""
        self.cm.expand(states, k)
        self._sync()

    def _queue(self, states: np.ndarray) -> None:
        """States the search can reach whose successors lie outside the window: expanded
        together, per step, when the first of them is."""
        cm, bp = self.cm, self.bp
        for q in states.tolist():
            k = int(cm.step[q])
            if bp.l <= k + 1 <= bp.u or k >= bp.end or q in self._queued:
                continue
            if not cm.expanded(q) and not cm.halted[q]:
                self._queued.add(q)
                self._waiting.setdefault(k, []).append(q)

    def entering(self, q0: int, q1: int) -> int:
        if not self.cm.expanded(q0):
            self._expand(q0)
        return self.cm.edge(q0, q1)

    def _expand(self, q: int) -> None:
        """Successors of q; outside the window, of every state of q's step still waiting."""
        cm, bp = self.cm, self.bp
        k = int(cm.step[q])
        batch = [q]
        if not bp.l <= k + 1 <= bp.u:
            waiting = self._waiting.pop(k, [])
            batch += [x for x in waiting if x != q and not cm.expanded(x) and not cm.halted[x]]
            cap = self._cap(BATCH)
            if len(batch) > cap:
                self._waiting[k] = batch[cap:]
                batch = batch[:cap]
        self._expand_batch(np.array(batch, dtype=np.int64), k)
