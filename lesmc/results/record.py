"""What a verification produced, as typed objects: per design, its properties' results.

The pipeline (lesmc/pipeline/check.py) returns a :class:`Results`; the
results document (lesmc/results/document.py) is written from it, and the
report and the replay read only that document.
"""

from __future__ import annotations

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
        """Every property result, run by run (those under faults after each run's own)."""
        return [r for run in self.runs for r in run.all_results]
