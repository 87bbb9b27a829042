"""``--design gnn`` under ``allow hide, inject`` (issue 61): the injected candidates reach
the gnn tracker as positions (lesmc/tracking/gnn.py ``candidate_measurements``). Against
a brute force: on random small scenes with injection candidates every subset of every
attacked frame's detections is hidden and every subset of its candidates injected, the
independent plain gnn tracker (tests/gnn_plain.py) tracks the detections left (in the
frame's order) then the injected candidates (in theirs), and switches / lost are scored
as in tests/test_gnn_attack.py."""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np
import pytest

from lesmc.cli.multi_check import multi_results
from lesmc.language.parser import parse_spec
from lesmc.scene import scene_from_dict

pytest.importorskip("gnn_reference")  # test_gnn_attack's oracle needs stonesoup
import gnn_plain
import test_gnn_attack as base
from inject_scale import cases
from test_gnn import scene_doc

SPEC = """
property sw_payoff {{ attack window {l}..{u} allow hide, inject minimize payoff
  subject to switches(0..end) > 0 holds if optimum > 1000 }}
property lost_payoff {{ attack window {l}..{u} allow hide, inject minimize payoff
  subject to lost(0..end) > 0 holds if optimum > 1000 }}
"""

#: each property: the measure (0 switches, 1 lost)
PROPS = {"sw_payoff": 0, "lost_payoff": 1}


def _candidates(seed: int, frames: list[np.ndarray]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Up to two candidates a frame: a detection shifted by a few px, or anywhere."""
    rng = np.random.default_rng(900 + seed)
    cands, pays = [], []
    for Z in frames:
        rows = []
        for _ in range(int(rng.integers(0, 3))):
            if len(Z) and rng.random() < 0.7:
                rows.append(Z[int(rng.integers(0, len(Z)))] + rng.uniform(-8, 8, 2))
            else:
                rows.append(rng.uniform(20, 80, 2))
        cands.append(np.array(rows, dtype=float).reshape(-1, 2))
        pays.append(rng.integers(1, 10, len(rows)).astype(float))
    return cands, pays


def _brute(
    frames: list[np.ndarray],
    pay: list[np.ndarray],
    cands: list[np.ndarray],
    cpay: list[np.ndarray],
    l: int,
    u: int,
) -> list[tuple[float, base.Out]]:
    """(payoff, the plain tracker's output) of every hide/inject combination in l..u."""
    end = len(frames) - 1
    results: list[tuple[float, base.Out]] = []

    def run(t: Any, k: int, hist: base.Out, cost: float) -> None:
        if k > end:
            results.append((cost, hist))
            return
        Z, C = frames[k], cands[k]
        opts: list[tuple[tuple[int, ...], tuple[int, ...]]] = [((), ())]
        if l <= k <= u:
            hides = [s for r in range(len(Z) + 1) for s in itertools.combinations(range(len(Z)), r)]
            adds = [s for r in range(len(C) + 1) for s in itertools.combinations(range(len(C)), r)]
            opts = [(h, a) for h in hides for a in adds]
        for h, a in opts:
            c = t.copy() if len(opts) > 1 else t
            seen = np.vstack([np.delete(Z, list(h), axis=0), C[list(a)]]).reshape(-1, 2)
            got = c.step(seen)
            cc = cost + math.fsum([*pay[k][list(h)], *cpay[k][list(a)]])
            run(c, k + 1, [*hist, got], cc)

    run(gnn_plain.Plain(base.PARAMS), 0, [], 0.0)
    return results


@pytest.mark.parametrize("seed", range(cases(10, 200)))
def test_gnn_with_candidates_equals_brute_force(seed: int) -> None:
    frames, pay, l, u = base._case(seed)
    u = min(u, l + 1)  # at most two attacked steps: the brute force stays small
    end = len(frames) - 1
    cands, cpay = _candidates(seed, frames)
    doc = scene_doc(frames, base.PARAMS, pay)
    doc["version"] = 3
    for k, fr in enumerate(doc["frames"]):
        n = len(frames[k])
        if len(cands[k]):
            fr["candidates"] = [
                {"id": f"{k}:{n + j}", "x": float(c[0]), "y": float(c[1]), "payoff": float(p)}
                for j, (c, p) in enumerate(zip(cands[k], cpay[k], strict=True))
            ]
    refs = base._refs(frames)
    if all(r is None for r in refs):
        pytest.skip("the target's track is never output (test_gnn_attack covers this)")
    spec = parse_spec(SPEC.format(l=l, u=u), "p.spec")
    got = {r["property"]: r for r in multi_results(scene_from_dict(doc), "s.json", (spec,))}
    runs = _brute(frames, pay, cands, cpay, l, u)
    hide_only = base._brute(frames, pay, l, u)
    for name, which in PROPS.items():
        want = min(
            (c for c, out in runs if base._score(out, refs, 0, end)[which] >= 1),
            default=math.inf,
        )
        res = got[name]
        opt = math.inf if res["optimum"] is None else res["optimum"]
        assert opt == pytest.approx(want), (seed, name, opt, want)
        plain = min(
            (r[0] for r in hide_only if base._score(r[3], refs, 0, end)[which] >= 1),
            default=math.inf,
        )
        assert opt <= plain  # injecting never raises an optimum
