"""The review of round 21's findings in lesmc/replay/ (each test fails on the code before)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from cli_run import ROOT, lesmc

from lesmc.replay.joint_forcing import forcing_costs


def _eq5_by_hand(src: list[int], rank: list[int], payoff: list[float]) -> list[float]:
    """Eq. 5 outcome by outcome: the sum of the payoffs of the same source's strictly
    lower ranks (an independent loop, no cumulative sums)."""
    out = []
    for s, r in zip(src, rank, strict=True):
        lower = [p for s2, r2, p in zip(src, rank, payoff, strict=True) if s2 == s and r2 < r]
        out.append(math.inf if any(math.isinf(p) for p in lower) else math.fsum(lower))
    return out


def _succ(src: list[int], rank: list[int], payoff: list[float]) -> SimpleNamespace:
    return SimpleNamespace(
        src=np.array(src, dtype=np.int64),
        rank=np.array(rank, dtype=np.int64),
        payoff=np.array(payoff, dtype=float),
    )


def test_forcing_costs_with_an_infinite_payoff_is_not_nan() -> None:
    src, rank = [0, 0, 0, 1, 1, 1], [0, 1, 2, 0, 1, 2]
    payoff = [0.3, math.inf, 0.7, 0.2, 0.5, 0.1]
    got = forcing_costs(_succ(src, rank, payoff))  # type: ignore[arg-type]
    assert not np.isnan(got).any()
    assert got.tolist() == [0.0, 0.3, math.inf, 0.0, 0.2, 0.7]
    assert got.tolist() == _eq5_by_hand(src, rank, payoff)


def test_forcing_costs_unsorted_ties_and_a_source_without_outcomes() -> None:
    # source 1 has none; source 2's outcomes come out of order; ranks 1 tie (share a sum)
    src, rank = [2, 0, 2, 2, 0, 3], [1, 0, 0, 1, 1, 0]
    payoff = [0.25, 0.5, 0.125, 4.0, math.inf, 1.0]
    got = forcing_costs(_succ(src, rank, payoff))  # type: ignore[arg-type]
    assert got.tolist() == _eq5_by_hand(src, rank, payoff)


def _multi_doc(scene: Path, hidden: list[str]) -> dict[str, object]:
    """A ``lesmc-multi-check`` document of ``sort`` on ``scene`` whose violated result
    hides ``hidden`` at step 1 (frame 1)."""
    steps = [
        {
            "step": k,
            "frame": k,
            "hidden": h,
            "injected": [],
            "target_id": 1,
            "switch": False,
            "reference": None,
            "tracks": [],
        }
        for k, h in ((0, []), (1, hidden))
    ]
    result = {
        "property": "hijack",
        "verdict": "violated",
        "optimum": 1.0,
        "constraint_value": 1,
        "states": 2,
        "transitions": 1,
        "counterexample": steps,
    }
    return {
        "format": "lesmc-multi-check",
        "version": 2,
        "design": "sort",
        "reference": "unattacked",
        "meta": {"scene": str(scene), "window": [1, 2]},
        "results": [result],
    }


def test_a_hidden_id_the_scene_lacks_is_located_at_its_line(tmp_path: Path) -> None:
    """``lesmc replay`` of multi-target results hiding an id the scene lacks: exit 2, no
    traceback, the error at the id's FILE:LINE:COL in the results (review 21, item 2)."""
    odd = tmp_path / "odd.json"
    odd.write_text(
        json.dumps(_multi_doc(ROOT / "examples" / "crossing.json", ["1:0", "1:99"]), indent=1)
    )
    (tmp_path / "frames").mkdir()
    r = lesmc("replay", str(odd), "--frames", str(tmp_path / "frames"), timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    lines = odd.read_text().splitlines()
    line = next(n for n, text in enumerate(lines, 1) if '"1:99"' in text)
    col = lines[line - 1].index('"1:99"') + 1
    assert f"{odd}:{line}:{col}: results[0].counterexample[1].hidden[1]: detection '1:99'" in (
        r.stderr
    ), r.stderr
