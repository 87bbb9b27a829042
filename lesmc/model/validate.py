"""Structural checks of a <PO>²-LTS, reported item by item (docs/lts-format.md)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import networkx as nx

from lesmc.errors import ModelError
from lesmc.model.lts import State, Transition


def validate_parts(
    states: Sequence[State],
    transitions: Sequence[Transition],
    initial: str,
    original: Sequence[str],
    components: Sequence[str] | None,
    path: str,
) -> nx.DiGraph:
    """Build the graph and check every rule; raise one ModelError listing all problems."""
    problems: list[tuple[str, str]] = []
    graph = nx.DiGraph()
    if not states:
        raise ModelError.many(path, [("", "the model has no states")])
    dim = len(states[0].s)
    if components is not None:
        if len(set(components)) != len(components):
            problems.append(("components", "component names must be unique"))
        dim = len(components)
    for st in states:
        item = f"state '{st.id}'"
        if st.id in graph:
            problems.append((item, "duplicate state id"))
            continue
        if len(st.s) != dim:
            problems.append((item, f"s has {len(st.s)} entries, expected {dim}"))
        if st.P is not None and st.P.shape != (dim, dim):
            problems.append((item, f"P must be {dim}x{dim}, got {'x'.join(map(str, st.P.shape))}"))
        graph.add_node(st.id, state=st)
    for i, t in enumerate(transitions):
        item = f"transition {i} ({t.src} -> {t.dst})"
        missing = [x for x in (t.src, t.dst) if x not in graph]
        if missing:
            problems.append((item, f"unknown state '{missing[0]}'"))
            continue
        ks, kd = graph.nodes[t.src]["state"].step, graph.nodes[t.dst]["state"].step
        if kd != ks + 1:
            problems.append((item, f"goes from step {ks} to step {kd}; must go to step {ks + 1}"))
        if not (math.isfinite(t.payoff) and t.payoff >= 0):
            problems.append((item, f"payoff must be finite and >= 0, got {t.payoff}"))
        if graph.has_edge(t.src, t.dst):
            problems.append((item, "a second transition between the same states"))
            continue
        graph.add_edge(t.src, t.dst, transition=t)
    if problems:
        raise ModelError.many(path, problems)
    problems.extend(_check_order(graph))
    problems.extend(_check_paths(graph, initial, original))
    if problems:
        raise ModelError.many(path, problems)
    return graph


def _check_order(graph: nx.DiGraph) -> list[tuple[str, str]]:
    """≺ must have a unique minimum per state: the transition taken when not attacked."""
    problems = []
    for sid in graph.nodes:
        ranks = [d["transition"].rank for _, _, d in graph.out_edges(sid, data=True)]
        if ranks and ranks.count(min(ranks)) > 1:
            problems.append(
                (
                    f"state '{sid}'",
                    f"{ranks.count(min(ranks))} transitions share the lowest rank "
                    f"{min(ranks)}; the unattacked successor must be unique",
                )
            )
    return problems


def _check_paths(graph: nx.DiGraph, initial: str, original: Sequence[str]) -> list[tuple[str, str]]:
    problems: list[tuple[str, str]] = []
    if initial not in graph:
        return [("initial", f"unknown state '{initial}'")]
    if graph.nodes[initial]["state"].step != 0:
        problems.append(("initial", f"state '{initial}' must be at step 0"))
    if not original:
        return [*problems, ("original", "the original path is empty")]
    if original[0] != initial:
        problems.append(("original", f"must start at the initial state '{initial}'"))
    e = len(original) - 1
    for k, sid in enumerate(original):
        if sid not in graph:
            problems.append((f"original[{k}]", f"unknown state '{sid}'"))
            return problems
        if graph.nodes[sid]["state"].step != k:
            problems.append(
                (
                    f"original[{k}]",
                    f"state '{sid}' is at step {graph.nodes[sid]['state'].step}, not {k}",
                )
            )
        if k > 0 and graph.has_edge(original[k - 1], sid):
            pick = min(
                graph.out_edges(original[k - 1], data=True), key=lambda x: x[2]["transition"].rank
            )
            if pick[1] != sid:
                problems.append(
                    (
                        f"original[{k}]",
                        f"'{sid}' is not the unattacked (rank-minimal) "
                        f"successor of '{original[k - 1]}', which is '{pick[1]}'",
                    )
                )
        elif k > 0:
            problems.append(
                (f"original[{k}]", f"no transition from '{original[k - 1]}' to '{sid}'")
            )
    reachable = nx.descendants(graph, initial) | {initial}
    for sid in graph.nodes:
        st = graph.nodes[sid]["state"]
        item = f"state '{sid}'"
        if sid not in reachable:
            problems.append((item, "not reachable from the initial state"))
        if st.step > e:
            problems.append((item, f"step {st.step} is beyond the original path's end {e}"))
        succ = graph.out_degree(sid)
        if st.halted and succ:
            problems.append((item, "is labelled halted but has successors"))
        elif not succ and st.step < e and not st.halted:
            problems.append(
                (
                    item,
                    f"has no successor before step {e}; label it 'halted' if the "
                    "tracker stopped there",
                )
            )
    return problems
