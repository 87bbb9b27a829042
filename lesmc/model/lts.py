"""The <PO>²-LTS (paper section 3.2) as a validated networkx DiGraph.

States are Bayes-filter estimates ρ_k = (s_k, P_k) at step k; a transition goes
from step k−1 to step k, carries the attack payoff of its observation and a
rank that realises the partial order ≺ among a state's outgoing transitions
(t ≺ t' iff rank(t) < rank(t')). The graph is a DAG because steps increase.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import networkx as nx
import numpy as np

HALTED = "halted"
"""Label of a state where the tracker stopped (trace(P) too large): no successors."""


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

    def combined_payoff(self, t: Transition) -> float:
        """Eq. 5 read strictly: the payoffs of the transitions ≺ t (nearer detections)."""
        return math.fsum(o.payoff for o in self.out(t.src) if o.rank < t.rank)

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
        from lesmc.model.validate import validate_parts

        if check:
            graph = validate_parts(states, transitions, initial, original, components, path)
        else:
            graph = nx.DiGraph()
            graph.add_nodes_from((st.id, {"state": st}) for st in states)
            graph.add_edges_from((t.src, t.dst, {"transition": t}) for t in transitions)
        comps = tuple(components) if components else default_components(len(states[0].s))
        return cls(comps, initial, tuple(original), graph)


def default_components(n: int) -> tuple[str, ...]:
    """Names s0, s1, ... used when a model does not name its components."""
    return tuple(f"s{i}" for i in range(n))
