"""A campaign's ``results.jsonl`` row, typed (lesmc/schemas/campaign-row.json; written by
lesmc/campaign/work.py, read by the campaign summary, lesmc/campaign/summary.py). Part of
the typed reading of the results documents (lesmc/results/read.py, whose conventions it
follows: the schema has validated the row, :func:`read_row` only converts, and each key
is spelled once).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from lesmc.results.result_doc import Num


@dataclass(frozen=True)
class Target:
    """A campaign target: its position (pixels) at step ``step``."""

    step: int
    x: float
    y: float

    def to_dict(self) -> dict[str, Any]:
        """The target as the row writes it."""
        return {"step": self.step, "x": self.x, "y": self.y}


@dataclass(frozen=True)
class CampaignRow:
    """One line of a campaign's ``results.jsonl`` (lesmc/schemas/campaign-row.json): what the
    summary reads of it. ``optimum`` as written (a number, "inf" or "unknown");
    ``payoffs`` None for the attack's payoffs (the row omits it)."""

    key: str
    video: str
    target: Target
    window: tuple[int, int]
    design: str
    property: str
    verdict: str
    status: str
    vacuous: bool
    optimum: Num
    payoffs: str | None
    objective_source: str | None
    attacked_frames: int | None


def read_row(row: Mapping[str, Any]) -> CampaignRow:
    """The typed row of a (validated) ``results.jsonl`` object."""
    t = row["target"]
    w = row["window"]
    return CampaignRow(
        key=row["key"],
        video=row["video"],
        target=Target(step=t["step"], x=t["x"], y=t["y"]),
        window=(w[0], w[1]),
        design=row["design"],
        property=row["property"],
        verdict=row["verdict"],
        status=row["status"],
        vacuous=bool(row.get("vacuous", False)),
        optimum=row["optimum"],
        payoffs=row.get("payoffs"),
        objective_source=row.get("objective_source"),
        attacked_frames=row.get("attacked_frames"),
    )
