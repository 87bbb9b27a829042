"""What the unfolder needs from a tracker design: batches of states and their successors.

A design is assembled from the parts in tracking/ (kalman.py: predictor and
updater; association.py: gate and the attacker's options; the deleter is the
trace(P) > max_trace halt), as Stone Soup composes its trackers. Its states
travel in batches of arrays: the estimate X (n, d), an index into the design's
table of distinct covariances, and the halted flag; a design whose state is
more than one filter (joint) also keeps the whole states as objects.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from lesmc.model.growing import GrowArray
from lesmc.tracking.scene import Scene


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


@dataclass
class Batch:
    """n tracker states: estimates X (n, d), covariance indices, halted flags, and for
    designs whose state is more than one filter, the states themselves (``objects``)."""

    X: np.ndarray
    cov: np.ndarray
    halted: np.ndarray
    objects: list[Any] | None = None

    def __len__(self) -> int:
        return int(self.X.shape[0])

    def take(self, idx: np.ndarray) -> Batch:
        objs = None if self.objects is None else [self.objects[int(i)] for i in idx]
        return Batch(self.X[idx], self.cov[idx], self.halted[idx], objs)


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
