"""A model out to other tools: Graphviz DOT, GraphML (Gephi, yEd, networkx) and JSON.

Every state carries its step, position (the first two components), halting and
covariance trace; every transition its rank (the partial order ≺), own payoff,
combined payoff (Eq. 5, from the kernel) and observation. Paths named by a
results file (counterexample, witness) are marked: in DOT by colour and pen
width, in GraphML by the ``role`` attribute. GraphML is written as a stream
(one line at a time), so a model of any size can be exported; DOT refuses
models above ``max_nodes`` states (Graphviz cannot lay out hundreds of
thousands), a limit the user can raise.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Iterator, Mapping, Sequence
from typing import IO, Any
from xml.sax.saxutils import escape, quoteattr

import numpy as np

from lesmc.common.errors import UsageError
from lesmc.model.arrays import ArrayModel

#: DOT's default size limit (states): Graphviz lays out a few thousand nodes readably.
DOT_MAX_NODES = 5000

#: How each role is drawn in DOT: colour, pen width.
ROLE_STYLE = {"original": ("black", 2.0), "counterexample": ("red", 3.0), "witness": ("blue", 3.0)}

Roles = Mapping[str, Sequence[int]]  # role -> the states of its path (rows)


def _fmt(x: float) -> str:
    """A number as JSON and XML readers take it (``inf`` for infinity)."""
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return repr(float(x))


def _edge_roles(cm: ArrayModel, roles: Roles) -> dict[int, str]:
    """Transition -> the most important role whose path uses it."""
    out: dict[int, str] = {}
    for role in ("original", "witness", "counterexample"):  # later ones win
        path = roles.get(role, ())
        for a, b in itertools.pairwise(path):
            out[cm.edge(int(a), int(b))] = role
    return out


def _state_roles(roles: Roles) -> dict[int, str]:
    out: dict[int, str] = {}
    for role in ("original", "witness", "counterexample"):
        for q in roles.get(role, ()):
            out[int(q)] = role
    return out


def _trace(cm: ArrayModel, q: int) -> float | None:
    if not cm.has_covariance:
        return None
    return float(np.trace(cm.P(q)))


def to_dot(cm: ArrayModel, roles: Roles | None = None, max_nodes: int = DOT_MAX_NODES) -> str:
    """The model as a Graphviz digraph (left to right, one rank per step)."""
    if cm.n_states > max_nodes:
        raise UsageError(
            f"the model has {cm.n_states} states, more than --max-nodes {max_nodes}: Graphviz "
            "cannot lay it out readably; raise the limit or export GraphML"
        )
    roles = roles or {"original": cm.original.tolist()}
    edge_role, state_role = _edge_roles(cm, roles), _state_roles(roles)
    combined = cm.combined
    lines = ["digraph lesmc {", "  rankdir=LR;", "  node [shape=box, fontsize=10];"]
    for step in range(cm.end + 1):
        members = np.flatnonzero(cm.step == step)
        lines.append("  { rank=same; " + " ".join(f"s{q};" for q in members.tolist()) + " }")
    for q in range(cm.n_states):
        x, y = (float(v) for v in cm.S[q, :2]) if cm.S.shape[1] >= 2 else (float(cm.S[q, 0]), 0.0)
        label = f"{cm.state_id(q)}\\nstep {int(cm.step[q])}\\n({x:.4g}, {y:.4g})"
        attrs = [f'label="{_dot_text(label)}"']
        if cm.halted[q]:
            attrs.append("style=dashed")
        role = state_role.get(q)
        if role is not None:
            colour, width = ROLE_STYLE[role]
            attrs += [f"color={colour}", f"penwidth={width}"]
        lines.append(f"  s{q} [{', '.join(attrs)}];")
    for t in range(cm.n_transitions):
        src, dst = int(cm.src[t]), int(cm.dst[t])
        obs = cm.obs_of(t) or "-"
        label = f"r{int(cm.rank[t])} {obs}\\nφ={_fmt(float(combined[t]))}"
        attrs = [f'label="{_dot_text(label)}"', "fontsize=8"]
        role = edge_role.get(t)
        if role is not None:
            colour, width = ROLE_STYLE[role]
            attrs += [f"color={colour}", f"penwidth={width}"]
        lines.append(f"  s{src} -> s{dst} [{', '.join(attrs)}];")
    lines.append("}")
    return "\n".join(lines) + "\n"


def _dot_text(text: str) -> str:
    return text.replace('"', '\\"')


_NODE_KEYS = (
    ("step", "int"),
    ("x", "double"),
    ("y", "double"),
    ("halted", "boolean"),
    ("trace_P", "double"),
    ("role", "string"),
)
_EDGE_KEYS = (
    ("rank", "int"),
    ("payoff", "double"),
    ("combined_payoff", "double"),
    ("obs", "string"),
    ("role", "string"),
)


def graphml_lines(cm: ArrayModel, roles: Roles | None = None) -> Iterator[str]:
    """The model as GraphML, one line at a time (write them as they come)."""
    roles = roles or {"original": cm.original.tolist()}
    edge_role, state_role = _edge_roles(cm, roles), _state_roles(roles)
    yield '<?xml version="1.0" encoding="UTF-8"?>'
    yield '<graphml xmlns="http://graphml.graphdrawing.org/xmlns">'
    for name, kind in _NODE_KEYS:
        yield f'  <key id="n_{name}" for="node" attr.name="{name}" attr.type="{kind}"/>'
    for name, kind in _EDGE_KEYS:
        yield f'  <key id="e_{name}" for="edge" attr.name="{name}" attr.type="{kind}"/>'
    yield '  <graph id="lesmc" edgedefault="directed">'
    combined = cm.combined
    two = cm.S.shape[1] >= 2
    for q in range(cm.n_states):
        data = {
            "step": str(int(cm.step[q])),
            "x": _fmt(float(cm.S[q, 0])),
            "y": _fmt(float(cm.S[q, 1])) if two else "0.0",
            "halted": "true" if cm.halted[q] else "false",
            "role": state_role.get(q, "other"),
        }
        trace = _trace(cm, q)
        if trace is not None:
            data["trace_P"] = _fmt(trace)
        yield f"    <node id={quoteattr(cm.state_id(q))}>" + _data("n", data) + "</node>"
    for t in range(cm.n_transitions):
        data = {
            "rank": str(int(cm.rank[t])),
            "payoff": _fmt(float(cm.payoff[t])),
            "combined_payoff": _fmt(float(combined[t])),
            "obs": cm.obs_of(t) or "",
            "role": edge_role.get(t, "other"),
        }
        src, dst = cm.state_id(int(cm.src[t])), cm.state_id(int(cm.dst[t]))
        yield (
            f'    <edge id="t{t}" source={quoteattr(src)} target={quoteattr(dst)}>'
            + _data("e", data)
            + "</edge>"
        )
    yield "  </graph>"
    yield "</graphml>"


def _data(prefix: str, values: Mapping[str, str]) -> str:
    return "".join(f'<data key="{prefix}_{k}">{escape(v)}</data>' for k, v in values.items())


def write_lines(lines: Iterable[str], fh: IO[Any]) -> None:
    """Each line and a newline to ``fh`` (GraphML as a stream)."""
    for line in lines:
        fh.write(line + "\n")
