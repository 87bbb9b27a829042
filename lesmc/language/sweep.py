"""Sensitivity sweeps (section 4.4): one property checked for many values of a parameter.

``--sweep eps=20..400:20`` replaces every property's constraint bound (ε of
robustness and resilience) by each value in turn; ``--sweep p=1,2,inf`` the norm of
the deviation (Eq. 4); ``--sweep payoffs=attack,certified`` the payoff source (the
attack's payoffs, named by its algorithm, ``deepfool`` or ``pgd``, as well;
certified lower bounds; or both, ``interval``). Several sweeps combine (every
combination). Each variant is a
property of its own, named ``NAME@eps=20`` (``NAME@eps=20,p=1``), so the
pipeline checks them all on the one model it builds per design: the model is never
rebuilt per value.
"""

from __future__ import annotations

import itertools
import math
import re
from dataclasses import dataclass, replace

from lesmc.common.errors import UsageError, clipped
from lesmc.language.properties import Property, SpecFile

#: The parameters a sweep may vary.
PARAMETERS = ("eps", "p", "payoffs")
#: The payoff sources of ``payoffs=``: the attack's (also by its algorithm's name),
#: the certified lower bounds, or both (docs/semantics.md, "Payoff intervals").
PAYOFF_SOURCES = ("attack", "deepfool", "pgd", "certified", "interval")
#: Most variants a sweep may make (per property).
MAX_VALUES = 1000
_NUMBER = r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?"


@dataclass(frozen=True)
class Sweep:
    """A parameter and its values, in the order given."""

    parameter: str
    values: tuple[float | str, ...]  #: numbers; payoff source names for ``payoffs``


def parse_sweep(text: str) -> Sweep:
    """``eps=LO..HI:STEP``, ``eps=V1,V2,...`` or ``p=1,2,inf``; a UsageError otherwise."""
    shown = clipped(text, 60)
    m = re.fullmatch(r"\s*([a-z]+)\s*=\s*(.+?)\s*", text)
    if not m or m.group(1) not in PARAMETERS:
        raise UsageError(
            f"--sweep must look like eps=LO..HI:STEP, eps=V1,V2 or p=1,2,inf, got '{shown}'"
        )
    name, spec = m.group(1), m.group(2)
    if name == "payoffs":
        sources = tuple(s.strip() for s in spec.split(","))
        bad = [s for s in sources if s not in PAYOFF_SOURCES]
        if bad or len(set(sources)) != len(sources):
            raise UsageError(
                f"--sweep {shown}: payoff sources are distinct names among "
                + ", ".join(PAYOFF_SOURCES)
            )
        return Sweep(name, sources)
    rng = re.fullmatch(rf"({_NUMBER})\.\.({_NUMBER}):({_NUMBER})", spec)
    if rng:
        lo, hi, step = (float(rng.group(i)) for i in (1, 2, 3))
        if not (math.isfinite(lo) and math.isfinite(hi) and step > 0 and lo <= hi):
            raise UsageError(f"--sweep {shown}: need LO <= HI and STEP > 0")
        count = math.floor((hi - lo) / step + 1e-9) + 1
        if count > MAX_VALUES:
            raise UsageError(f"--sweep {shown}: {count} values, at most {MAX_VALUES}")
        values = tuple(lo + i * step for i in range(count))
    else:
        parts = [s.strip() for s in spec.split(",")]
        if not all(re.fullmatch(_NUMBER, s) or s == "inf" for s in parts):
            raise UsageError(f"--sweep {shown}: values must be numbers separated by commas")
        values = tuple(float(s) for s in parts)
        if len(values) > MAX_VALUES:
            raise UsageError(f"--sweep {shown}: {len(values)} values, at most {MAX_VALUES}")
    if name == "p" and not all(v in (1.0, 2.0, math.inf) for v in values):
        raise UsageError(f"--sweep {shown}: the norm p is 1, 2 or inf")
    if name == "eps" and not all(math.isfinite(v) for v in values):
        raise UsageError(f"--sweep {shown}: eps values must be finite")
    return Sweep(name, values)


def distinct_variants(sweep: Sweep, text: str) -> None:
    """``--sweep TEXT``'s values each make their own variant: its property name holds the
    value's text, so two values alike there would define one property twice. (A sweep
    built in Python may repeat a value: the repeat is answered by reuse.)"""
    texts = [_text(v) for v in sweep.values]
    twice = next((t for i, t in enumerate(texts) if t in texts[:i]), None)
    if twice is not None:
        shown = clipped(text, 60)
        raise UsageError(
            f"--sweep {shown}: two values make the same variant {sweep.parameter}={twice} "
            "(a value given twice, or two that agree to 6 significant digits)"
        )


def _text(v: float | str) -> str:
    if isinstance(v, str):
        return v
    return "inf" if math.isinf(v) else f"{v:g}"


def payoff_mode(source: str) -> str:
    """The payoff mode of a source: an attack's name is the ``attack`` mode."""
    return "attack" if source in ("deepfool", "pgd") else source


def _variant(prop: Property, settings: tuple[tuple[str, float | str], ...]) -> Property:
    changed = prop
    for name, v in settings:
        if name == "payoffs":
            changed = replace(changed, payoffs=payoff_mode(str(v)))
        elif name == "eps":
            changed = replace(changed, constraint=replace(changed.constraint, threshold=float(v)))
        else:
            changed = replace(changed, norm=float(v))
    label = ",".join(f"{n}={_text(v)}" for n, v in settings)
    return replace(changed, name=f"{prop.name}@{label}", sweep=(*prop.sweep, *settings))


def swept(spec: SpecFile, sweeps: tuple[Sweep, ...]) -> SpecFile:
    """``spec`` with each property replaced by its variants, one per combination of the
    sweeps' values (in the order given)."""
    if not sweeps:
        return spec
    names = [s.parameter for s in sweeps]
    if len(set(names)) != len(names):
        raise UsageError("--sweep: each parameter at most once (give its values in one --sweep)")
    combos = list(itertools.product(*[[(s.parameter, v) for v in s.values] for s in sweeps]))
    if len(combos) > MAX_VALUES:
        raise UsageError(f"--sweep: {len(combos)} combinations, at most {MAX_VALUES}")
    props = tuple(_variant(p, combo) for p in spec.properties for combo in combos)
    return replace(spec, properties=props)
