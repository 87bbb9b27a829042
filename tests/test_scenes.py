"""Hand-made scenes (tests/scenes/) reproduce the paper's qualitative findings (section 8)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from lesmc.api import check
from lesmc.language.parser import load_spec
from lesmc.scene import load_scene

SCENES = Path(__file__).parent / "scenes"


def verdicts(
    name: str, design: str = "single", engine: str = "bnb"
) -> dict[str, tuple[str, float]]:
    scene = load_scene(SCENES / f"{name}.json").with_tracker(design=design)
    results = check(scene, [load_spec(SCENES / f"{name}.spec")], engine=engine)  # type: ignore[arg-type]
    return {r.property: (r.verdict, math.inf if r.optimum is None else r.optimum) for r in results}


@pytest.mark.parametrize("engine", ["bnb", "enumerate"])
def test_rq1_attack_moves_the_track_but_the_deviation_stays_bounded(engine: str) -> None:
    v = verdicts("rq1_platoon", engine=engine)
    assert v["robustness"] == ("holds", 5.0)  # the cheapest attack past 120 hides two vehicles
    assert v["bounded"] == ("holds", math.inf)  # no attack moves it 20 px at any step


@pytest.mark.parametrize("engine", ["bnb", "enumerate"])
def test_rq1_track_recovers_after_a_one_step_attack(engine: str) -> None:
    v = verdicts("rq1_oncoming", engine=engine)
    assert v["moved"] == ("violated", 3.0)  # hiding the target (payoff 3) moves the track > 5 px
    assert v["resilience"] == ("holds", math.inf)  # ... and every such path recovers


def test_rq2_robust_but_not_resilient() -> None:
    v = verdicts("rq2_parallel")
    assert v["robustness"][0] == "holds" and v["resilience"][0] == "violated"


def test_rq2_resilient_but_not_robust() -> None:
    v = verdicts("rq2_stop")
    assert v["robustness"] == ("violated", 6.0) and v["resilience"] == ("holds", math.inf)


@pytest.mark.parametrize("engine", ["bnb", "enumerate"])
def test_rq4_joint_kfs_and_monitor_remove_adversarial_tracks_resilience_unchanged(
    engine: str,
) -> None:
    single = verdicts("rq4_merge", "single", engine)
    joint = verdicts("rq4_merge", "joint", engine)
    assert single["robustness"] == ("violated", 3.0)
    assert joint["robustness"] == ("holds", math.inf)  # Table 5: "inf."
    assert single["resilience"][0] == joint["resilience"][0] == "violated"
    assert joint["resilience"][1] == pytest.approx(single["resilience"][1], rel=1e-12)
