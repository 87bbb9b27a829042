"""What a check returns: verdict, optimum, counterexample, witness and statistics."""

from __future__ import annotations

import builtins
import math
import warnings
from dataclasses import dataclass, field
from typing import Any, Literal

from lesmc.engines.space import SearchSpace
from lesmc.model.kernel import compare

Verdict = Literal["holds", "violated", "unknown"]

#: Why a search stopped: it finished, or a budget ran out (then bounds are reported).
StopReason = Literal["finished", "max_states", "timeout", "max_memory", "interrupted"]


@dataclass(frozen=True)
class PathStep:
    """One step of a reported path: the state entered, its observation and measures."""

    step: int
    state: str
    obs: str | None
    rank: int | None
    combined_payoff: float
    deviation: float
    attacked: bool


@dataclass(frozen=True)
class PathInfo:
    """A complete path from step 0 to the property's end (or to a halt).

    ``deviation`` is dist.at(k) of the property's components and norm for every step
    k = 0..end (Eq. 4), +inf after a halt (docs/semantics.md).
    """

    states: tuple[str, ...]
    objective: float
    constraint: float
    steps: tuple[PathStep, ...]
    halted: bool
    deviation: tuple[float, ...] = ()

    def to_json(self, with_constraint: bool = True) -> dict[str, Any]:
        d: dict[str, Any] = {"states": list(self.states), "objective": _num(self.objective)}
        if with_constraint:
            d["constraint"] = _num(self.constraint)
        d["halted"] = self.halted
        d["deviation"] = [_num(x) for x in self.deviation]
        d["steps"] = [
            {
                "step": s.step,
                "state": s.state,
                "obs": s.obs,
                "rank": s.rank,
                "combined_payoff": _num(s.combined_payoff),
                "deviation": _num(s.deviation),
                "attacked": s.attacked,
            }
            for s in self.steps
        ]
        return d


@dataclass
class Stats:
    """How the engine got its answer; ``seconds`` is the search alone, not loading."""

    engine: str
    states_expanded: int = 0
    transitions: int = 0
    seconds: float = 0.0
    stopped: StopReason = "finished"
    paths: int | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "engine": self.engine,
            "states_expanded": self.states_expanded,
            "transitions": self.transitions,
            "seconds": round(self.seconds, 6),
            "stopped": self.stopped,
        }
        if self.paths is not None:
            d["paths"] = self.paths
        d.update(self.extra)
        return d


@dataclass
class EngineOutcome:
    """An engine's raw answer; paths are transition-index lists from the root."""

    optimum: float  # +inf when no path violates (or not yet found)
    lower: float
    upper: float
    counterexample: list[int] | None
    witness: list[int] | None
    witness_exact: bool
    stats: Stats


