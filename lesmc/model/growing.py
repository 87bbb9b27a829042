"""A model unfolded on demand: arrays that grow as an engine asks for successors.

This is the model interface for models given by a successor function (paper
Algorithm 1 run lazily): the engines read the state and transition arrays,
and call :meth:`GrowingModel.expand` with a *batch* of states of one step to
have all their successors computed at once. Whoever produces the successors
(lesmc/unfold/unfold.py for scenes) implements :class:`Expander`; engines import
only this module and never know what a scene is.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

from lesmc.model.kernel import combined_counts, combined_payoffs

if TYPE_CHECKING:
    from lesmc.model.arrays import Tracks

#: Work (GrowingModel.work) one batch of expansions does at most, on demand (engines/lazy.py)
#: and in the eager build (unfold/unfold.py): batches shrink for designs whose states are
#: expensive (joint), so that a deadline is looked at often enough; about 0.05 s at
#: about 1-2 µs a unit (a transition on ``single``, a track of an
#: examined row on ``joint``), counted rather than timed so that the batches, and what
#: a budget looked at between them stops, are the same on every run.
BATCH_WORK = 1 << 15


class ExpansionStopped(Exception):
    """A budget (``reason``: ``timeout``, ``max_memory``, ``interrupted``) ran out inside one
    expansion too long to wait for (the joint design under inject looks between its chunks:
    lesmc/tracking/joint.py ``stop``). Raised before any successor is added, so the model
    stays as it was; the search that asked ends ``unknown`` (lesmc/engines/check.py)."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


def counted_batch(work: float, states: int, most: int, unmeasured: int, per_batch: int) -> int:
    """How many states to expand next so that the batch does about ``per_batch`` work
    (:data:`BATCH_WORK`, which each caller passes), at ``work`` per ``states`` expanded as
    measured so far (``unmeasured`` when none is), at most ``most``. Counted, not timed:
    the batches, and so the states a budget looked at between them stops at, are the same
    on every run whatever the machine's load (the lazy model's batches, engines/lazy.py,
    and the eager build's, unfold/unfold.py)."""
    if states <= 0:
        return unmeasured
    per = max(work / states, 1e-9)
    return max(1, min(most, int(per_batch / per) + 1))


