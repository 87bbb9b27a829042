"""What a verification produced, as typed objects: per design, its properties' results.

The pipeline (lesmc/pipeline/check.py) returns a :class:`Results`; the
results document (lesmc/results/document.py) is written from it, and the
report and the replay read only that document.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from lesmc.designs import registry
from lesmc.engines.result import CheckResult
from lesmc.language.semantics import BoundProperty
from lesmc.model.arrays import ArrayModel
from lesmc.scene import Scene


@dataclass
class DesignRun:
    """One design's bound properties and their results (same order).

    ``design`` is a registry name (``model`` for a .lts file); ``window`` the attack
    window every property was moved to (None: the properties' own); ``model`` the
    whole model of the attack payoffs when it was built (the report draws it);
    ``scene`` the scene it was unfolded from, with the design's tracker.
    ``fault_bound`` and ``fault_results``: the properties under component failures
    (``NAME+FAULT``, lesmc/pipeline/faults.py), checked on models of their own: their
    paths are not paths of ``model``.
    """

    design: str
    bound: list[BoundProperty]
    results: list[CheckResult]
    model: ArrayModel | None = None
    scene: Scene | None = None
    window: tuple[int, int] | None = None
    fault_bound: list[BoundProperty] = field(default_factory=list)
    fault_results: list[CheckResult] = field(default_factory=list)
    #: each property's place among those its design checks in its window, in the specs'
    #: order (the properties of one design and window may be split over runs, one per
    #: attacker: lesmc/pipeline/check.py); empty: in the order listed
    order: tuple[int, ...] = ()
    #: a model built with ``allow ..., inject``: (state, step, rank) -> the ids of the
    #: detections hidden and of what is injected by the cheapest way to force that
    #: outcome (the tracker's ``attack_at``); None: not known (its counterexamples list
    #: no hidden detections rather than guess them from the ranks)
    attack_of: Callable[[int, int, int], tuple[list[str], list[str]]] | None = field(
        default=None, compare=False, repr=False
    )

    @property
    def all_results(self) -> list[CheckResult]:
        """The results, then those under faults."""
        return [*self.results, *self.fault_results]

    @property
    def label(self) -> str:
        """How tables name the design."""
        return registry.label(self.design)


@dataclass
class Results:
    """Every design run of one job, the scene as checked (with the certified bounds this job
    added, if any) and what the certification did (``certified``: its summary)."""

    runs: list[DesignRun]
    scene: Scene | None = None
    certified: dict[str, Any] | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def results(self) -> list[CheckResult]:
        """Every property result: design by design and window by window, each's in the
        specs' order (its runs' :attr:`DesignRun.order`), then those under faults."""
        groups: dict[tuple[str, tuple[int, int] | None], list[DesignRun]] = {}
        for run in self.runs:
            groups.setdefault((run.design, run.window), []).append(run)
        out: list[CheckResult] = []
        for runs in groups.values():
            if all(len(run.order) == len(run.results) for run in runs):
                placed = [
                    (o, r) for run in runs for o, r in zip(run.order, run.results, strict=True)
                ]
                out += [r for _, r in sorted(placed, key=lambda p: p[0])]
            else:
                out += [r for run in runs for r in run.results]
            out += [r for run in runs for r in run.fault_results]
        return out
