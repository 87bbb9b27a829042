"""What the unfolder needs from a tracker design: batches of states and their successors.

A design is composed of parts, as Stone Soup composes its trackers (docs/trackers.md,
"Parts"): kalman.py's predictor and updater, and from tracking/parts/ a hypothesiser
(the gate), a data associator, an initiator, deleters (the trace(P) > max_trace halt)
and the attacker's options (parts/attacker.py, every tracker's). Its states
travel in batches of arrays: the estimate X (n, d), an index into the design's
table of distinct covariances, and the halted flag; a design whose state is
more than one filter (joint) also carries the whole states as a :class:`Payload`
(arrays, gathered and stored by the unfolder without looking inside).

What derives from a filter's covariance P alone (P̂, S, S⁻¹, det S, K, the
updated P, the gate radius, the trace halts) is computed once per distinct P
(:class:`Gains`) and spread to the rows that share it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from lesmc.model.growing import GrowArray
from lesmc.scene import Scene, TrackerConfig
from lesmc.tracking.kalman import (
    Matrices,
    innovations,
    position_spread,
    predict_covariances,
    with_faults,
)
from lesmc.tracking.parts.deleter import TraceDeleter
from lesmc.tracking.parts.hypothesiser import GateHypothesiser


class CovarianceTable:
    """The distinct covariances P of a design's states, each stored once, by exact value.

    They are kept in one growing (c, d, d) array, so :meth:`stack` is a view and
    costs nothing however often the unfolder asks for it.
    """

    def __init__(self) -> None:
        self._rows: GrowArray | None = None
        self._index: dict[bytes, int] = {}

    def add(self, P: np.ndarray) -> int:
        """The index of ``P`` (added if new)."""
        key = P.tobytes()
        i = self._index.get(key)
        if i is None:
            if self._rows is None:
                self._rows = GrowArray(np.float64, P.shape)
            i = self._rows.n
            self._rows.extend(P[None])
            self._index[key] = i
        return i

    def add_many(self, Ps: np.ndarray) -> np.ndarray:
        """The indices of covariances ``Ps`` (k, d, d), the new ones appended in one go."""
        out = np.empty(len(Ps), dtype=np.int64)
        raw = np.ascontiguousarray(Ps, dtype=np.float64).tobytes()
        w = len(raw) // max(len(Ps), 1)
        fresh: list[int] = []
        n = len(self)
        for j in range(len(Ps)):
            key = raw[j * w : (j + 1) * w]
            i = self._index.get(key)
            if i is None:
                i = self._index[key] = n + len(fresh)
                fresh.append(j)
            out[j] = i
        if fresh:
            if self._rows is None:
                self._rows = GrowArray(np.float64, Ps.shape[1:])
            self._rows.extend(Ps[fresh])
        return out

    def __getitem__(self, i: int) -> np.ndarray:
        if not 0 <= i < len(self):
            raise IndexError(i)
        assert self._rows is not None
        out: np.ndarray = self._rows.data[i]
        return out

    def __len__(self) -> int:
        return 0 if self._rows is None else self._rows.n

    def stack(self) -> np.ndarray:
        """All covariances (c, d, d), as a read-only view."""
        if self._rows is None:
            return np.zeros((0, 0, 0))
        view = self._rows.view
        view.flags.writeable = False
        return view


class Payload(Protocol):
    """The whole states of a batch, for designs whose state is more than (x, P)."""

    def __len__(self) -> int: ...

    def take(self, idx: np.ndarray) -> Payload:
        """The states at positions ``idx``."""
        ...

    def store(self) -> PayloadStore:
        """An empty store for payloads of this kind."""
        ...


class PayloadStore(Protocol):
    """Where the unfolder keeps the payloads of the states it has added, in order."""

    def extend(self, payload: Payload, /) -> None: ...

    def take(self, idx: np.ndarray) -> Payload:
        """The stored states with positions ``idx``."""
        ...


@dataclass
class Batch:
    """n tracker states: estimates X (n, d), covariance indices, halted flags, and for
    designs whose state is more than one filter, the states themselves (``objects``)."""

    X: np.ndarray
    cov: np.ndarray
    halted: np.ndarray
    objects: Payload | None = None

    def __len__(self) -> int:
        return int(self.X.shape[0])

    def take(self, idx: np.ndarray) -> Batch:
        objs = None if self.objects is None else self.objects.take(idx)
        return Batch(self.X[idx], self.cov[idx], self.halted[idx], objs)


@dataclass(frozen=True)
class GainRows:
    """What derives from each row's covariance P (Eq. 2-3, the gate, the halt), over the
    rows (any shape)."""

    radius: np.ndarray  # no detection farther than this can pass the gate
    norm: np.ndarray  # 2π sqrt(det S): the likelihood N(z; Hx̂, S) is exp(−d²/2) / norm
    S_inv: np.ndarray  # (..., 2, 2)
    spread: np.ndarray  # trace(H P̂ Hᵀ): the Euclidean gate's scale
    K: np.ndarray  # (..., d, 2)
    pred: np.ndarray  # table index of P̂ (the state after a skipped update)
    post: np.ndarray  # table index of the updated P
    halt_pred: np.ndarray  # trace(P̂) > max_trace
    halt_post: np.ndarray  # trace(P⁺) > max_trace


class Gains:
    """The gain rows of every covariance of ``table``, computed once per distinct P; the
    gate radius from the design's ``hypothesiser``, the halts from its ``deleter``.

    P̂ and P⁺ are added to ``table``, so the gains of a design's next states
    are found by index. :meth:`rows` computes what is new among the indices it
    is asked for in one batch (kalman.innovations) and spreads the rows.
    """

    FIELDS = ("radius", "norm", "S_inv", "spread", "K", "pred", "post", "halt_pred", "halt_post")

    def __init__(
        self,
        m: Matrices,
        table: CovarianceTable,
        hypothesiser: GateHypothesiser,
        deleter: TraceDeleter,
    ) -> None:
        self.m = m
        self.table = table
        self.hypothesiser = hypothesiser
        self.deleter = deleter
        self.known = GrowArray(np.bool_)
        self.cols = {
            "radius": GrowArray(np.float64),
            "norm": GrowArray(np.float64),
            "S_inv": GrowArray(np.float64, (2, 2)),
            "spread": GrowArray(np.float64),
            "K": GrowArray(np.float64, (m.dim, 2)),
            "pred": GrowArray(np.int64),
            "post": GrowArray(np.int64),
            "halt_pred": GrowArray(np.bool_),
            "halt_post": GrowArray(np.bool_),
        }

    def rows(self, cov: np.ndarray) -> GainRows:
        """The gains of covariance indices ``cov`` (any shape) as arrays of that shape."""
        cs = np.unique(cov)
        old = cs[cs < self.known.n]
        new = np.concatenate([old[~self.known.data[old]], cs[cs >= self.known.n]])
        if new.size:
            self._fill(new.astype(np.int64))
        return GainRows(*(self.cols[name].data[cov] for name in self.FIELDS))

    def _fill(self, cs: np.ndarray) -> None:
        """Predict and gain (Eq. 2-3), gate radius, likelihood norm and halts of the
        covariances ``cs``, all together; P̂ and P⁺ join the table."""
        m = self.m
        P_pred = predict_covariances(m, self.table.stack()[cs])
        inn = innovations(m, P_pred)
        spread = position_spread(m, P_pred)
        values = {
            "radius": self.hypothesiser.radii(inn.S, spread),
            "norm": 2 * math.pi * np.sqrt(np.linalg.det(inn.S)),
            "S_inv": inn.S_inv,
            "spread": spread,
            "K": inn.K,
            "pred": self.table.add_many(P_pred),
            "post": self.table.add_many(inn.P_post),
            "halt_pred": self.deleter.halts(P_pred),
            "halt_post": self.deleter.halts(inn.P_post),
        }
        top = int(cs.max()) + 1
        if top > self.known.n:  # make room up to the largest (unknown rows stay marked so)
            grow = top - self.known.n
            self.known.extend(np.zeros(grow, dtype=bool))
            for col in self.cols.values():
                col.extend(np.zeros((grow, *col.data.shape[1:]), dtype=col.data.dtype))
        for name in self.FIELDS:
            self.cols[name].data[cs] = values[name]
        self.known.data[cs] = True


class Schedule:
    """The matrices and gains in force at each frame: the model's own, and from a fault's
    frame on those with the fault (section 9.2; lesmc/pipeline/faults.py). Every
    combination of active faults has its own :class:`Gains` over the one covariance table,
    so states of any phase share covariances."""

    def __init__(
        self,
        m: Matrices,
        cfg: TrackerConfig,
        table: CovarianceTable,
        hypothesiser: GateHypothesiser,
        deleter: TraceDeleter,
    ) -> None:
        self.faults = cfg.faults
        self._parts = (hypothesiser, deleter)
        self._by: dict[tuple[int, ...], tuple[Matrices, Gains]] = {
            (): (m, Gains(m, table, hypothesiser, deleter))
        }
        self._table = table

    def at(self, frame: int) -> tuple[Matrices, Gains]:
        """The matrices and gains of the transition that enters ``frame``."""
        if not self.faults:
            return self._by[()]
        active = tuple(i for i, f in enumerate(self.faults) if f.frame <= frame)
        if active not in self._by:
            m = with_faults(self._by[()][0], (self.faults[i] for i in active))
            self._by[active] = (m, Gains(m, self._table, *self._parts))
        return self._by[active]


@dataclass
class Successors:
    """Every outcome of a batch at the next frame, grouped by source and in rank order.

    ``src`` is the position of the source in the batch; ``payoff`` the
    transition's own payoff (so that Eq. 5, the sum over lower ranks, is the
    cost of forcing the outcome); ``det`` the detection used (index into the
    frame), −1 when the tracker skips the update.
    """

    src: np.ndarray
    rank: np.ndarray
    payoff: np.ndarray
    det: np.ndarray
    states: Batch
    #: the NIS yᵀ S⁻¹ y of each outcome's update (NaN: it skips the update); None: the
    #: design does not report it (the ``nis`` and ``misses`` monitors need it)
    nis: np.ndarray | None = None
    #: the work the design did for them, a count that is the same on every run and grows
    #: about as its time (lesmc/model/growing.py, ``GrowingModel.work``): the joint design
    #: counts the (state, attacker option) rows it evaluated before merging the options
    #: with equal outcomes (under inject: each hiding option × each candidate subset),
    #: times a row's tracks (each row moves them all); None: one per outcome (a
    #: single-target design moves one track an outcome)
    examined: int | None = None


class Design(Protocol):
    """A tracker design: an initial state and, per batch of states, the attacker-forced outcomes."""

    name: str
    scene: Scene
    covariances: CovarianceTable

    def initial(self) -> Batch:
        """The one state at the target's frame."""
        ...

    def successors(self, batch: Batch, step: int, attacked: bool) -> Successors:
        """Outcomes of moving every state of ``batch`` from frame ``step − 1`` to ``step``:
        all the attacker can force when ``attacked``, else only the unattacked one
        (rank 0, own payoff 0)."""
        ...

    def keys(self, batch: Batch) -> np.ndarray:
        """Exact identity of each state as a row of 64-bit words (n, w), so that
        coinciding states are shared."""
        ...
