"""``lesmc track`` of a multi-target design (sort, gnn): every track's id, box (gnn: its
position) and status per step, and the target's track id (schema lesmc/schemas/track.json)."""

from __future__ import annotations

import json
from typing import Any

import click

from lesmc.scene import Footage, Scene


def track_multi(sc: Scene | Footage, path: str, end: int | None, as_json: bool) -> None:
    """Run the multi-target design of ``sc`` unattacked and print its tracks."""
    from lesmc.tracking.trackers import make_multi

    steps = make_multi(sc, path).run(end)
    if as_json:
        click.echo(json.dumps(multi_document(sc.tracker.design, steps), indent=1))
        return
    from rich.table import Table

    from lesmc.report.text import make_console

    title = f"unattacked tracks ({sc.tracker.design} design)"
    table = Table(title=title, title_justify="left")
    point = bool(steps) and steps[0].tracks.boxes.shape[1] == 2
    place = ("x", "y") if point else ("x1", "y1", "x2", "y2")
    for col in ("step", "frame", "id", *place, "status", "target"):
        table.add_column(col, justify="left" if col in ("status", "target") else "right")
    for s in steps:
        t = s.tracks
        for i in range(len(t.ids)):
            mark = "target" if s.target_id is not None and int(t.ids[i]) == s.target_id else ""
            table.add_row(
                str(s.step),
                str(s.frame),
                str(int(t.ids[i])),
                *(f"{float(v):.1f}" for v in t.boxes[i]),
                t.status(i),
                mark,
            )
    make_console().print(table)


def multi_document(design: str, steps: list[Any]) -> dict[str, Any]:
    """The ``lesmc-track`` document of a multi-target run (``steps``: tracking.multi's
    ``MultiStep`` list)."""
    from lesmc.pipeline.multi_tracks import track_entries

    return {
        "format": "lesmc-track",
        "version": 1,
        "design": design,
        "track": [
            {
                "step": s.step,
                "frame": s.frame,
                "tracks": track_entries(s.tracks),
                "target_id": s.target_id,
            }
            for s in steps
        ],
    }
