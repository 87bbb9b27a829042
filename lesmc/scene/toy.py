"""Hand-made scenes from straight-line vehicles: for examples, tests and docs.

Each vehicle moves with constant velocity and is detected in a range of
frames at its exact position; the payoff of hiding it is fixed per vehicle.
These scenes are synthetic by construction (docs/scene-format.md says so); the
perception unit (``lesmc perceive``) produces scenes from video.
"""

from __future__ import annotations

from dataclasses import dataclass

from lesmc.scene import Detection, Frame, Scene, Target, TrackerConfig


@dataclass(frozen=True)
class Vehicle:
    """A vehicle: id, position at frame 0, velocity (px/frame), attack payoff, frames seen, stop."""

    id: str
    x0: float
    y0: float
    vx: float
    vy: float
    payoff: float
    first: int = 0
    last: int = 10**9
    stop: int | None = None  # the vehicle halts at this frame and stays

    def at(self, k: int) -> tuple[float, float]:
        t = k if self.stop is None else min(k, self.stop)
        return self.x0 + self.vx * t, self.y0 + self.vy * t


def vehicle_scene(
    vehicles: list[Vehicle],
    frames: int,
    target: Vehicle,
    tracker: TrackerConfig | None = None,
    comment: str = "",
) -> Scene:
    """A scene whose track starts on ``target`` at frame 0 (its position, zero velocity)."""
    out = []
    for k in range(frames):
        dets = tuple(
            Detection(f"{k}:{v.id}", round(v.at(k)[0], 3), round(v.at(k)[1], 3), v.payoff)
            for v in vehicles
            if v.first <= k <= v.last
        )
        out.append(Frame(k, dets))
    meta = {"synthetic": "hand-made straight-line vehicles (lesmc.scene.toy)"}
    if comment:
        meta["comment"] = comment
    return Scene(1.0, tuple(out), Target(0, target.at(0)), tracker or TrackerConfig(), meta)
