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
import re
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import IO, Any
from xml.sax.saxutils import escape, quoteattr

import numpy as np

from lesmc.common.errors import UsageError
from lesmc.common.files import atomic_open
from lesmc.exporters.request import DOT_MAX_NODES, Request
from lesmc.model.arrays import ArrayModel

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


#: Lines per chunk of the GraphML stream.
CHUNK_LINES = 65536

#: Characters an XML attribute or text must not hold as they are.
_XML_SPECIAL = re.compile(r"[<>&\"'\n\r\t]")


def graphml_lines(cm: ArrayModel, roles: Roles | None = None) -> Iterator[str]:
    """The model as GraphML, in chunks of whole lines (write them as they come).

    Column by column: each attribute is formatted for all states (transitions) at
    once and the lines are assembled from the columns, CHUNK_LINES at a time.
    Numbers are ``repr`` of the double (the shortest text that reads back to it;
    ``inf`` for infinity).
    """
    roles = roles or {"original": cm.original.tolist()}
    head = ['<?xml version="1.0" encoding="UTF-8"?>']
    head.append('<graphml xmlns="http://graphml.graphdrawing.org/xmlns">')
    for name, kind in _NODE_KEYS:
        head.append(f'  <key id="n_{name}" for="node" attr.name="{name}" attr.type="{kind}"/>')
    for name, kind in _EDGE_KEYS:
        head.append(f'  <key id="e_{name}" for="edge" attr.name="{name}" attr.type="{kind}"/>')
    head.append('  <graph id="lesmc" edgedefault="directed">')
    yield "\n".join(head) + "\n"
    ids = _quoted_ids(cm)
    yield from _chunks(_node_lines(cm, ids, _state_roles(roles)))
    yield from _chunks(_edge_lines(cm, ids, _edge_roles(cm, roles)))
    yield "  </graph>\n</graphml>\n"


def _quoted_ids(cm: ArrayModel) -> list[str]:
    """Every state's id as a quoted XML attribute value."""
    ids = cm.state_ids()
    if cm.ids is None or _XML_SPECIAL.search("".join(ids)) is None:
        return [f'"{i}"' for i in ids]
    return [quoteattr(i) for i in ids]


def _column(n: int, marks: Mapping[int, str], default: str) -> list[str]:
    """``default`` for each of ``n`` rows, ``marks[row]`` where given."""
    out = [default] * n
    for i, v in marks.items():
        out[i] = v
    return out


def _node_lines(cm: ArrayModel, ids: list[str], state_role: Mapping[int, str]) -> Iterator[str]:
    n = cm.n_states
    xs = cm.S[:, 0].tolist()
    ys = cm.S[:, 1].tolist() if cm.S.shape[1] >= 2 else [0.0] * n
    halted = np.where(cm.halted, "true", "false").tolist()
    role = _column(n, state_role, "other")
    rows = zip(ids, cm.step.tolist(), xs, ys, halted, role, strict=True)
    if not cm.has_covariance:
        for i, k, x, y, h, r in rows:
            yield (
                f'    <node id={i}><data key="n_step">{k}</data><data key="n_x">{x!r}</data>'
                f'<data key="n_y">{y!r}</data><data key="n_halted">{h}</data>'
                f'<data key="n_role">{r}</data></node>'
            )
        return
    assert cm.P_table is not None and cm.cov is not None
    traces = np.trace(cm.P_table, axis1=1, axis2=2)[cm.cov].tolist()
    for (i, k, x, y, h, r), tr in zip(rows, traces, strict=True):
        yield (
            f'    <node id={i}><data key="n_step">{k}</data><data key="n_x">{x!r}</data>'
            f'<data key="n_y">{y!r}</data><data key="n_halted">{h}</data>'
            f'<data key="n_role">{r}</data><data key="n_trace_P">{tr!r}</data></node>'
        )


def _edge_lines(cm: ArrayModel, ids: list[str], edge_role: Mapping[int, str]) -> Iterator[str]:
    m = cm.n_transitions
    if cm.obs is None:
        obs = [""] * m
    else:
        names = np.array([escape(o) for o in cm.obs_names] + [""], dtype=object)
        obs = names[np.where(cm.obs >= 0, cm.obs, len(names) - 1)].tolist()
    role = _column(m, edge_role, "other")
    rows = zip(
        cm.src.tolist(),
        cm.dst.tolist(),
        cm.rank.tolist(),
        cm.payoff.tolist(),
        cm.combined.tolist(),
        obs,
        role,
        strict=True,
    )
    for t, (a, b, k, p, c, o, r) in enumerate(rows):
        yield (
            f'    <edge id="t{t}" source={ids[a]} target={ids[b]}><data key="e_rank">{k}</data>'
            f'<data key="e_payoff">{p!r}</data><data key="e_combined_payoff">{c!r}</data>'
            f'<data key="e_obs">{o}</data><data key="e_role">{r}</data></edge>'
        )


def _chunks(lines: Iterator[str]) -> Iterator[str]:
    """The lines, CHUNK_LINES at a time, each chunk ending with a newline."""
    while True:
        chunk = list(itertools.islice(lines, CHUNK_LINES))
        if not chunk:
            return
        yield "\n".join(chunk) + "\n"


def write_lines(chunks: Iterable[str], fh: IO[Any]) -> None:
    """Each chunk of whole lines to ``fh`` (GraphML as a stream)."""
    for chunk in chunks:
        fh.write(chunk)


def write_dot(model: ArrayModel, path: str | Path, request: Request) -> dict[str, object]:
    """The DOT writer of the registry (lesmc/exporters/formats.py)."""
    text = to_dot(model, request.roles, request.max_nodes or DOT_MAX_NODES)
    with atomic_open(path) as fh:
        fh.write(text)
    return {}


def write_graphml(model: ArrayModel, path: str | Path, request: Request) -> dict[str, object]:
    """The GraphML writer of the registry (lesmc/exporters/formats.py)."""
    with atomic_open(path) as fh:
        write_lines(graphml_lines(model, request.roles), fh)
    return {}
