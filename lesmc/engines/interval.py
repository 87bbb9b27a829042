"""Verdicts from two payoff sets: certified lower bounds and attack payoffs (docs/semantics.md).

Domain-free: it only combines two results of the same property, one checked
with every payoff replaced by a lower bound of the true cheapest attack
(``certified``), one with the payoffs an attack achieved (``attack``, upper
bounds). When lowering payoffs can only lower the optimum (``monotone``: the
constraint does not demand a *large* payoff), the true optimum lies in
[certified optimum, attack optimum]:

- ``holds`` iff the certified result holds: proven against every attack;
- ``violated`` iff the attack result is violated, with its counterexample;
- ``unknown`` otherwise, with the interval.
"""

from __future__ import annotations

import math
from dataclasses import replace

from lesmc.engines.result import CheckResult, Verdict
from lesmc.language.semantics import BoundProperty


def payoff_monotone(bp: BoundProperty) -> bool:
    """Lowering payoffs can only lower the optimum: true unless the constraint asks for a
    large payoff (``subject to payoff > c``), which lower payoffs can make false."""
    return not (bp.constraint.declared.reads_payoffs and bp.op in (">", ">="))


def combine(certified: CheckResult, attack: CheckResult, monotone: bool = True) -> CheckResult:
    """The interval verdict of one property from its certified and attack results."""
    verdict: Verdict
    if attack.verdict == "violated":
        verdict = "violated"
    elif certified.verdict == "holds" and monotone:
        verdict = "holds"
    else:
        verdict = "unknown"
    notes = [f"attack payoffs: {n}" for n in attack.notes]
    notes += [f"certified payoffs: {n}" for n in certified.notes]
    if not monotone:
        notes.append(
            "the constraint asks for a large payoff: lower payoffs do not bound the optimum "
            "from below, so 'holds' cannot be proven with certified payoffs"
        )
    if verdict == "unknown":
        notes.append(
            f"the optimum lies between the certified {_fmt(certified.lower)} and the "
            f"attack's {_fmt(attack.upper)}; the threshold {attack.threshold:g} is inside"
        )
    elif certified.lower != attack.upper:
        notes.append(
            f"the optimum against every attack lies between the certified "
            f"{_fmt(certified.lower)} and the attack's {_fmt(attack.upper)}"
        )
    lower = certified.lower if monotone else -math.inf
    # ``optimum``: the counterexample's cost when violated; the optimum itself when both
    # payoff sets agree on it (None: no path violates under either); else unknown, and
    # the interval [lower, upper] is what is known (``null`` never stands for "unknown")
    point = lower == attack.upper and certified.optimum_known and attack.optimum_known
    if verdict == "violated":
        optimum, known = attack.optimum, attack.optimum_known
    elif point:
        optimum, known = attack.optimum, True
    else:
        optimum, known = None, False
    return replace(
        attack,
        verdict=verdict,
        optimum=optimum,
        optimum_known=known,
        lower=lower,
        upper=attack.upper,
        notes=notes,
        payoffs="interval",
        optimum_certified=certified.lower if certified.lower == certified.upper else None,
        optimum_attack=attack.lower if attack.lower == attack.upper else None,
        certified_stats=certified.stats,
    )


def _fmt(x: float) -> str:
    return f"{x:g}"
