"""A property's question as an MDP in Storm's explicit DRN format.

Storm and PRISM minimise expected rewards until a target; lesmc minimises a
payoff over the paths that satisfy a constraint (section 4). The two meet on a
tree of path prefixes: a state of the MDP is an LTS state together with the
constraint's value accumulated so far (prefixes that agree on both have the
same futures and are one MDP state); each allowed transition (the runtime
monitor's cuts and the property's window applied, as the engines apply them:
lesmc/engines/space.py) is an action whose reward is its objective
contribution (the combined payoff of Eq. 5 inside the window, 0 outside); a
leaf whose completed path satisfies the constraint moves to the absorbing
state labelled ``violated`` with the tail's objective as reward, any other
leaf loops on itself. Then Storm's ``Rmin=? [F "violated"]`` is the optimum
lesmc computes (+inf when no path violates). Only objectives that add up along
the path (payoff, payoff.mean) have this form: a dist.max objective is refused.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from fractions import Fraction
from pathlib import Path
from typing import Any

from lesmc.common.errors import UsageError
from lesmc.common.files import atomic_open
from lesmc.engines.check import bind_all
from lesmc.engines.space import build_space
from lesmc.exporters.request import MDP_MAX_PREFIXES, Request, chosen_property
from lesmc.language.properties import SpecFile
from lesmc.language.semantics import BoundProperty
from lesmc.model.arrays import ArrayModel
from lesmc.model.multi import MultiModel

#: Path prefixes (MDP states) the export may unfold by default.
DRN_MAX_PREFIXES = MDP_MAX_PREFIXES

#: What Storm answers on an MDP without its reward model (a dist.max objective): whether
#: some path violates, that is whether lesmc's optimum is finite (> 0: it is).
REACH_PROPERTY = 'Pmax=? [F "violated"]'

#: Writes an MDP's text and facts (:func:`to_drn`, :func:`lesmc.exporters.prism.to_prism`).
MdpText = Callable[[ArrayModel, BoundProperty, int, bool], tuple[str, dict[str, Any]]]


def write_drn(model: ArrayModel, path: str | Path, request: Request) -> dict[str, object]:
    """The DRN writer of the registry (lesmc/exporters/formats.py)."""
    return write_mdp(model, path, request, "drn", to_drn)


def write_mdp(
    model: ArrayModel, path: str | Path, request: Request, fmt: str, text: MdpText
) -> dict[str, object]:
    """Write the MDP of the request's property as ``text`` makes it; its facts."""
    bp = mdp_property(model, request.spec, request.prop, fmt)
    out, facts = text(model, bp, request.max_nodes or MDP_MAX_PREFIXES, request.strict)
    with atomic_open(path) as fh:
        fh.write(out)
    return facts


def mdp_property(
    model: ArrayModel, spec: SpecFile | None, prop: str | None, fmt: str
) -> BoundProperty:
    """The one property of ``spec`` an MDP export states (``prop``, or the only one)."""
    if spec is None:
        raise UsageError(f"--format {fmt} exports a property: give --spec (and --property)")
    return chosen_property(bind_all(model, [spec]), spec.path, prop)


def exact_number(x: float) -> str:
    """``x`` as a literal Storm and PRISM read as exactly this double's value.

    Its shortest decimal (``repr``) when that decimal is the double's exact value
    (integers, 0.5, 2.375), else the rational ``p/q`` with q a power of two: Storm's
    exact mode then computes with the numbers lesmc computed with, not with their
    nearest decimals (``0.1`` read exactly is 1/10, which no double is).
    """
    if x == int(x) and abs(x) < 2.0**53:
        return str(int(x))
    q = Fraction(x)
    return repr(x) if Fraction(repr(x)) == q else f"{q.numerator}/{q.denominator}"


def to_drn(
    cm: ArrayModel, bp: BoundProperty, max_prefixes: int = DRN_MAX_PREFIXES, strict: bool = False
) -> tuple[str, dict[str, Any]]:
    """The DRN text and facts about it (states, choices, the property, what is left out).

    A maximum objective (dist.max) is no sum of rewards: the MDP and its ``violated``
    label are written without the reward model (``not_exported`` says so), or with
    ``strict`` the export is refused."""
    return drn_text(cm, build_space(cm, bp), bp, max_prefixes, strict)


