"""What the unfolder needs from a tracker design: batches of states and their successors.

A design is assembled from the parts in tracking/ (kalman.py: predictor and
updater; association.py: gate and the attacker's options; the deleter is the
trace(P) > max_trace halt), as Stone Soup composes its trackers. Its states
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
from lesmc.tracking.association import gate_radius
from lesmc.tracking.kalman import Innovation, Matrices, innovation
from lesmc.tracking.scene import Scene, TrackerConfig


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
class Gain:
    """Everything that depends on a filter's covariance P only (Eq. 2-3, the gate, the halt)."""

    P_pred: np.ndarray
    inn: Innovation
    radius: float
    norm: float  # 2π sqrt(det S): the likelihood N(z; Hx̂, S) is exp(−d²/2) / norm
    pred: int  # table index of P̂ (the state after a skipped update)
    post: int  # table index of the updated P
    halt_pred: bool  # trace(P̂) > max_trace
    halt_post: bool  # trace(P⁺) > max_trace


@dataclass(frozen=True)
class GainRows:
    """The :class:`Gain` of each row's covariance, as arrays over the rows (any shape)."""

    radius: np.ndarray
    norm: np.ndarray
    S_inv: np.ndarray  # (..., 2, 2)
    P_pred: np.ndarray  # (..., 4, 4)
    K: np.ndarray  # (..., 4, 2)
    pred: np.ndarray
    post: np.ndarray
    halt_pred: np.ndarray
    halt_post: np.ndarray


class Gains:
    """The :class:`Gain` of every covariance of ``table``, computed once per distinct P.

    P̂ and P⁺ are added to ``table``, so the gains of a design's next states
    are found by index. :meth:`rows` spreads them to rows of covariance indices.
    """

    FIELDS = ("radius", "norm", "S_inv", "P_pred", "K", "pred", "post", "halt_pred", "halt_post")

    def __init__(self, m: Matrices, cfg: TrackerConfig, table: CovarianceTable) -> None:
        self.m = m
        self.cfg = cfg
        self.table = table
        self._gains: dict[int, Gain] = {}
        self.known = GrowArray(np.bool_)
        self.cols = {
            "radius": GrowArray(np.float64),
            "norm": GrowArray(np.float64),
            "S_inv": GrowArray(np.float64, (2, 2)),
            "P_pred": GrowArray(np.float64, (4, 4)),
            "K": GrowArray(np.float64, (4, 2)),
            "pred": GrowArray(np.int64),
            "post": GrowArray(np.int64),
            "halt_pred": GrowArray(np.bool_),
            "halt_post": GrowArray(np.bool_),
        }

    def gain(self, c: int) -> Gain:
        """Predict and gain for the covariance with table index ``c`` (computed once)."""
        g = self._gains.get(c)
        if g is None:
            m, cfg = self.m, self.cfg
            P = self.table[c]
            P_pred = m.F @ P @ m.F.T + m.Q
            inn = innovation(m, P_pred)
            g = Gain(
                P_pred,
                inn,
                gate_radius(inn, P_pred, cfg.gate, cfg.gate_type),
                2 * math.pi * math.sqrt(float(np.linalg.det(inn.S))),
                self.table.add(P_pred),
                self.table.add(inn.P_post),
                float(np.trace(P_pred)) > cfg.max_trace,
                float(np.trace(inn.P_post)) > cfg.max_trace,
            )
            self._gains[c] = g
        return g

    def rows(self, cov: np.ndarray) -> GainRows:
        """The gains of covariance indices ``cov`` (any shape) as arrays of that shape."""
        for c in np.unique(cov).tolist():
            if c >= self.known.n or not self.known.data[c]:
                self._put(c, self.gain(c))
        return GainRows(*(self.cols[name].data[cov] for name in self.FIELDS))

    def _put(self, c: int, g: Gain) -> None:
        if c >= self.known.n:  # make room up to c (unknown rows stay marked so)
            grow = c + 1 - self.known.n
            self.known.extend(np.zeros(grow, dtype=bool))
            for col in self.cols.values():
                col.extend(np.zeros((grow, *col.data.shape[1:]), dtype=col.data.dtype))
        values = (
            g.radius,
            g.norm,
            g.inn.S_inv,
            g.P_pred,
            g.inn.K,
            g.pred,
            g.post,
            g.halt_pred,
            g.halt_post,
        )
        for name, v in zip(self.FIELDS, values, strict=True):
            self.cols[name].data[c] = v
        self.known.data[c] = True


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


def make_design(scene: Scene) -> Design:
    """The design the scene's tracker configuration names."""
    from lesmc.tracking.joint import JointDesign
    from lesmc.tracking.single import SingleDesign

    if scene.tracker.design == "joint":
        return JointDesign(scene)
    return SingleDesign(scene)
