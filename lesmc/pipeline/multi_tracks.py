"""What a report draws of a multi-target counterexample: every track (id, box, status) at
each step of the attacked run, the detections hidden and the candidates injected with
their boxes, the target's reference box and the steps where the target's id switches
(``lesmc-multi-check`` version 2, docs/results.md; drawn by lesmc/report/multi.py).

The attacked run is the design's own tracker stepped along the counterexample: at each
step the frame's detections left after the hidden ones, then the injected candidates
(the order lesmc/unfold/multi.py feeds them in), so the tracks are those of the states
the check's optimal path went through. The switch steps are
:func:`lesmc.model.identity.indicators`' (the ``switches`` measure's own rule).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from lesmc.model.identity import NONE, indicators, last_seen
from lesmc.scene import Frame


def place_key(row: Any) -> str:
    """How a track's or detection's place is named: ``box`` [x1, y1, x2, y2], or a point
    tracker's ``position`` [x, y]."""
    return "box" if len(row) == 4 else "position"


def track_entries(ft: Any) -> list[dict[str, Any]]:
    """Every track of ``ft`` (tracking.multi's ``FrameTracks``) as ``lesmc track --json``
    and the counterexample steps list them: ``{"id", "box" | "position", "status"}``."""
    return [
        {
            "id": int(ft.ids[i]),
            place_key(ft.boxes[i]): [float(v) for v in ft.boxes[i]],
            "status": ft.status(i),
        }
        for i in range(len(ft.ids))
    ]


@dataclass(frozen=True)
class StepDrawing:
    """One counterexample step as the report draws it: every track after the step, the
    attacked detections (``{"id", "action": "hidden" | "injected", "box" | "position"}``),
    the reference box (None: none at this step) and whether the target's id switched."""

    tracks: tuple[dict[str, Any], ...]
    attacked: tuple[dict[str, Any], ...]
    reference: tuple[float, ...] | None
    switch: bool


def attacked_run(
    design: Any, frames: tuple[Frame, ...], subsets: list[tuple[int, ...]], n_dets: tuple[int, ...]
) -> list[Any]:
    """The ``FrameTracks`` of each step of the run in which ``subsets[k]`` (indices into
    step k's detections, then its candidates: ``n_dets[k]`` detections) are hidden
    (detections) or injected (candidates); ``design`` a ComposedDesign."""
    tracker = design.tracker
    state = tracker.initial()
    out = []
    for k, sub in enumerate(subsets):
        f = frames[k]
        rows = np.vstack([design.measurements(f), design.candidate_measurements(f)])
        keep = np.arange(len(rows)) < n_dets[k]
        keep[list(sub)] ^= True  # hidden detections off, injected candidates on
        state, ft = tracker.step(state, rows[keep])
        out.append(ft)
    return out


def step_drawings(
    design: Any,
    frames: tuple[Frame, ...],
    subsets: list[tuple[int, ...]],
    n_dets: tuple[int, ...],
    target_ids: list[int | None],
    refbox: np.ndarray,
) -> list[StepDrawing]:
    """Each counterexample step's :class:`StepDrawing` (``refbox``: the model's reference
    box per step, nan rows where none; ``target_ids``: the path's target's track ids)."""
    runs = attacked_run(design, frames, subsets, n_dets)
    tid = np.array([NONE if t is None else t for t in target_ids], dtype=np.int64)
    last = np.empty_like(tid)
    last[0] = tid[0]
    for k in range(1, len(tid)):
        last[k] = last_seen(last[k - 1 : k], tid[k : k + 1])[0]
    no_ref = np.zeros(len(tid) - 1, dtype=bool)
    switched = np.concatenate([[0.0], indicators("switches", last[:-1], tid[1:], no_ref)])
    out = []
    for k, sub in enumerate(subsets):
        f = frames[k]
        rows = np.vstack([design.measurements(f), design.candidate_measurements(f)])
        names = (*f.detections, *f.candidates)
        attacked = tuple(
            {
                "id": names[j].id,
                "action": "hidden" if j < n_dets[k] else "injected",
                place_key(rows[j]): [float(v) for v in rows[j]],
            }
            for j in sub
        )
        ref = refbox[k]
        out.append(
            StepDrawing(
                tuple(track_entries(runs[k])),
                attacked,
                None if np.isnan(ref).any() else tuple(float(v) for v in ref),
                bool(switched[k]),
            )
        )
    return out
