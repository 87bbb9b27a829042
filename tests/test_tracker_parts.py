"""single and joint as compositions of declared parts (issue 58, "Architecture"): the
attacker's options written once and agreeing with a brute force of the threat model, no
tracker module over 400 lines, the joint design's parameters in its own config."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lesmc.common.errors import InputError
from lesmc.scene import JointConfig, TrackerConfig, tracker_from_dict
from lesmc.scene.toy import Vehicle, vehicle_scene
from lesmc.tracking.joint import JointDesign
from lesmc.tracking.parts.attacker import attack_option_rows, hiding_options
from lesmc.tracking.single import SingleDesign

ROOT = Path(__file__).resolve().parents[1]
TRACKING = ROOT / "lesmc" / "tracking"
ATTACKER = "lesmc.tracking.parts.attacker"


def brute_force(gated: list[bool], pay: list[float]) -> list[tuple[int, float]]:
    """The threat model, option by option: option j hides the j nearest candidates (it
    cannot hide an unattackable one) and costs their payoffs; the tracker then takes the
    nearest visible candidate if the gate admits it, else skips (−1). Each distinct outcome
    once, at its cheapest option, in the order of the options."""
    best: dict[int, float] = {}
    for j in range(len(gated) + 1):
        if any(math.isinf(p) for p in pay[:j]):
            break
        outcome = j if j < len(gated) and gated[j] else -1
        best.setdefault(outcome, math.fsum(pay[:j]))
    return list(best.items())


rows = st.integers(0, 7).flatmap(
    lambda k: st.tuples(
        st.lists(st.booleans(), min_size=k, max_size=k),
        st.lists(
            st.one_of(st.floats(0.01, 5, allow_nan=False), st.just(math.inf)),
            min_size=k,
            max_size=k,
        ),
    )
)


@settings(max_examples=300, deadline=None)
@given(row=rows)
def test_single_view_of_the_attackers_options_is_the_brute_force(
    row: tuple[list[bool], list[float]],
) -> None:
    """attack_option_rows (single): each outcome's combined payoff (Eq. 5, the own payoffs
    of the lower ranks) is the cheapest way to force it."""
    gated, pay = row
    k = len(gated)
    got = attack_option_rows(
        np.array(gated, dtype=bool).reshape(1, k),
        np.array(pay, dtype=float).reshape(1, k),
        np.ones((1, k), dtype=bool),
    )
    combined = np.concatenate([[0.0], np.cumsum(got.payoff)[:-1]])
    want = brute_force(gated, pay)
    assert got.col.tolist() == [c for c, _ in want]
    assert combined == pytest.approx([c for _, c in want], rel=1e-12, abs=1e-12)


@settings(max_examples=300, deadline=None)
@given(row=rows)
def test_joint_view_of_the_attackers_options_is_the_brute_force(
    row: tuple[list[bool], list[float]],
) -> None:
    """hiding_options (joint), one primary track whose candidates lie at distances 1, 2, ...:
    its options are the brute force's hiding options up to the last one that can change the
    outcome, each costing the payoffs of the candidates it hides."""
    gated, pay = row
    k = len(gated)
    n_opt, cost, rank_of, near_z, per = hiding_options(
        np.array([0]),
        np.zeros(k, dtype=np.int64),
        np.arange(k, dtype=np.int64),
        np.arange(1.0, k + 1.0),
        np.zeros(k),
        np.array(gated, dtype=bool),
        np.array([k + 1.0]),
        np.array(pay, dtype=float),
        1,
        k,
    )
    assert per.tolist() == [k] and near_z[0].tolist() == list(range(k))
    assert rank_of[0].tolist() == list(range(k))
    options = [(j if j < k and gated[j] else -1, float(cost[0, j])) for j in range(n_opt[0])]
    distinct: dict[int, float] = {}
    for outcome, c in options:
        distinct.setdefault(outcome, c)
    want = brute_force(gated, pay)
    assert list(distinct) == [c for c, _ in want]
    assert list(distinct.values()) == pytest.approx([c for _, c in want], rel=1e-12, abs=1e-12)
    # no option beyond the last that can change the outcome
    last_gated = max((j for j in range(k) if gated[j]), default=-1)
    assert n_opt[0] <= last_gated + 2


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return out


def _defined(path: Path) -> set[str]:
    return {
        n.name
        for n in ast.parse(path.read_text()).body
        if isinstance(n, ast.FunctionDef | ast.ClassDef)
    }


def test_the_attackers_options_are_written_once() -> None:
    """Every tracker takes them from one part (attacker.py, and its subset view for the
    multi-target trackers, attacker_subsets.py), and no other module defines them."""
    for user in ("tracking/single.py", "tracking/parts/joint_step.py", "tracking/joint.py"):
        assert ATTACKER in _imports(ROOT / "lesmc" / user), user
    assert ATTACKER + "_subsets" in _imports(ROOT / "lesmc" / "unfold/multi.py")
    files = ("attacker.py", "attacker_subsets.py")
    names = {n for f in files for n in _defined(TRACKING / "parts" / f) if not n.startswith("_")}
    assert {"attack_option_rows", "hiding_options", "ranks_and_payoffs", "hidden_subsets"} <= names
    assert {"injection_option_rows", "subset_options", "attackable"} <= names
    for path in (ROOT / "lesmc").rglob("*.py"):
        if path.name not in files:
            assert not names & _defined(path), path


def test_no_tracker_module_is_over_400_lines() -> None:
    long = {
        str(p.relative_to(ROOT)): n
        for p in TRACKING.rglob("*.py")
        if (n := len(p.read_text().splitlines())) > 400
    }
    assert not long


def test_no_package_shadows_a_tracking_module() -> None:
    for p in TRACKING.rglob("*.py"):
        assert not p.with_suffix("").is_dir(), p


def test_joint_parameters_are_the_joint_designs_own_config() -> None:
    """Tracker files keep the keys' names and their validation; the values reach the joint
    composition's parts and not the shared configuration."""
    cfg = tracker_from_dict(
        {"design": "joint", "init_radius": 40.0, "init_distance": 7.5, "prune_radius": 90.0}
    )
    assert cfg.joint == JointConfig(init_radius=40.0, init_distance=7.5, prune_radius=90.0)
    assert not hasattr(cfg, "init_radius")
    keys = list(cfg.to_json())
    assert keys[keys.index("max_trace") + 1 :][:3] == [
        "init_radius",
        "init_distance",
        "prune_radius",
    ]
    assert cfg.to_json()["init_distance"] == 7.5
    with pytest.raises(
        InputError, match=r"t\.toml: prune_radius must be a number in \(0, 1e\+07\]"
    ):
        tracker_from_dict({"prune_radius": 0}, "t.toml")
    car = Vehicle("a", 100.0, 100.0, 5.0, 0.0, 1.0)
    scene = vehicle_scene([car], 4, car, tracker=cfg)
    joint = JointDesign(scene)
    assert (joint.parts.initiator.init_radius, joint.parts.initiator.init_distance) == (40.0, 7.5)
    assert joint.parts.pruner.prune_radius == 90.0
    assert joint.parts.deleter.max_trace == cfg.max_trace
    single = SingleDesign(scene)
    assert single.parts.hypothesiser.gate == cfg.gate
    assert single.parts.deleter.max_trace == TrackerConfig().max_trace
