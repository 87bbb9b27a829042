"""A runtime monitor's false alarms on unattacked traffic (``lesmc alarms``).

Every moving vehicle of the truth gets the unattacked tracker started on it (its true
position and velocity at the scene's target frame), as ``lesmc verify``'s "monitor on
unattacked tracks" does (lesmc/experiment/false_alarms.py, which runs them in one batch);
the chosen monitor (lesmc/language/monitors.py) then reads each track's τ and NIS. With
no attack, every alarm is a false alarm: the rate is what the monitor costs a deployed
tracker on normal traffic.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from lesmc.common.errors import UsageError
from lesmc.designs import registry
from lesmc.experiment.false_alarms import TruthStart, truth_starts, unattacked_tracks
from lesmc.language import monitors
from lesmc.language.properties import Monitor
from lesmc.model.kernel import track_alarms
from lesmc.perception.quality import TruthFrame
from lesmc.scene import Scene

FORMAT = "lesmc-alarms"
VERSION = 1


def chosen_monitor(kind: str, parameter: str | None, window: int) -> Monitor:
    """The monitor ``--monitor KIND PARAM [--window K]`` names, checked against the registry
    (a usage error, exit 2, for an unknown kind or a parameter outside its domain)."""
    value = None
    if parameter is not None:
        try:
            value = float(parameter)
        except ValueError:
            raise UsageError(f"--monitor {kind}: {parameter!r} is not a number") from None
    try:
        kind, value, window = monitors.resolve(kind, value, window)
    except ValueError as exc:
        raise UsageError(f"--monitor: {exc}") from None
    return Monitor(parameter=value, kind=kind, window=window)


def scene_starts(scene: Scene) -> tuple[list[TruthStart], list[str]]:
    """The scene's ground-truth tracks that are at the target's frame and the next one and
    move between them: where each starts (its position there, its velocity as the
    displacement to the next frame over dt), and their ids."""
    k = scene.target.step
    starts, ids = [], []
    for i, t in enumerate(scene.truth):
        at = {step: (x, y) for step, x, y in t.positions}
        if k not in at or k + 1 not in at:
            continue
        (x0, y0), (x1, y1) = at[k], at[k + 1]
        vx, vy = (x1 - x0) / scene.dt, (y1 - y0) / scene.dt
        if vx == 0.0 and vy == 0.0:
            continue
        starts.append(TruthStart(i, x0, y0, vx, vy))
        ids.append(t.id)
    return starts, ids


def video_starts(tf: TruthFrame, size: tuple[int, int]) -> tuple[list[TruthStart], list[str]]:
    """The moving, visible vehicles of the video's truth at the target's frame (the same as
    ``lesmc verify``'s false-alarm count), and their ids."""
    starts = truth_starts(tf, size)
    return starts, [str(s.vid) for s in starts]


def alarms_document(
    scene: Scene,
    starts: Sequence[TruthStart],
    ids: Sequence[str],
    steps: int,
    design: str,
    monitor: Monitor,
) -> dict[str, Any]:
    """The ``lesmc-alarms`` document: per track, per step 1..n, the alarm, τ and the NIS
    (null where the step took no update), and the rate over all of them."""
    tracker = registry.get(design).tracker
    series = unattacked_tracks(scene, starts, tracker, steps)
    tracks = []
    n_steps = n_alarms = alarmed = 0
    for vid, s in zip(ids, series, strict=True):
        fired = track_alarms(monitor.kind, monitor.parameter, monitor.window, s.tau, s.nis)
        rows = [
            {
                "step": j,
                "alarm": bool(fired[j]),
                "tau": float(s.tau[j]),
                "nis": None if np.isnan(s.nis[j]) else float(s.nis[j]),
            }
            for j in range(1, len(s.tau))
        ]
        tracks.append({"truth_id": vid, "steps": rows})
        n_steps += len(rows)
        hits = int(fired[1:].sum())
        n_alarms += hits
        alarmed += int(hits > 0)
    return {
        "format": FORMAT,
        "version": VERSION,
        "design": design,
        "tracker": tracker,
        "monitor": {
            "kind": monitor.kind,
            "parameter": monitor.parameter,
            "window": monitor.window,
        },
        "start_frame": scene.target.step,
        "tracks": tracks,
        "rate": {
            "steps": n_steps,
            "alarms": n_alarms,
            "tracks": len(tracks),
            "tracks_with_alarm": alarmed,
        },
    }