@dataclass
class CheckResult:
    """The answer to one property, checked with one design (``design``).

    ``optimum`` is the optimum when it is known (``optimum_known``): a number, ``math.inf``
    when no attacked path violates; None when it is not known (a budget stopped the
    search, or in interval mode the two payoff sets disagree: ``lower`` and ``upper``
    say where it lies). A sweep's variant names the values it was checked with
    (``sweep``: ``{"eps": 10.782}``).
    """

    property: str
    verdict: Verdict
    optimum: float | None
    threshold: float
    holds_op: str
    objective: str
    constraint: str
    lower: float
    upper: float
    #: the cheapest path found that satisfies the constraint (breaks the system, P+): a
    #: counterexample only when its objective fails ``holds if`` (:attr:`counterexample`);
    #: on a property that holds it is the cheapest such attack, which costs too much
    cheapest: PathInfo | None
    witness: PathInfo | None
    witness_value: float | None
    witness_exact: bool
    stats: Stats
    notes: list[str] = field(default_factory=list)
    #: False when a budget stopped the search before the optimum's bounds met
    optimum_known: bool = True
    #: proven bounds on θ* (equal when the witness is exact); None: not searched
    witness_bounds: tuple[float, float] | None = None
    original_alarms: list[int] | None = None  # monitored: the unattacked track's alarm steps
    vacuous: bool = False  # the monitor excludes the unattacked track itself

    payoffs: str = "attack"  #: attack | certified | interval (docs/semantics.md)
    optimum_certified: float | None = None  #: interval mode: the optimum with lower payoffs
    optimum_attack: float | None = None  #: interval mode: the optimum with attack payoffs
    certified_stats: Stats | None = None  #: interval mode: how the certified search went

    #: the property's spec file, its measures and its comparisons as data
    spec: str = ""
    objective_source: str = ""
    constraint_source: str = ""
    constraint_op: str = ""
    constraint_bound: float = 0.0
    #: a violated verdict on a scene made by perception: ``not replayed`` until the
    #: counterexample is replayed through the detector (``confirmed``; ``diverged`` makes
    #: the verdict unknown); None: nothing to replay (a model, a hand-made scene)
    replay: str | None = None
    #: the design it was checked with (lesmc/designs/registry.py; for a model file, the
    #: design its meta names, else ``model``); None: checked outside the pipeline
    design: str | None = None
    #: a ``--sweep`` variant's parameters and values (``{"eps": 10.782}``); empty: none
    sweep: dict[str, float | str] = field(default_factory=dict)
    #: with ``replay == "not replayed"``: the command that replays it (the scene's meta
    #: names the frames and networks it was made with)
    replay_command: str | None = None

    @builtins.property
    def counterexample(self) -> PathInfo | None:
        """The counterexample: :attr:`cheapest` when its objective fails ``holds if`` (it
        proves the property false on the model), else None (a property that holds has
        none). Up to lesmc 0.1.0 this attribute held :attr:`cheapest` whatever the verdict."""
        cex = is_counterexample(self.cheapest, self.holds_op, self.threshold)
        return self.cheapest if cex else None

    @builtins.property  # ``property`` is a field of this class: the property name
    def status(self) -> str:
        """The verdict word (:func:`status_word`)."""
        return status_word(self.verdict, self.vacuous, self.replay)

    @builtins.property
    def verdict_text(self) -> str:
        """The verdict as tables and reports print it: the word and why (:func:`verdict_words`)."""
        return verdict_words(self.verdict, self.vacuous, self.original_alarms or [], self.replay)

    def optimum_json(self) -> float | str:
        """The optimum in JSON: a number, ``"inf"`` (no attacked path violates) or
        ``"unknown"`` (a budget stopped the search, or, in interval mode, the two payoff
        sets disagree: the bounds say where it lies)."""
        if not self.optimum_known or self.optimum is None:
            return "unknown"
        return _num(self.optimum)

    def sweep_json(self) -> dict[str, float | str]:
        """``sweep`` in JSON: numbers, ``"inf"`` for an infinite norm, source names."""
        return {k: _num(v) if isinstance(v, float) else v for k, v in self.sweep.items()}

    def to_json(self) -> dict[str, Any]:
        """Deprecated alias of :meth:`to_dict` (it returns a dict); removed in the next
        release."""
        warnings.warn(
            "CheckResult.to_json() is deprecated: use to_dict()", DeprecationWarning, stacklevel=2
        )
        return self.to_dict()

    def to_dict(self) -> dict[str, Any]:
        """The result as ``lesmc check --json`` prints it (lesmc/schemas/check.json)."""
        extra: dict[str, Any] = {"payoffs": self.payoffs}
        if self.sweep:
            extra["sweep"] = {
                k: v if isinstance(v, str) else _num(v) for k, v in self.sweep.items()
            }
        if self.payoffs == "interval":
            for key in ("optimum_certified", "optimum_attack"):
                v = getattr(self, key)
                extra[key] = None if v is None else _num(v)
        wb = self.witness_bounds
        return {
            "design": self.design,
            "property": self.property,
            "spec": self.spec,
            "verdict": self.verdict,
            "status": self.status,
            "vacuous": self.vacuous,
            "replay": self._replay_json(),
            "optimum": self.optimum_json(),
            "witness_bounds": None if wb is None else {"lower": _num(wb[0]), "upper": _num(wb[1])},
            "threshold": self.threshold,
            "holds_op": self.holds_op,
            "holds_if": f"optimum {self.holds_op} {self.threshold:g}",
            "objective": self.objective,
            "objective_source": self.objective_source,
            "constraint": self.constraint,
            "constraint_source": self.constraint_source,
            "constraint_op": self.constraint_op,
            "constraint_bound": self.constraint_bound,
            "bounds": {"lower": _num(self.lower), "upper": _num(self.upper)},
            "counterexample": None if self.cheapest is None else self.cheapest.to_json(),
            "is_counterexample": None
            if self.cheapest is None
            else is_counterexample(self.cheapest, self.holds_op, self.threshold),
            "witness": None if self.witness is None else self.witness.to_json(),
            "witness_value": None if self.witness_value is None else _num(self.witness_value),
            "witness_exact": self.witness_exact,
            "notes": self.notes,
            "stats": self.stats.to_json(),
            "original_alarms": self.original_alarms,
        } | extra

    def _replay_json(self) -> dict[str, Any] | None:
        """The ``replay`` object: the status, and how to replay one not replayed yet."""
        if self.replay is None:
            return None
        out: dict[str, Any] = {"status": self.replay}
        if self.replay == "not replayed" and self.replay_command is not None:
            out["command"] = self.replay_command
        return out