def drn_text(
    cm: ArrayModel | MultiModel, space: Any, bp: BoundProperty, max_prefixes: int, strict: bool
) -> tuple[str, dict[str, Any]]:
    """:func:`to_drn` on the property's ``space`` of ``cm`` (lesmc/engines/space.py's, or
    a multi-target model's: lesmc/exporters/multi.py)."""
    rewards = not space.obj_max
    not_exported = None if rewards else not_exported_line(bp, strict)
    choices, labels = prefix_tree(cm, space, rewards, max_prefixes)
    text = _drn(choices, labels, rewards)
    facts = {
        "property": bp.name,
        "not_exported": not_exported,
        "drn": {"states": len(choices), "choices": sum(map(len, choices))},
        "storm_property": 'Rmin=? [F "violated"]' if rewards else REACH_PROPERTY,
        "prism_property": 'R{"payoff"}min=? [F "violated"]' if rewards else REACH_PROPERTY,
    }
    return text, facts


def not_exported_line(bp: BoundProperty, strict: bool) -> str:
    """What a DRN export of a dist.max objective leaves out (refused with ``strict``)."""
    what = (
        f"property '{bp.name}': the objective {bp.objective.text} is a maximum over steps, "
        "not a sum of rewards (Storm's reward properties cannot state it)"
    )
    if strict:
        raise UsageError(f"{what}: not exported (--strict)")
    return (
        f"{what}: the MDP and its label 'violated' are written, the reward model is not; "
        f"{REACH_PROPERTY} > 0 says whether some path violates (its objective may still "
        "be +inf, e.g. a deleted track's deviation)"
    )


def prefix_tree(
    cm: ArrayModel | MultiModel, space: Any, rewards: bool, max_prefixes: int
) -> tuple[list[list[tuple[float, int]]], list[str]]:
    """The MDP: per state its actions (reward, target) and its label; state 0 is the
    root, state 1 the absorbing ``violated`` state."""
    index: dict[tuple[int, float], int] = {}
    choices: list[list[tuple[float, int]]] = []  # per MDP state: (reward, target)
    labels: list[str] = []
    todo: list[tuple[int, int, float]] = []

    def state(q: int, con: float) -> int:
        got = index.get((q, con))
        if got is None:
            if len(index) >= max_prefixes:
                raise UsageError(
                    f"more than {max_prefixes} path prefixes: raise --max-nodes, or export a "
                    "model with a narrower attack window"
                )
            got = index[(q, con)] = len(choices)
            choices.append([])
            labels.append("")
            todo.append((got, q, con))
        return got

    state(int(space.root), float(space.root_con))
    goal = len(choices)  # absorbing, labelled violated (unreachable when nothing violates)
    choices.append([])
    labels.append("violated")
    while todo:
        s, q, con = todo.pop()
        if space.is_leaf(q):
            to, tc = space.tail(q)
            if space.violates(space.agg(space.con_max, con, tc)) and math.isfinite(to):
                choices[s].append((float(to), goal))
            continue
        for t in space.successors(q):
            reward = float(space.c_obj[t]) if rewards else 0.0
            if not math.isfinite(reward):
                continue  # a detection the attack cannot hide: no such choice
            nxt = state(int(cm.dst[t]), space.agg(space.con_max, con, float(space.c_con[t])))
            choices[s].append((reward, nxt))
    for s, acts in enumerate(choices):
        if s == goal or not acts:
            choices[s] = [(0.0, s)]  # absorbing
    return choices, labels


def _drn(choices: list[list[tuple[float, int]]], labels: list[str], rewards: bool) -> str:
    question = (
        'Rmin=? [F "violated"] is the optimum'
        if rewards
        else f"no reward model (a maximum objective): {REACH_PROPERTY} > 0 iff a path violates"
    )
    lines = [
        f"// lesmc: the attacker's choices of a <PO>2-LTS; {question}",
        "@type: MDP",
        "@parameters",
        "",
        "@reward_models",
        "payoff" if rewards else "",
        "@nr_states",
        str(len(choices)),
        "@nr_choices",
        str(sum(map(len, choices))),
        "@model",
    ]
    for s, acts in enumerate(choices):
        tags = " ".join(t for t in (("init" if s == 0 else ""), labels[s]) if t)
        lines.append(f"state {s}" + (f" {tags}" if tags else ""))
        for a, (reward, target) in enumerate(acts):
            lines.append(f"\taction {a} [{exact_number(reward)}]" if rewards else f"\taction {a}")
            lines.append(f"\t\t{target} : 1")
    return "\n".join(lines) + "\n"