class GrowArray:
    """A numpy array with amortised appends along the first axis (``data`` may be longer).

    It grows by a quarter: while it grows the old and the new buffer coexist,
    so the peak is 2.25x the data rather than 3x with doubling, for about
    four copies of each element in all instead of two.
    """

    def __init__(self, dtype: type | np.dtype, width: tuple[int, ...] = ()) -> None:
        self.data = np.empty((256, *width), dtype=dtype)
        self.n = 0

    def extend(self, values: np.ndarray) -> None:
        need = self.n + len(values)
        if need > len(self.data):
            cap = max(need, len(self.data) + len(self.data) // 4)
            bigger = np.empty((cap, *self.data.shape[1:]), dtype=self.data.dtype)
            bigger[: self.n] = self.data[: self.n]
            self.data = bigger
        self.data[self.n : need] = values
        self.n = need

    @property
    def view(self) -> np.ndarray:
        return self.data[: self.n]


@dataclass
class Expansion:
    """Successors of a batch of states: CSR over the batch, rank order within each source."""

    counts: np.ndarray  # (b,) transitions per source
    dst: np.ndarray  # (m,) global state indices (new states already added)
    payoff: np.ndarray
    rank: np.ndarray
    obs: np.ndarray  # codes into the expander's observation names, −1 none
    #: the NIS of each transition's update, NaN where it takes none; None: not reported
    nis: np.ndarray | None = None
    #: the work done for it, in track moves (lesmc/tracking/design.py Successors.examined:
    #: on the joint design the rows it examined before merging equal outcomes, times their
    #: tracks); None: one per transition. Counted, not timed, so that what a budget of it
    #: decides does not depend on the machine's load (:attr:`GrowingModel.work`)
    work: int | None = None


class Expander(Protocol):
    """Computes successors and adds the new states to its model."""

    def expand(self, states: np.ndarray, step: int) -> Expansion: ...


class GrowingModel:
    """States and transitions as growing arrays; out-transitions of state q are
    ``out_lo[q]:out_hi[q]`` once q is expanded (``expanded[q]``)."""

    def __init__(self, components: tuple[str, ...], dim: int) -> None:
        self.components = components
        self._step = GrowArray(np.int32)
        self._S = GrowArray(np.float64, (dim,))
        self._cov = GrowArray(np.int32)
        self._halted = GrowArray(np.bool_)
        self._lo = GrowArray(np.int64)
        self._hi = GrowArray(np.int64)
        self._src = GrowArray(np.int64)
        self._dst = GrowArray(np.int64)
        self._payoff = GrowArray(np.float64)
        self._rank = GrowArray(np.int64)
        self._obs = GrowArray(np.int64)
        self._combined = GrowArray(np.float64)
        self._counted = GrowArray(np.float64)
        self._nis = GrowArray(np.float64)
        #: every expansion so far reported the NIS of its updates (the tracker computes them)
        self.reports_nis = True
        self.original = np.zeros(0, dtype=np.int64)
        #: the states deviations are measured against (lesmc.model.arrays.reference_states)
        self.reference: np.ndarray | None = None
        #: ground-truth tracks (lesmc.model.arrays.Tracks) ``dist.nearest`` accepts
        self.tracks: Tracks | None = None
        self.P_table = np.zeros((0, dim, dim))
        self.obs_names: tuple[str, ...] = ()
        self.expander: Expander | None = None
        #: the unfolding's work so far (the sum of Expansion.work), a measure of its cost
        #: that is the same on every run (check.check_shared's cap)
        self.work = 0
        #: how many states have been expanded so far
        self.states_expanded = 0

    # -- states -------------------------------------------------------------
    def add_states(self, step: int, S: np.ndarray, cov: np.ndarray, halted: np.ndarray) -> int:
        """Append states at one step; returns the index of the first."""
        first = self._step.n
        n = len(S)
        self._step.extend(np.full(n, step, dtype=np.int32))
        self._S.extend(S)
        self._cov.extend(cov)
        self._halted.extend(halted)
        self._lo.extend(np.full(n, -1, dtype=np.int64))
        self._hi.extend(np.full(n, -1, dtype=np.int64))
        return first

    @property
    def n_states(self) -> int:
        return self._step.n

    @property
    def step(self) -> np.ndarray:
        return self._step.view

    @property
    def S(self) -> np.ndarray:
        return self._S.view

    @property
    def cov(self) -> np.ndarray:
        return self._cov.view

    @property
    def halted(self) -> np.ndarray:
        return self._halted.view

    @property
    def out_lo(self) -> np.ndarray:
        return self._lo.view

    @property
    def out_hi(self) -> np.ndarray:
        return self._hi.view

    def expanded(self, q: int) -> bool:
        return bool(self._lo.data[q] >= 0)

    # -- transitions --------------------------------------------------------
    @property
    def src(self) -> np.ndarray:
        return self._src.view

    @property
    def dst(self) -> np.ndarray:
        return self._dst.view

    @property
    def payoff(self) -> np.ndarray:
        return self._payoff.view

    @property
    def rank(self) -> np.ndarray:
        return self._rank.view

    @property
    def obs(self) -> np.ndarray:
        return self._obs.view

    @property
    def combined(self) -> np.ndarray:
        return self._combined.view

    @property
    def nis(self) -> np.ndarray | None:
        """The NIS of each transition's update (NaN: none); None when the tracker does not
        report them (docs/lts-format.md, ``transitions[].nis``)."""
        return self._nis.view if self.reports_nis else None

    @property
    def counted(self) -> np.ndarray:
        """Eq. 5 over unit payoffs (kernel.combined_counts) per transition."""
        return self._counted.view

    @property
    def n_transitions(self) -> int:
        return self._dst.n

    def expand(self, states: np.ndarray, step: int) -> np.ndarray:
        """Compute the successors of ``states`` (all at ``step``, none expanded yet, none
        halted); returns the indices of their transitions."""
        assert self.expander is not None
        exp = self.expander.expand(states, step)
        self.work += len(exp.dst) if exp.work is None else int(exp.work)
        self.states_expanded += len(states)
        first = self._dst.n
        ptr = np.concatenate(([0], np.cumsum(exp.counts)))
        self._src.extend(np.repeat(states, exp.counts))
        self._dst.extend(exp.dst)
        self._payoff.extend(exp.payoff)
        self._rank.extend(exp.rank)
        self._obs.extend(exp.obs)
        if exp.nis is None:
            self.reports_nis = False
            self._nis.extend(np.full(len(exp.dst), np.nan))
        else:
            self._nis.extend(exp.nis)
        self._combined.extend(combined_payoffs(ptr, exp.payoff, exp.rank))
        self._counted.extend(combined_counts(ptr, exp.payoff, exp.rank))
        self._lo.data[states] = first + ptr[:-1]
        self._hi.data[states] = first + ptr[1:]
        return np.arange(first, self._dst.n)

    def edge(self, q0: int, q1: int) -> int:
        """The transition from q0 (expanded) to q1, the first in rank order."""
        lo, hi = int(self._lo.data[q0]), int(self._hi.data[q0])
        return lo + int(np.nonzero(self._dst.data[lo:hi] == q1)[0][0])

    def obs_of(self, t: int) -> str | None:
        o = int(self._obs.data[t])
        return None if o < 0 else self.obs_names[o]

    def state_id(self, q: int) -> str:
        return f"k{int(self._step.data[q])}.{q}"

    def _grows(self) -> list[GrowArray]:
        grows = [self._step, self._S, self._cov, self._halted, self._lo, self._hi]
        more = [self._src, self._dst, self._payoff, self._rank, self._obs, self._combined]
        return [*grows, *more, self._counted, self._nis]

    def nbytes(self) -> int:
        return sum(int(g.view.nbytes) for g in self._grows())

    def capacity_bytes(self) -> int:
        """Bytes the arrays have room for: about what their next doubling copies (a
        memory budget keeps this much in reserve)."""
        return sum(int(g.data.nbytes) for g in self._grows())
