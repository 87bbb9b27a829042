"""A property's question as an MDP in the PRISM language (PRISM, Storm, Modest).

The same MDP as the DRN export (lesmc/exporters/drn.py: one state per path prefix
and constraint value, the attacker's allowed choices as actions, the objective's
contribution as the action's reward, the label ``violated`` on the absorbing
state the violating leaves move to), written as one module whose variable ``s``
numbers the MDP states. Action ``a{k}`` is a state's k-th choice; the reward
model ``payoff`` rewards each (state, action). Then
``R{"payoff"}min=? [F "violated"]`` is lesmc's optimum (+inf when no path violates).

Rewards are written exactly (:func:`prism_number`): Storm's PRISM parser reads an
integer literal as a 64-bit integer, so a double whose rational form needs a larger
integer (a denominator of 2^63 or more: any reward below about 1e-3 with all 53 bits
set, every reward down to the smallest double) is written as ``m*pow(2.0,e)``.
"""

from __future__ import annotations

import math
from fractions import Fraction
from pathlib import Path
from typing import Any

from lesmc.engines.space import build_space
from lesmc.exporters.drn import (
    DRN_MAX_PREFIXES,
    REACH_PROPERTY,
    exact_number,
    not_exported_line,
    prefix_tree,
    write_mdp,
)
from lesmc.exporters.request import Request
from lesmc.language.semantics import BoundProperty
from lesmc.model.arrays import ArrayModel
from lesmc.model.multi import MultiModel

PRISM_PROPERTY = 'R{"payoff"}min=? [F "violated"]'

#: The largest integer literal Storm's PRISM parser reads ("no 64-bit integer overflow").
PRISM_INT_MAX = 2**63 - 1


def prism_number(x: float) -> str:
    """``x`` as a PRISM literal Storm reads as exactly this double's value.

    :func:`~lesmc.exporters.drn.exact_number`'s literal, unless its rational ``p/q`` has
    an integer beyond 64 bits; then ``m*pow(2.0,e)`` with m odd (|m| < 2^53), which
    Storm's exact mode evaluates exactly and double arithmetic (Storm's default mode,
    PRISM) exactly as well: m and 2^e are doubles and so is their product, ``x``.
    """
    text = exact_number(x)
    q = Fraction(x)
    if "/" not in text or max(abs(q.numerator), q.denominator) <= PRISM_INT_MAX:
        return text
    mantissa, exponent = math.frexp(x)
    m, e = int(mantissa * 2**53), exponent - 53
    while m % 2 == 0:
        m, e = m // 2, e + 1
    return f"{m}*pow(2.0,{e})"


def write_prism(model: ArrayModel, path: str | Path, request: Request) -> dict[str, object]:
    """The PRISM writer of the registry (lesmc/exporters/formats.py)."""
    return write_mdp(model, path, request, "prism", to_prism)


def to_prism(
    cm: ArrayModel, bp: BoundProperty, max_prefixes: int = DRN_MAX_PREFIXES, strict: bool = False
) -> tuple[str, dict[str, Any]]:
    """The PRISM program and facts about it (as :func:`~lesmc.exporters.drn.to_drn`)."""
    return prism_text(cm, build_space(cm, bp), bp, max_prefixes, strict)


def prism_text(
    cm: ArrayModel | MultiModel, space: Any, bp: BoundProperty, max_prefixes: int, strict: bool
) -> tuple[str, dict[str, Any]]:
    """:func:`to_prism` on the property's ``space`` of ``cm`` (as
    :func:`~lesmc.exporters.drn.drn_text`)."""
    rewards = not space.obj_max
    not_exported = None if rewards else not_exported_line(bp, strict)
    choices, labels = prefix_tree(cm, space, rewards, max_prefixes)
    facts = {
        "property": bp.name,
        "not_exported": not_exported,
        "prism": {"states": len(choices), "choices": sum(map(len, choices))},
        "prism_property": PRISM_PROPERTY if rewards else REACH_PROPERTY,
    }
    return _program(choices, labels, rewards, bp.name), facts


def _program(
    choices: list[list[tuple[float, int]]], labels: list[str], rewards: bool, name: str
) -> str:
    n = len(choices)
    lines = [
        f"// lesmc: the attacker's choices for property '{name}' of a <PO>2-LTS;",
        f"// {PRISM_PROPERTY} is lesmc's optimum"
        if rewards
        else f"// no reward model (a maximum objective): {REACH_PROPERTY} > 0 iff a path violates",
        "mdp",
        "",
        "module attack",
        f"  s : [0..{n - 1}] init 0;",
    ]
    for s, acts in enumerate(choices):
        for a, (_, target) in enumerate(acts):
            lines.append(f"  [a{a}] s={s} -> (s'={target});")
    lines += ["endmodule", ""]
    if rewards:
        lines.append('rewards "payoff"')
        entries = [
            f"  [a{a}] s={s} : {prism_number(reward)};"
            for s, acts in enumerate(choices)
            for a, (reward, _) in enumerate(acts)
            if reward != 0.0
        ]
        lines += entries or ["  true : 0;"]
        lines += ["endrewards", ""]
    violated = [str(s) for s, lab in enumerate(labels) if lab == "violated"]
    lines.append(f'label "violated" = {" | ".join(f"s={v}" for v in violated)};')
    return "\n".join(lines) + "\n"
