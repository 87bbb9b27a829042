"""The pipeline as the verbs run it, for tests: every design's whole model, then the checks."""

from __future__ import annotations

from collections.abc import Sequence

from lesmc.language.properties import SpecFile
from lesmc.pipeline.check import run
from lesmc.pipeline.job import Job, PayoffMode
from lesmc.results.record import DesignRun
from lesmc.scene import Scene


def design_runs(
    scene: Scene,
    specs: Sequence[SpecFile],
    designs: Sequence[str],
    payoffs: PayoffMode = "attack",
) -> list[DesignRun]:
    """What ``lesmc verify`` checks for ``designs`` (whole models built, as the report needs)."""
    job = Job(tuple(specs), scene=scene, designs=tuple(designs), payoffs=payoffs, full_models=True)
    return run(job).runs
