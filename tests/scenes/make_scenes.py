"""Regenerate the hand-made scenes of this folder: ``python tests/scenes/make_scenes.py``.

Each scene reproduces one of the paper's qualitative findings (section 8); the
expected verdicts are asserted in tests/test_scenes.py. Vehicles move in
straight lines at 10 px/frame unless said otherwise; the track starts on the
target "t" at frame 0.
"""

from __future__ import annotations

from pathlib import Path

from lesmc.scene import save_scene
from lesmc.scene.toy import Vehicle, vehicle_scene

HERE = Path(__file__).parent
T = Vehicle("t", 100, 100, 10, 0, 3.0)

SCENES = {
    # RQ1 robustness: a platoon in the next lanes; hiding nearer vehicles moves the
    # track onto a neighbour, but the gate bounds the deviation.
    "rq1_platoon": (
        [
            T,
            Vehicle("a", 100, 106, 10, 0, 2.0),
            Vehicle("b", 100, 94, 10, 0, 2.5),
            Vehicle("c", 100, 112, 10, 0, 1.5),
        ],
        "a platoon in adjacent lanes: bounded deviation",
    ),
    # RQ1 resilience: an oncoming vehicle passes close at frame 8; a one-step attack
    # makes the track take it, the velocity keeps the prediction on course, it recovers.
    "rq1_oncoming": (
        [T, Vehicle("o", 260, 112, -10, 0, 2.0)],
        "an oncoming vehicle passes at frame 8: the track recovers",
    ),
    # RQ2, robust but not resilient: a parallel vehicle 6 px away; once the track
    # jumps to it, it stays there (small deviation that never goes away).
    "rq2_parallel": (
        [T, Vehicle("n", 100, 106, 10, 0, 2.0)],
        "a parallel vehicle 6 px away: small but permanent deviation",
    ),
    # RQ2, resilient but not robust: the target stops at frame 5; hidden, the coasting
    # track overshoots by up to ~30 px, then finds it again.
    "rq2_stop": (
        [Vehicle("t", 100, 100, 10, 0, 3.0, stop=5)],
        "the target stops while hidden: large overshoot, full recovery",
    ),
    # RQ4 (Table 5): a parallel vehicle c tracked from the start, and a vehicle n merging
    # 5 px from the target at frame 7. Single design: hiding t sends the track to c.
    # Joint design: c has its own track, so only skips remain, which the monitor flags;
    # the late merger n still misleads both designs alike (resilience unchanged).
    "rq4_merge": (
        [T, Vehicle("c", 100, 112, 10, 0, 2.0), Vehicle("n", 100, 105, 10, 0, 2.0, first=7)],
        "a tracked neighbour and a late merger: joint KFs + monitor stop the attack",
    ),
}


def main() -> None:
    for name, (vehicles, comment) in SCENES.items():
        save_scene(vehicle_scene(vehicles, 20, vehicles[0], comment=comment), HERE / f"{name}.json")
        print(f"wrote {name}.json")


if __name__ == "__main__":
    main()
