"""A scene's ``meta.attack`` and ``meta.frontend`` (docs/scene-format.md): the attack
settings ``lesmc perceive -o`` records and a replay attacks with again, the notes it writes
beside them for a reader, the front end's settings the replay reruns, and their check when
a scene is read (lesmc/scene/io.py)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from lesmc.common.errors import Problems
from lesmc.common.fields import FRONTEND_RANGES, is_finite, is_int, show

#: The attack settings a scene's ``meta.attack`` records that lesmc reads back (the
#: replay attacks with them), and the values each may take: what ``lesmc perceive``
#: accepts (--attack, --payoff-norm, --overshoot, --max-iter; converged: < 1). The
#: command line keeps its own copy of the ranges (importing this module would cost
#: ``perceive --help`` numpy); tests/test_input_limits.py checks that the two agree.
ATTACK_SETTINGS: dict[str, tuple[Callable[[Any], bool], str]] = {
    "method": (lambda v: v in ("deepfool", "pgd"), '"deepfool" or "pgd"'),
    "norm": (lambda v: v in ("l2", "per-pixel"), '"l2" or "per-pixel"'),
    "overshoot": (lambda v: is_finite(v) and 0 <= v <= 1, "a number in [0, 1]"),
    "max_iter": (lambda v: is_int(v) and 1 <= v <= 10_000, "an integer in 1..10000"),
    "converged": (lambda v: is_finite(v) and 0 <= v < 1, "a number in [0, 1)"),
}


@dataclass(frozen=True)
class AttackNotes:
    """What ``meta.attack`` may say besides its settings: descriptions for a reader, never
    read back. The writers (``lesmc perceive -o``, lesmc/experiment/perceive.py) build
    them here, and the reader accepts exactly these fields (:data:`ATTACK_NOTES`)."""

    pixel_scale: str | None = None  #: the pixels' range as the attack sees them
    input: str | None = None  #: what the attack perturbs (the network input's shape, units)
    where: str | None = None  #: the part of the frame a perturbation may change

    def meta(self) -> dict[str, str]:
        """The notes given, as ``meta.attack`` fields."""
        return {k: v for k, v in dataclasses.asdict(self).items() if v is not None}


#: The fields of :class:`AttackNotes`: what ``meta.attack`` may say besides its settings.
ATTACK_NOTES = tuple(f.name for f in dataclasses.fields(AttackNotes))


def recorded_attack(meta: dict[str, Any], pr: Problems) -> dict[str, Any]:
    """The settings of :data:`ATTACK_SETTINGS` that ``meta.attack`` records, each checked
    (a bad one is a problem in ``pr`` and left out). A ``meta.attack`` that is not an
    object, or a field that is neither a setting nor one of :data:`ATTACK_NOTES` (a
    misspelt setting would otherwise price and replay with the default), is a problem too."""
    got: dict[str, Any] = {}
    if "attack" not in meta:
        return got
    attack = meta["attack"]
    if not isinstance(attack, dict):
        pr.add("meta.attack", f"must be an object of attack settings, got {show(attack)}")
        return got
    for key in attack:
        if key not in ATTACK_SETTINGS and key not in ATTACK_NOTES:
            pr.add(f"meta.attack.{key}", f"unknown setting (known: {', '.join(ATTACK_SETTINGS)})")
    for key, (ok, what) in ATTACK_SETTINGS.items():
        if key in attack:
            if ok(attack[key]):
                got[key] = attack[key]
            else:
                pr.add(f"meta.attack.{key}", f"must be {what}, got {show(attack[key])}")
    return got


def recorded_frontend(meta: dict[str, Any], pr: Problems) -> dict[str, int]:
    """The front end's settings ``meta.frontend`` records (``history``, ``delta_bc``), each
    an integer in :data:`FRONTEND_RANGES` ({} when there is no ``meta.frontend``); a bad
    one is a problem in ``pr`` and left out, and so is a ``meta.frontend`` that is not an
    object (null too) or a field of another name (a misspelt setting would replay with
    the default)."""
    if "frontend" not in meta:
        return {}
    fe = meta["frontend"]
    if not isinstance(fe, dict):
        pr.add("meta.frontend", f"must be an object with history and delta_bc, got {show(fe)}")
        return {}
    for k in fe:
        if k not in FRONTEND_RANGES:
            pr.add(f"meta.frontend.{k}", f"unknown setting (known: {', '.join(FRONTEND_RANGES)})")
    got: dict[str, int] = {}
    for key, (lo, hi) in FRONTEND_RANGES.items():
        if key not in fe:
            continue
        if is_int(fe[key]) and lo <= fe[key] <= hi:
            got[key] = fe[key]
        else:
            pr.add(f"meta.frontend.{key}", f"must be an integer in {lo}..{hi}, got {show(fe[key])}")
    return got
