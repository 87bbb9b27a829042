"""One property's result in a results document, typed (``runs[].results[]``, and the
``replay`` object a replay writes into it), and the numbers as the documents write them
(:data:`Num`, :func:`number`). Part of the typed reading of the results documents
(lesmc/results/read.py, whose conventions it follows: the schemas have validated the
document, the functions only convert, and each key is spelled once).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

#: A number as the documents write it: a JSON number, "inf"/"-inf", or "unknown" (optima).
Num = float | int | str


@dataclass(frozen=True)
class Perturbation:
    """What a replay's attack added to one hidden detection's N_dr window
    (``replay.perturbations[]``): the window's origin, the payoff recomputed on the frames and
    the perturbation, (m+1, 21, 21), oldest channel first."""

    obs: str
    window_origin: tuple[int, ...]
    payoff_recomputed: Num
    delta: list[Any]


@dataclass(frozen=True)
class ReplayDoc:
    """A result's replay (``replay``): its status, where and why it diverged, how the attack
    went, and (not replayed) the command that replays it."""

    status: str
    step: int | None
    reason: str | None
    max_error_px: float | None
    attack: str | None
    command: str | None
    perturbations: tuple[Perturbation, ...]
    #: a diverged replay: the property judged on the replayed run (None: not judged)
    on_frames: OnFrames | None = None


@dataclass(frozen=True)
class OnFrames:
    """A diverged replay's ``on_frames``: whether the replayed run (another path than the
    model's) violates the property at the cost of the perturbations it applied, and why."""

    violated: bool
    why: str


@dataclass(frozen=True)
class Stats:
    """How a property's search went (``stats``)."""

    engine: str
    states_expanded: int
    seconds: float
    stopped: str


@dataclass(frozen=True)
class ResultDoc:
    """One property's result in a design run (``runs[].results[]``). Numbers as written (a
    number, "inf", "-inf"; ``optimum`` also "unknown"); ``payoffs`` the payoff mode;
    ``counterexample`` and ``witness``: their paths' deviations per step (None: no path)."""

    property: str
    verdict: str
    status: str
    vacuous: bool
    optimum: Num
    bounds: tuple[Num, Num]
    threshold: float
    holds_op: str
    holds_if: str
    objective: str
    objective_source: str
    constraint: str
    payoffs: str
    witness_value: Num | None
    is_counterexample: bool | None
    counterexample: tuple[Num, ...] | None
    witness: tuple[Num, ...] | None
    original_alarms: tuple[int, ...] | None
    notes: tuple[str, ...]
    stats: Stats
    replay: ReplayDoc | None


def number(x: Num) -> float:
    """A number as the documents write it: "inf" and "-inf" are infinite."""
    if x == "inf":
        return math.inf
    if x == "-inf":
        return -math.inf
    return float(x)


def _replay(obj: Mapping[str, Any]) -> ReplayDoc:
    of = obj.get("on_frames")
    return ReplayDoc(
        status=obj["status"],
        step=obj.get("step"),
        reason=obj.get("reason"),
        max_error_px=obj.get("max_error_px"),
        attack=obj.get("attack"),
        command=obj.get("command"),
        perturbations=tuple(
            Perturbation(
                obs=p["obs"],
                window_origin=tuple(p["window_origin"]),
                payoff_recomputed=p["payoff_recomputed"],
                delta=p["delta"],
            )
            for p in obj.get("perturbations", [])
        ),
        on_frames=None if of is None else OnFrames(bool(of["violated"]), str(of["why"])),
    )


def read_replay(obj: Mapping[str, Any]) -> ReplayDoc:
    """The typed replay object of a result (lesmc/replay/run.py writes them)."""
    return _replay(obj)


def _deviation(path: Mapping[str, Any] | None) -> tuple[Num, ...] | None:
    return None if path is None else tuple(path["deviation"])


def read_result(res: Mapping[str, Any]) -> ResultDoc:
    rp = res["replay"]
    st = res["stats"]
    alarms = res["original_alarms"]
    return ResultDoc(
        property=res["property"],
        verdict=res["verdict"],
        status=res["status"],
        vacuous=bool(res["vacuous"]),
        optimum=res["optimum"],
        bounds=(res["bounds"]["lower"], res["bounds"]["upper"]),
        threshold=float(res["threshold"]),
        holds_op=res["holds_op"],
        holds_if=res["holds_if"],
        objective=res["objective"],
        objective_source=res["objective_source"],
        constraint=res["constraint"],
        payoffs=res["payoffs"],
        witness_value=res["witness_value"],
        is_counterexample=res.get("is_counterexample"),
        counterexample=_deviation(res["counterexample"]),
        witness=_deviation(res["witness"]),
        original_alarms=None if alarms is None else tuple(alarms),
        notes=tuple(res["notes"]),
        stats=Stats(
            engine=st["engine"],
            states_expanded=st["states_expanded"],
            seconds=st["seconds"],
            stopped=st["stopped"],
        ),
        replay=None if rp is None else _replay(rp),
    )
