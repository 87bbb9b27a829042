"""The <PO>²-LTS as arrays: what the engines check (paper section 3.2).

States are rows: step k, estimate s_k, covariance P_k (an index into a table
of the distinct covariances: in a tracker's model few histories of updates
and skips exist, so most states share theirs) and the halted flag.
Transitions are in CSR form: the out-transitions of state i are
``ptr[i]:ptr[i+1]``, sorted by rank (the partial order ≺; ties by the target's
id), each with its target, own payoff, rank and observation. State ids exist
only at the file boundary: a model read from a file keeps its ids, a model the
unfolder builds names state i ``k{step}.{i}``.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, overload

import numpy as np

from lesmc.model.kernel import combined_counts, combined_payoffs


class IdArray(Sequence[str]):
    """State ids held as one array of fixed-width UTF-8 bytes (numpy ``S``), as the
    binary form stores them: an id is decoded when it is read, so loading a model
    makes no Python string per state. Trailing NUL bytes pad an id to the width."""

    def __init__(self, raw: np.ndarray) -> None:
        self.raw = raw

    def __len__(self) -> int:
        return int(self.raw.shape[0])

    @overload
    def __getitem__(self, i: int) -> str: ...
    @overload
    def __getitem__(self, i: slice) -> list[str]: ...
    def __getitem__(self, i: int | slice) -> str | list[str]:
        if isinstance(i, slice):
            return [b.decode() for b in self.raw[i].tolist()]
        return bytes(self.raw[i]).decode()

    def __iter__(self) -> Iterator[str]:
        return (b.decode() for b in self.raw.tolist())


@dataclass(eq=False)
class Tracks:
    """Acceptable tracks besides the original path (section 4.2): ground-truth tracks of
    the scene, one row of positions per model step; NaN where a track is absent.

    ``components`` names the model components the positions give (the track's
    position, e.g. x, y); ``at`` is (tracks, steps, len(components)).
    """

    components: tuple[str, ...]
    ids: tuple[str, ...]
    at: np.ndarray

    def take(self, steps: int) -> Tracks:
        """The first ``steps`` steps."""
        return Tracks(self.components, self.ids, self.at[:, :steps])


def reference_states(model: Any) -> np.ndarray:
    """ρ̃ of Eq. 4, one state per step: the model's unattacked path, or the reference it
    carries (a fault variant's: the fault-free system's unattacked track,
    lesmc/pipeline/faults.py). Works for an ArrayModel and a GrowingModel alike."""
    ref: np.ndarray | None = model.reference
    return model.S[model.original] if ref is None else ref


@dataclass(eq=False)
class ArrayModel:
    """A validated <PO>²-LTS; ``original`` is the unattacked path, one state per step 0..e."""

    components: tuple[str, ...]
    step: np.ndarray  # (n,) int64
    S: np.ndarray  # (n, d) float64 state estimates
    halted: np.ndarray  # (n,) bool
    ptr: np.ndarray  # (n+1,) int64 CSR offsets
    dst: np.ndarray  # (m,) int64
    payoff: np.ndarray  # (m,) float64, own payoff of each transition
    rank: np.ndarray  # (m,) int64
    original: np.ndarray  # (e+1,) int64 state indices
    cov: np.ndarray | None = None  # (n,) int64 index into P_table, −1: no P; None: none at all
    P_table: np.ndarray | None = None  # (c, d, d)
    obs: np.ndarray | None = None  # (m,) int64 index into obs_names, −1 = no observation
    obs_names: tuple[str, ...] = ()
    ids: Sequence[str] | None = None  # a list, or an IdArray read from the binary form
    labels: dict[int, tuple[str, ...]] = field(default_factory=dict)  # other than "halted"
    meta: dict[str, Any] = field(default_factory=dict)
    #: (steps, d) the states deviations are measured against (Eq. 4's ρ̃); None: S[original]
    reference: np.ndarray | None = None
    #: ground-truth tracks ``dist.nearest`` also accepts (section 4.2); None: none
    tracks: Tracks | None = None
    #: (m,) float64: the normalised innovation squared of each transition's update, NaN
    #: where it takes none (what the ``nis`` and ``misses`` monitors read); None: not known
    nis: np.ndarray | None = None

    @property
    def n_states(self) -> int:
        return int(self.step.shape[0])

    @property
    def n_transitions(self) -> int:
        return int(self.dst.shape[0])

    @property
    def end(self) -> int:
        """e: the last step of the original path."""
        return int(self.original.shape[0]) - 1

    @property
    def initial(self) -> int:
        return int(self.original[0])

    @cached_property
    def has_covariance(self) -> bool:
        """Every state has its covariance P (the runtime monitor needs it)."""
        return self.cov is not None and bool((self.cov >= 0).all())

    @cached_property
    def combined(self) -> np.ndarray:
        """Eq. 5 per transition (the kernel's :func:`~lesmc.model.kernel.combined_payoffs`)."""
        return combined_payoffs(self.ptr, self.payoff, self.rank)

    @cached_property
    def counted(self) -> np.ndarray:
        """Eq. 5 over unit payoffs per transition: the outcomes hidden (``count``)."""
        return combined_counts(self.ptr, self.payoff, self.rank)

    @cached_property
    def src(self) -> np.ndarray:
        """The source state of each transition."""
        return np.repeat(np.arange(self.n_states, dtype=np.int64), np.diff(self.ptr))

    def P(self, states: np.ndarray | int) -> np.ndarray:
        """Covariances of the given states (n, d, d) or of one state (d, d)."""
        if self.cov is None or self.P_table is None:
            raise ValueError("the model has no covariances")
        out: np.ndarray = self.P_table[self.cov[states]]
        return out

    def state_id(self, i: int) -> str:
        """The id of state ``i``: from the file, else ``k{step}.{i}``."""
        if self.ids is not None:
            return self.ids[i]
        return f"k{int(self.step[i])}.{i}"

    def state_ids(self) -> list[str]:
        """Every state's id (:meth:`state_id`), made at once."""
        if isinstance(self.ids, list):
            return self.ids
        return list(self.ids) if self.ids is not None else self.default_ids()

    def default_ids(self) -> list[str]:
        """The ids ``k{step}.{i}`` a model without ids has."""
        return [f"k{k}.{i}" for i, k in enumerate(self.step.tolist())]

    @cached_property
    def _index(self) -> dict[str, int]:
        return {self.state_id(i): i for i in range(self.n_states)}

    def index(self, sid: str) -> int:
        """The row of the state with id ``sid`` (KeyError if none)."""
        return self._index[sid]

    def obs_of(self, t: int) -> str | None:
        """The observation of transition ``t`` (None: the tracker skipped the update)."""
        if self.obs is None:
            return None
        o = int(self.obs[t])
        return None if o < 0 else self.obs_names[o]

    def out(self, i: int) -> range:
        """The out-transitions of state ``i``, in rank order."""
        return range(int(self.ptr[i]), int(self.ptr[i + 1]))

    def edge(self, q0: int, q1: int) -> int:
        """The transition from q0 to q1 (the first in rank order)."""
        lo, hi = int(self.ptr[q0]), int(self.ptr[q0 + 1])
        hits = np.nonzero(self.dst[lo:hi] == q1)[0]
        if not hits.size:
            raise KeyError(f"no transition {self.state_id(q0)} -> {self.state_id(q1)}")
        return lo + int(hits[0])

    def nbytes(self) -> int:
        """Memory held by the model's arrays (ids and names excluded)."""
        arrays = [self.step, self.S, self.halted, self.ptr, self.dst, self.payoff, self.rank]
        arrays += [a for a in (self.cov, self.P_table, self.obs) if a is not None]
        return sum(int(a.nbytes) for a in arrays) + int(self.original.nbytes)