def is_counterexample(path: PathInfo | None, holds_op: str, threshold: float) -> bool:
    """Whether the cheapest path that breaks the system is a counterexample: its objective
    fails section 4's rule ``objective holds_op threshold`` (a halted track's infinite
    objective fails no rule with a finite threshold)."""
    return path is not None and not compare(holds_op, path.objective, threshold)


#: Every verdict word, in the order tables and summaries count them (docs/cli.md).
STATUSES = ("holds", "holds (vacuous)", "violated", "violated (not replayed)", "unknown")


def status_word(verdict: str, vacuous: bool, replay: str | None) -> str:
    """The one word for a verdict, everywhere (tables, reports, campaigns, JSON ``status``):
    a vacuous holds is not a holds, a violation not replayed through the detector says so."""
    if verdict == "holds" and vacuous:
        return "holds (vacuous)"
    if verdict == "violated" and replay == "not replayed":
        return "violated (not replayed)"
    return verdict


def verdict_words(verdict: str, vacuous: bool, alarms: list[int], replay: str | None = None) -> str:
    """:func:`status_word` and the reason in a few words, for tables and reports."""
    word = status_word(verdict, vacuous, replay)
    if word == "holds (vacuous)":
        steps = ", ".join(str(k) for k in alarms)
        return f"holds (vacuous: the unattacked track raises the alarm at steps {steps})"
    return word


def _num(x: float) -> float | str:
    """JSON has no infinity: write it as the string "inf"."""
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return float(x)


def path_info(space: SearchSpace, transitions: list[int]) -> PathInfo:
    """Recompute a path's states and measures from its transitions (root onwards)."""
    cm, bp = space.cm, space.bp
    steps: list[PathStep] = []
    prefix = [int(q) for q in cm.original[: bp.l]]
    for k, q in enumerate(prefix):
        t = space.entering(prefix[k - 1], q) if k else None
        steps.append(_step(space, q, t, attacked=False))
    obj, con = space.root_obj, space.root_con
    q = space.root
    for t in transitions:
        q = int(cm.dst[t])
        obj = space.agg(space.obj_max, obj, float(space.c_obj[t]))
        con = space.agg(space.con_max, con, float(space.c_con[t]))
        steps.append(_step(space, q, t, attacked=bool(bp.l <= cm.step[q] <= bp.u)))
    t_obj, t_con = space.tail(q)
    obj = space.agg(space.obj_max, obj, t_obj)
    con = space.agg(space.con_max, con, t_con)
    dev = [s.deviation for s in steps] + [math.inf] * (bp.end + 1 - len(steps))
    return PathInfo(
        states=tuple(s.state for s in steps),
        objective=obj,
        constraint=con,
        steps=tuple(steps),
        halted=bool(cm.halted[q]) and int(cm.step[q]) < bp.end,
        deviation=tuple(dev),
    )


def _step(space: SearchSpace, q: int, t: int | None, attacked: bool) -> PathStep:
    cm = space.cm
    return PathStep(
        step=int(cm.step[q]),
        state=cm.state_id(q),
        obs=None if t is None else cm.obs_of(t),
        rank=None if t is None else int(cm.rank[t]),
        combined_payoff=0.0 if t is None else float(cm.combined[t]),
        deviation=float(space.dist[q]),
        attacked=attacked,
    )
