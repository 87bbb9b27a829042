"""The <PO>²-LTS (paper section 3.2) as a validated networkx DiGraph.

States are Bayes-filter estimates ρ_k = (s_k, P_k) at step k; a transition goes
from step k−1 to step k, carries the attack payoff of its observation and a
rank that realises the partial order ≺ among a state's outgoing transitions
(t ≺ t' iff rank(t) < rank(t')). The graph is a DAG because steps increase.

This is the object view of a model (the HTML report and the scene builder use
it); the engines and the file format work on
:class:`~lesmc.model.arrays.ArrayModel`. :func:`to_arrays` and :func:`to_lts`
convert between the two.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import networkx as nx
import numpy as np

from lesmc.model.validate import HALTED, Parts, build, default_components

if TYPE_CHECKING:
    from lesmc.model.arrays import ArrayModel

__all__ = ["HALTED", "LTS", "State", "Transition", "default_components", "to_arrays", "to_lts"]


@dataclass(frozen=True, eq=False)
class State:
    """A state ρ_k = (s_k, P_k) of the LTS (section 3.3)."""

    id: str
    step: int
    s: np.ndarray
    P: np.ndarray | None = None
    labels: frozenset[str] = frozenset()

    @property
    def halted(self) -> bool:
        return HALTED in self.labels


@dataclass(frozen=True)
class Transition:
    """A transition (ρ_{k−1}, ρ_k): its own payoff and its rank in ≺."""

    src: str
    dst: str
    payoff: float
    rank: int
    obs: str | None = None


@dataclass
class LTS:
    """A validated <PO>²-LTS with its original (unattacked) path.

    ``graph`` nodes carry ``state`` (a :class:`State`), edges carry
    ``transition`` (a :class:`Transition`). Build one with :meth:`from_parts`,
    which validates; do not mutate the graph afterwards.
    """

    components: tuple[str, ...]
    initial: str
    original: tuple[str, ...]
    graph: nx.DiGraph = field(repr=False)
    meta: dict[str, Any] = field(default_factory=dict)
    """Free-form provenance (e.g. the builder's window); written to and read from files."""

    @property
    def end(self) -> int:
        """e: the last step of the original path."""
        return len(self.original) - 1

    @property
    def has_covariance(self) -> bool:
        return all(self.state(q).P is not None for q in self.graph.nodes)

    def state(self, sid: str) -> State:
        state: State = self.graph.nodes[sid]["state"]
        return state

    def states(self) -> Iterable[State]:
        for sid in self.graph.nodes:
            yield self.graph.nodes[sid]["state"]

    def out(self, sid: str) -> list[Transition]:
        """Outgoing transitions of ``sid`` in rank order (ties by target id)."""
        ts = [d["transition"] for _, _, d in self.graph.out_edges(sid, data=True)]
        return sorted(ts, key=lambda t: (t.rank, t.dst))

    def transitions(self) -> Iterable[Transition]:
        for _, _, d in self.graph.edges(data=True):
            yield d["transition"]

    @classmethod
    def from_parts(
        cls,
        states: Sequence[State],
        transitions: Sequence[Transition],
        initial: str,
        original: Sequence[str],
        components: Sequence[str] | None = None,
        path: str = "<model>",
        check: bool = True,
    ) -> LTS:
        """Assemble and validate a model; raise ModelError listing every problem.

        ``check=False`` skips validation: only for models lesmc builds itself,
        whose construction guarantees the rules (tests validate them anyway).
        """
        if check:
            build(_parts(states, transitions, initial, original, components), path)
        graph = nx.DiGraph()
        graph.add_nodes_from((st.id, {"state": st}) for st in states)
        graph.add_edges_from((t.src, t.dst, {"transition": t}) for t in transitions)
        comps = tuple(components) if components else default_components(len(states[0].s))
        return cls(comps, initial, tuple(original), graph)


def to_arrays(lts: LTS) -> ArrayModel:
    """The array model of an LTS (validated; rows in (step, id) order, ids kept)."""
    states = list(lts.states())
    parts = _parts(states, list(lts.transitions()), lts.initial, lts.original, lts.components)
    parts.meta = lts.meta
    return build(parts, "<model>")


def to_lts(model: ArrayModel) -> LTS:
    """The object view of an array model (not re-validated: the model is)."""
    n = model.n_states
    ids = model.state_ids()
    step = model.step.tolist()
    labels: list[frozenset[str]] = [frozenset()] * n
    for i, labs in model.labels.items():
        labels[i] = frozenset(labs)
    for i in np.flatnonzero(model.halted).tolist():
        labels[i] = labels[i] | {HALTED}
    cov = model.cov.tolist() if model.cov is not None else [-1] * n
    table = model.P_table if model.P_table is not None else np.zeros((0, 0, 0))
    states = [
        State(ids[i], step[i], model.S[i], table[cov[i]] if cov[i] >= 0 else None, labels[i])
        for i in range(n)
    ]
    obs = [model.obs_of(t) for t in range(model.n_transitions)]
    trans = [
        Transition(ids[a], ids[b], p, r, o)
        for a, b, p, r, o in zip(
            model.src.tolist(),
            model.dst.tolist(),
            model.payoff.tolist(),
            model.rank.tolist(),
            obs,
            strict=True,
        )
    ]
    original = [ids[q] for q in model.original.tolist()]
    lts = LTS.from_parts(states, trans, original[0], original, model.components, check=False)
    lts.meta = model.meta
    return lts


def _parts(
    states: Sequence[State],
    transitions: Sequence[Transition],
    initial: str,
    original: Sequence[str],
    components: Sequence[str] | None,
) -> Parts:
    """The columns of a model given as objects, for :func:`~lesmc.model.validate.build`."""
    s = [np.asarray(st.s, dtype=np.float64).reshape(-1) for st in states]
    Ps = [None if st.P is None else np.asarray(st.P, dtype=np.float64) for st in states]
    shape = [(-1, -1) if P is None else _shape2(P) for P in Ps]
    present = [P.reshape(-1) for P in Ps if P is not None]
    labels = {}
    for i, st in enumerate(states):
        other = st.labels - {HALTED}
        if other:
            labels[i] = tuple(sorted(other))
    obs = [t.obs for t in transitions]
    return Parts(
        ids=[st.id for st in states],
        step=np.array([st.step for st in states], dtype=np.int64).reshape(-1),
        s_len=np.array([v.shape[0] for v in s], dtype=np.int64).reshape(-1),
        s_flat=np.concatenate(s) if s else np.zeros(0),
        P_shape=np.array(shape, dtype=np.int64).reshape(-1, 2),
        P_flat=np.concatenate(present) if present else np.zeros(0),
        halted=np.array([st.halted for st in states], dtype=bool).reshape(-1),
        labels=labels,
        src=[t.src for t in transitions],
        dst=[t.dst for t in transitions],
        payoff=np.array([t.payoff for t in transitions], dtype=np.float64).reshape(-1),
        rank=np.array([t.rank for t in transitions], dtype=np.int64).reshape(-1),
        obs=obs if any(o is not None for o in obs) else None,
        initial=initial,
        original=list(original),
        components=list(components) if components is not None else None,
    )


def _shape2(P: np.ndarray) -> tuple[int, int]:
    """Rows and columns of a P (a P that is not a matrix gets a shape that fails the check)."""
    if P.ndim == 2:
        return int(P.shape[0]), int(P.shape[1])
    return int(P.size), 0
